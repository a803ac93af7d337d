"""The package as pip builds it: every file of the packages that is not Python source (the
shipped setups, scenarios, dashboard, the simulated PX4's event catalog) is inside the
wheel, so that an installed ``uavbar-supervisor`` needs no source tree."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from dataclasses import dataclass
from pathlib import Path

import pytest

from benchmarks.service import all_connected, running_service

ROOT = Path(__file__).resolve().parent.parent
NOT_SOURCES = (".git", ".venv", "build", "flight-logs", "*.egg-info", "__pycache__", ".*_cache")
PACKAGES = (
    "geometry",
    "supervisor",
    "controllers",
    "mocap",
    "px4_mavlink",
    "api",
    "sim",
    "benchmarks",
    "configs",
)


def package_data() -> set[str]:
    """The files of the packages that are not Python source, as git tracks them."""
    tracked = subprocess.run(
        ["git", "ls-files", *PACKAGES], cwd=ROOT, capture_output=True, text=True, check=True
    ).stdout.split()
    return {name for name in tracked if not name.endswith(".py")}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The wheel pip builds from a copy of the tree (the build writes build/, *.egg-info)."""
    folder = tmp_path_factory.mktemp("wheel")
    source = folder / "source"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(*NOT_SOURCES))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(folder), "."],
        cwd=source,
        check=True,
        capture_output=True,
        timeout=300,
    )
    [built] = folder.glob("uavbar_supervisor-*.whl")
    return built


@pytest.mark.slow
def test_the_wheel_holds_the_configs_scenarios_and_dashboard(wheel: Path) -> None:
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


def _site_packages(python: Path | str) -> str:
    return subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()


@dataclass(frozen=True)
class Installed:
    cli: Path  # the console script
    elsewhere: Path  # a folder outside the tree to run it in


@pytest.fixture(scope="module")
def installed(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Installed:
    """The wheel alone installed in a fresh virtualenv."""
    venv = tmp_path_factory.mktemp("venv")
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    python = venv / "bin" / "python"
    install = [sys.executable, "-m", "pip", "--python", str(python), "install", "--no-deps"]
    subprocess.run([*install, "--no-index", "-q", str(wheel)], check=True, timeout=300)
    # The dependencies are this environment's (no registry here), named by a .pth line: a
    # line adds the folder only, so this tree's editable install (a .pth hook) is not run.
    Path(_site_packages(python), "dependencies.pth").write_text(_site_packages(sys.executable))
    elsewhere = tmp_path_factory.mktemp("elsewhere")
    imported = subprocess.run(
        [str(python), "-c", "import supervisor; print(supervisor.__file__)"],
        cwd=elsewhere,
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert Path(imported).is_relative_to(venv), imported
    return Installed(venv / "bin" / "uavbar-supervisor", elsewhere)


@pytest.mark.slow
def test_the_installed_wheel_flies_the_paper_scenario_from_another_folder(
    installed: Installed,
) -> None:
    flown = subprocess.run(
        [str(installed.cli), "simulate", "--scenario", "paper", "--json"],
        cwd=installed.elsewhere,
        capture_output=True,
        text=True,
        timeout=900,
    )
    assert flown.returncode == 0, flown.stderr[-3000:]
    summary = json.loads(flown.stdout)
    assert summary["completed"] and summary["final_mode"] == "hover", summary
    assert summary["slack_events"] == 0, summary


@pytest.mark.slow
async def test_the_installed_wheel_serves_the_dashboard_and_the_embedded_simulator(
    installed: Installed,
) -> None:
    logs = installed.elsewhere / "logs"
    program = [str(installed.cli)]
    async with (
        running_service("wheel-token", logs, program=program, cwd=installed.elsewhere) as service,
        service.client() as http,
    ):
        await service.wait_for(http, all_connected, 60.0, "healthy mocap and both links")
        page = await http.get("/")
    assert page.status_code == 200 and 'data-testid="abort"' in page.text
