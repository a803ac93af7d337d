"""Every third-party module the installed package imports comes with it: a wheel installed
elsewhere gets ``[project] dependencies`` (and what those require), not the development
extras. (``tests/test_wheel.py`` cannot see this: its fresh environment borrows this one's
packages.) The benchmarks are left out: they run from the development environment."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions, requires
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RUNTIME_PACKAGES = (
    "api",
    "configs",
    "controllers",
    "geometry",
    "mocap",
    "px4_mavlink",
    "sim",
    "supervisor",
)
OURS = {*RUNTIME_PACKAGES, "benchmarks"}


def normalized(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def requirement_name(requirement: str) -> str:
    return normalized(re.split(r"[<>=!~\[;\s(]", requirement, maxsplit=1)[0])


def declared_runtime_distributions() -> set[str]:
    """``[project] dependencies``, and what each of them requires in turn (one level)."""
    pyproject = tomllib.loads((ROOT / "pyproject.toml").read_text())
    direct = {requirement_name(r) for r in pyproject["project"]["dependencies"]}
    required = {
        requirement_name(r) for name in direct for r in requires(name) or [] if "extra ==" not in r
    }
    return direct | required


def third_party_imports() -> dict[str, set[str]]:
    """Top-level module → the files of the runtime packages that import it."""
    found: dict[str, set[str]] = {}
    for package in RUNTIME_PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(), str(path))):
                if isinstance(node, ast.Import):
                    names = [alias.name for alias in node.names]
                elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                    names = [node.module]
                else:
                    continue
                for name in names:
                    top = name.split(".")[0]
                    if top not in sys.stdlib_module_names and top not in OURS:
                        found.setdefault(top, set()).add(str(path.relative_to(ROOT)))
    found.pop("__future__", None)
    return found


def test_every_module_the_package_imports_is_a_runtime_dependency() -> None:
    declared = declared_runtime_distributions()
    distributions = packages_distributions()
    missing = {
        module: sorted(files)
        for module, files in third_party_imports().items()
        if not {normalized(d) for d in distributions.get(module, [])} & declared
    }
    assert not missing, f"imported but not a runtime dependency: {missing}"
