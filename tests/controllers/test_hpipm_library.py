"""Which HPIPM build is loaded: the override, the AVX2 build only on a CPU that runs it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import casadi
import pytest

from controllers.qp import hpipm_library
from controllers.qp.hpipm_library import LIBRARIES, library_folder

ROOT = Path(__file__).resolve().parents[2]


def _fake_build(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name in LIBRARIES:
        (folder / name).write_bytes(b"\x7fELF")
    return folder


def test_the_override_wins_and_must_hold_both_libraries(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    folder = _fake_build(tmp_path / "mine")
    monkeypatch.setenv("UAVBAR_HPIPM_DIR", str(folder))
    assert library_folder() == folder
    (folder / "libhpipm.so").unlink()
    with pytest.raises(FileNotFoundError, match=r"libhpipm\.so"):
        library_folder()


@pytest.mark.parametrize(
    ("flags", "uses_optimized"),
    [({"sse4_2", "avx", "avx2", "fma"}, True), ({"sse4_2", "avx"}, False), (set(), False)],
)
def test_the_avx2_build_is_used_only_where_the_cpu_runs_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, flags: set[str], uses_optimized: bool
) -> None:
    monkeypatch.delenv("UAVBAR_HPIPM_DIR", raising=False)
    optimized = _fake_build(tmp_path / "uavbar-hpipm")
    monkeypatch.setattr(hpipm_library, "OPTIMIZED_DIR", optimized)
    monkeypatch.setattr(hpipm_library, "cpu_flags", lambda: frozenset(flags))
    casadi_folder = Path(casadi.__file__).parent
    assert library_folder() == (optimized if uses_optimized else casadi_folder)


def test_without_the_avx2_build_casadis_is_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("UAVBAR_HPIPM_DIR", raising=False)
    monkeypatch.setattr(hpipm_library, "OPTIMIZED_DIR", tmp_path / "absent")
    monkeypatch.setattr(hpipm_library, "cpu_flags", lambda: frozenset({"avx2", "fma"}))
    assert library_folder() == Path(casadi.__file__).parent


def test_casadis_generic_build_passes_the_hpipm_tests_too() -> None:
    """The two builds differ in HPIPM version (one function's arguments changed): the
    back-end's whole test module, in a process that loads casadi's build."""
    casadi_folder = Path(casadi.__file__).parent
    env = {**os.environ, "UAVBAR_HPIPM_DIR": str(casadi_folder)}
    check = "from controllers.qp.hpipm import library_build; print(library_build())"
    build = subprocess.run(
        [sys.executable, "-c", check], env=env, capture_output=True, text=True, check=True
    )
    assert build.stdout.strip() == "generic"
    run_pytest = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"]
    tests = subprocess.run(
        [*run_pytest, "tests/controllers/test_hpipm.py"],
        env=env,
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert tests.returncode == 0, tests.stdout[-2000:]
