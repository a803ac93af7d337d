"""Install the AVX2 build of HPIPM/BLASFEO into the virtualenv (see hpipm_library.py).

acados' libraries reach PyPI inside the ``comma-deps-acados`` wheel, which also carries a
casadi 3.7 of its own, so it is never installed as a package (it would overwrite our
casadi): ``pip download`` fetches the pinned wheel, and only the two libraries are taken
out of it, each checked against its pinned SHA-256 before it is written.

Run: ``python -m supervisor.cli.hpipm_install [--wheel PATH]`` (``make`` does). A failure
leaves nothing half-written; the back-end then uses casadi's generic build.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from controllers.qp.hpipm_library import OPTIMIZED_DIR

WHEEL_REQUIREMENT = "comma-deps-acados==0.2.2.post92"
_MEMBER_FOLDER = "comma_deps_acados-0.2.2.post92.data/purelib/acados/install/lib/"
PINNED_SHA256 = {
    "libblasfeo.so": "4804a491b10ca1065010c84d1e7fb9cc005acd2cfed504f0655ba94bd77ac01b",
    "libhpipm.so": "1eac1f3673d6f99876104f86ef8b80f884f860ce77ba9ff135af5b2e355616c6",
}


def download_wheel(folder: Path) -> Path:
    """The pinned wheel, fetched by pip into ``folder``."""
    pip = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps"]
    subprocess.run(
        [*pip, "--only-binary=:all:", "--dest", str(folder), WHEEL_REQUIREMENT], check=True
    )
    wheels = sorted(folder.glob("comma_deps_acados-*.whl"))
    if not wheels:
        raise FileNotFoundError(f"pip download left no wheel in {folder}")
    return wheels[0]


def extract_libraries(wheel: Path, target: Path) -> None:
    """Both libraries from ``wheel`` into ``target``, after checking every hash; raises
    ``ValueError`` on a missing member or a hash mismatch, writing nothing then."""
    contents: dict[str, bytes] = {}
    with zipfile.ZipFile(wheel) as archive:
        for name, expected in PINNED_SHA256.items():
            try:
                data = archive.read(_MEMBER_FOLDER + name)
            except KeyError:
                raise ValueError(f"{wheel.name} has no {_MEMBER_FOLDER + name}") from None
            digest = hashlib.sha256(data).hexdigest()
            if digest != expected:
                raise ValueError(f"{name} in {wheel.name}: SHA-256 {digest}, pinned {expected}")
            contents[name] = data
    target.mkdir(parents=True, exist_ok=True)
    for name, data in contents.items():
        partial = target / f".{name}.{os.getpid()}"
        partial.write_bytes(data)
        partial.replace(target / name)  # atomic: a loader never sees half a library


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheel", type=Path, help="use this wheel instead of downloading it")
    parser.add_argument("--target", type=Path, default=OPTIMIZED_DIR, help="install folder")
    args = parser.parse_args(argv)
    try:
        with tempfile.TemporaryDirectory() as scratch:
            wheel = args.wheel or download_wheel(Path(scratch))
            extract_libraries(wheel, args.target)
    except (OSError, ValueError, subprocess.CalledProcessError, zipfile.BadZipFile) as error:
        print(f"hpipm_install: {error}; HPIPM stays on casadi's generic build", file=sys.stderr)
        return 1
    print(f"hpipm_install: AVX2 build of HPIPM/BLASFEO in {args.target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
