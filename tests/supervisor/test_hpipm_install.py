"""The AVX2 HPIPM installer: only libraries whose hashes match the pins are written."""

from __future__ import annotations

import hashlib
import zipfile
from pathlib import Path

import pytest

from supervisor.cli import hpipm_install
from supervisor.cli.hpipm_install import _MEMBER_FOLDER, extract_libraries, main

LIBS = {"libblasfeo.so": b"blasfeo build", "libhpipm.so": b"hpipm build"}


def _wheel(path: Path, members: dict[str, bytes]) -> Path:
    with zipfile.ZipFile(path, "w") as archive:
        for name, data in members.items():
            archive.writestr(_MEMBER_FOLDER + name, data)
    return path


@pytest.fixture
def pinned(monkeypatch: pytest.MonkeyPatch) -> None:
    digests = {name: hashlib.sha256(data).hexdigest() for name, data in LIBS.items()}
    monkeypatch.setattr(hpipm_install, "PINNED_SHA256", digests)


@pytest.mark.usefixtures("pinned")
def test_pinned_libraries_are_extracted(tmp_path: Path) -> None:
    target = tmp_path / "lib"
    extract_libraries(_wheel(tmp_path / "a.whl", LIBS), target)
    assert {p.name: p.read_bytes() for p in target.iterdir()} == LIBS


@pytest.mark.usefixtures("pinned")
def test_a_tampered_library_writes_nothing(tmp_path: Path) -> None:
    wheel = _wheel(tmp_path / "a.whl", {**LIBS, "libhpipm.so": b"something else"})
    target = tmp_path / "lib"
    with pytest.raises(ValueError, match=r"libhpipm\.so.*SHA-256"):
        extract_libraries(wheel, target)
    assert not target.exists()


@pytest.mark.usefixtures("pinned")
def test_a_wheel_without_the_libraries_fails_cleanly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    wheel = _wheel(tmp_path / "a.whl", {"libblasfeo.so": LIBS["libblasfeo.so"]})
    target = tmp_path / "lib"
    assert main(["--wheel", str(wheel), "--target", str(target)]) == 1
    assert "has no" in capsys.readouterr().err
    assert not target.exists()
