"""The import rules of docs/architecture.md, enforced by walking every module's AST."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = (
    "geometry",
    "api",
    "supervisor",
    "controllers",
    "mocap",
    "px4_mavlink",
    "sim",
    "benchmarks",
)

# Which first-party packages each package may import (arrows point one way).
ALLOWED = {
    "geometry": set(),
    "controllers": {"geometry"},
    "mocap": {"geometry"},
    "px4_mavlink": set(),
    "sim": {"geometry", "mocap", "px4_mavlink"},
    # supervisor: which of its rooms may import what is in ROOMS below
    "supervisor": {"geometry", "controllers", "mocap", "px4_mavlink", "sim", "benchmarks", "api"},
    "api": {"geometry", "supervisor", "controllers", "mocap"},
    "benchmarks": {"geometry", "controllers", "mocap", "px4_mavlink", "sim", "supervisor", "api"},
}
# The simulated PX4 and the supervisor's link speak MAVLink through one package below both
# (px4_mavlink: the sans-IO codec, PX4's event messages and catalog, signing, the UDP
# transport; the same bytes on both ends), as mocap is below both for QTM. So the simulator
# imports nothing of the supervisor, and the protocol nothing of those above it.
BELOW_THE_SUPERVISOR = {
    "sim": {"supervisor"},
    "px4_mavlink": {"supervisor", "sim", "api"},
}

# The rooms of supervisor/, and which other rooms each may import: arrows point one way,
# and a value type lives in the lowest room that uses it.
ROOMS = {
    "vehicles": set(),
    "flight": {"vehicles"},
    "mavlink": {"vehicles"},
    "logs": {"flight"},
    "ipc": {"flight"},
    "runtime": {"flight", "vehicles", "ipc", "logs"},
    "agents": {"flight", "vehicles"},
    "app": {"flight", "vehicles", "mavlink", "ipc", "runtime", "logs", "agents"},
    "simulate": {"flight", "logs", "runtime", "app"},
    "cli": {"flight", "logs", "runtime", "app", "simulate", "ipc", "agents"},
}
# Beyond the rooms: who may reach the world simulator, the MAVLink protocol, the API and the
# benchmarks.
ROOMS_USING_SIM = {"app", "simulate"}
ROOMS_USING_PX4_MAVLINK = {"mavlink", "app"}  # the link, the relay; app builds them
COMPOSITION_ROOT = {"supervisor/app/serve.py": "api", "supervisor/app/api_process.py": "api"}
BENCH_COMMAND = {"supervisor/cli/main.py": "benchmarks"}

# Pure cores: computation only — no event loop, sockets, clocks, threads or processes.
NO_IO = {"asyncio", "socket", "time", "threading", "subprocess"}
PURE = {
    "geometry": NO_IO,
    "controllers": NO_IO | {"tomllib", "fastapi", "pymavlink", "supervisor"},
    "supervisor/flight": NO_IO,
    "px4_mavlink/codec.py": NO_IO,
    "px4_mavlink/signing.py": NO_IO,
    "px4_mavlink/px4_messages.py": NO_IO,
    "px4_mavlink/events.py": NO_IO,
    "supervisor/mavlink/session.py": NO_IO,
    "supervisor/mavlink/parameters.py": NO_IO,
    "mocap/qtm_protocol.py": NO_IO,
    "mocap/fusion.py": NO_IO,
    "sim/faults.py": NO_IO,
    "supervisor/logs/view_seal.py": NO_IO,
}
# The state is indexed by name (geometry.state, geometry.formation); a literal index or
# slice into a vector called x / state / x_eq anywhere else is what this rule catches.
LITERAL_STATE_INDEX = re.compile(
    r"\b(?:x|state|x_eq|x_ref|state_ref)\[\s*-?\d+\s*(?::\s*\d+\s*)?\]"
)


def imported_modules(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def modules_of(package: str) -> list[Path]:
    path = ROOT / package
    return [path] if path.suffix == ".py" else sorted(path.rglob("*.py"))


def relative(path: Path) -> str:
    return str(path.relative_to(ROOT))


@pytest.mark.parametrize("package", PACKAGES)
def test_first_party_imports_point_one_way(package: str) -> None:
    violations = []
    for path in modules_of(package):
        for name in imported_modules(path):
            top = name.split(".")[0]
            if top in PACKAGES and top != package and top not in ALLOWED[package]:
                violations.append(f"{relative(path)} imports {name}")
    assert not violations, "\n".join(violations)


@pytest.mark.parametrize("package", sorted(BELOW_THE_SUPERVISOR))
def test_the_simulator_and_the_mavlink_protocol_import_nothing_of_the_supervisor(
    package: str,
) -> None:
    violations = [
        f"{relative(path)} imports {name}"
        for path in modules_of(package)
        for name in imported_modules(path)
        if name.split(".")[0] in BELOW_THE_SUPERVISOR[package]
    ]
    assert not violations, "\n".join(violations)


def test_every_supervisor_module_lives_in_a_room() -> None:
    """Every module but the exception root (``supervisor/errors.py``, which any room may
    raise from) lives in a room."""
    outside = ("__init__.py", "errors.py")
    loose = [relative(p) for p in (ROOT / "supervisor").glob("*.py") if p.name not in outside]
    rooms = {p.name for p in (ROOT / "supervisor").iterdir() if (p / "__init__.py").exists()}
    assert not loose, f"modules outside the rooms: {loose}"
    assert rooms == set(ROOMS)


def room_may_import(room: str, where: str, name: str) -> bool:
    """Whether module ``where`` of ``room`` may import ``name`` (first-party names only)."""
    parts = name.split(".")
    if parts[0] == "supervisor":
        return len(parts) == 1 or parts[1] in (room, "errors") or parts[1] in ROOMS[room]
    if parts[0] == "sim":
        return room in ROOMS_USING_SIM
    if parts[0] == "px4_mavlink":
        return room in ROOMS_USING_PX4_MAVLINK
    if parts[0] == "api":
        return COMPOSITION_ROOT.get(where) == "api"
    if parts[0] == "benchmarks":
        return BENCH_COMMAND.get(where) == "benchmarks"
    return True


@pytest.mark.parametrize("room", sorted(ROOMS))
def test_rooms_import_one_way(room: str) -> None:
    violations = [
        f"{relative(path)} imports {name}"
        for path in modules_of(f"supervisor/{room}")
        for name in imported_modules(path)
        if not room_may_import(room, relative(path), name)
    ]
    assert not violations, "\n".join(violations)


@pytest.mark.parametrize("part", sorted(PURE))
def test_pure_cores_do_no_io(part: str) -> None:
    paths = modules_of(part)
    assert paths and all(p.exists() for p in paths), f"{part} is missing"
    violations = [
        f"{relative(path)} imports {name}"
        for path in paths
        for name in imported_modules(path)
        if name.split(".")[0] in PURE[part]
    ]
    assert not violations, "\n".join(violations)


def test_each_room_says_what_lives_there() -> None:
    for room in (*ROOMS, "."):
        init = ROOT / "supervisor" / room / "__init__.py"
        docstring = ast.get_docstring(ast.parse(init.read_text())) or ""
        assert docstring and "\n" not in docstring.strip(), f"{relative(init)}: one line"
    assert ast.get_docstring(ast.parse((ROOT / "geometry" / "__init__.py").read_text()))


def test_no_literal_state_index_outside_the_state_module() -> None:
    violations = [
        f"{relative(path)}:{number}: {line.strip()}"
        for package in PACKAGES
        for path in modules_of(package)
        if relative(path) != "geometry/state.py"
        for number, line in enumerate(path.read_text().splitlines(), start=1)
        if LITERAL_STATE_INDEX.search(line)
    ]
    assert not violations, "\n".join(violations)


def test_one_array_type() -> None:
    definitions = [
        relative(path)
        for package in PACKAGES
        for path in modules_of(package)
        if re.search(r"^FloatArray\s*=", path.read_text(), re.MULTILINE)
    ]
    assert definitions == ["geometry/arrays.py"]


def test_sim_plant_does_not_reuse_the_controller_model() -> None:
    """A controller tested on its own model proves little (ARCHITECTURE.md)."""
    for path in modules_of("sim"):
        assert not any(name.startswith("controllers") for name in imported_modules(path)), path


def test_the_rules_cover_every_package() -> None:
    assert {
        p.name for p in ROOT.iterdir() if (p / "__init__.py").exists() and p.name != "tests"
    } == set(PACKAGES)


@pytest.mark.parametrize("entry", ["supervisor.app.flight_main", "supervisor.app.relay_main"])
def test_the_flight_and_relay_processes_never_load_the_simulator(entry: str) -> None:
    """They fly whatever answers on the configured addresses; importing the simulator (its
    compiled kernels) cost each start of theirs a second."""
    program = (
        f"import sys, {entry}; print(sorted(m for m in sys.modules if m.split('.')[0] == 'sim'))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", program], cwd=ROOT, capture_output=True, text=True, check=True
    )
    assert loaded.stdout.strip() == "[]"
