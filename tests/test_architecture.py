"""The import rules of docs/architecture.md, enforced by walking every module's AST."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("api", "supervisor", "controllers", "mocap", "sim", "benchmarks")

# Which first-party packages each package may import (arrows point one way).
ALLOWED = {
    "controllers": set(),
    "mocap": set(),
    "sim": {"mocap"},
    "supervisor": {"controllers", "mocap", "sim", "benchmarks"},  # the CLI's `bench` command
    "api": {"supervisor", "controllers", "mocap"},
    "benchmarks": {"controllers", "mocap", "sim", "supervisor", "api"},
}
# The composition root: the one module that assembles the service, API included.
COMPOSITION_ROOT = {"supervisor/serve.py": {"api"}}
# Pure packages: computation only, no event loop, sockets or config files.
FORBIDDEN_MODULES = {
    "controllers": {"asyncio", "socket", "tomllib", "fastapi", "pymavlink", "supervisor"},
}


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
    return sorted((ROOT / package).rglob("*.py"))


@pytest.mark.parametrize("package", PACKAGES)
def test_first_party_imports_point_one_way(package: str) -> None:
    violations = []
    for path in modules_of(package):
        for name in imported_modules(path):
            top = name.split(".")[0]
            allowed = ALLOWED[package] | COMPOSITION_ROOT.get(str(path.relative_to(ROOT)), set())
            if top in PACKAGES and top != package and top not in allowed:
                violations.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not violations, "\n".join(violations)


@pytest.mark.parametrize("package", sorted(FORBIDDEN_MODULES))
def test_pure_packages_do_no_io(package: str) -> None:
    violations = []
    for path in modules_of(package):
        for name in imported_modules(path):
            if name.split(".")[0] in FORBIDDEN_MODULES[package]:
                violations.append(f"{path.relative_to(ROOT)} imports {name}")
    assert not violations, "\n".join(violations)


def test_sim_plant_does_not_reuse_the_controller_model() -> None:
    """A controller tested on its own model proves little (ARCHITECTURE.md)."""
    for path in modules_of("sim"):
        assert not any(name.startswith("controllers") for name in imported_modules(path)), path


def test_the_rules_cover_every_package() -> None:
    assert {
        p.name for p in ROOT.iterdir() if (p / "__init__.py").exists() and p.name != "tests"
    } == set(PACKAGES)
