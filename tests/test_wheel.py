"""The package as pip builds it: every file of the packages that is not Python source (the
shipped setups, scenarios, dashboard, the simulated PX4's event catalog) is inside the
wheel, so that an installed ``uavbar-supervisor`` needs no source tree."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOT_SOURCES = (".git", ".venv", "build", "flight-logs", "*.egg-info", "__pycache__", ".*_cache")
PACKAGES = ("geometry", "supervisor", "controllers", "mocap", "api", "sim", "benchmarks", "configs")


def package_data() -> set[str]:
    """The files of the packages that are not Python source, as git tracks them."""
    tracked = subprocess.run(
        ["git", "ls-files", *PACKAGES], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    return {name for name in tracked if not name.endswith(".py")}


@pytest.mark.slow
def test_the_wheel_holds_the_configs_scenarios_and_dashboard(tmp_path: Path) -> None:
    source = tmp_path / "source"  # a copy: the build writes build/ and *.egg-info
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*NOT_SOURCES))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), "."],
        cwd=source,
        check=True,
        capture_output=True,
        timeout=300,
    )
    [wheel] = tmp_path.glob("uavbar_supervisor-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = package_data()
    assert {"configs/sim.toml", "configs/scenarios/paper.toml"} <= shipped
    assert {"api/static/index.html", "sim/px4_events.json"} <= shipped
    assert {
        "api/static/vendor/three.module.min.js",
        "api/static/vendor/three-LICENSE.txt",
    } <= shipped
    assert shipped <= names, shipped - names
    assert not any(name.startswith("tests/") for name in names)
    entry_points = next(name for name in names if name.endswith("entry_points.txt"))
    assert "uavbar-supervisor = supervisor.cli.main:main" in (
        zipfile.ZipFile(wheel).read(entry_points).decode()
    )
