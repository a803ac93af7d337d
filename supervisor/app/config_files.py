"""Setup files as data: TOML read, ``extends`` merged, ``--set`` overrides applied, and
where each key came from. Standard library only, so that the terminal client finds the
service's address without importing the typed configuration (``supervisor.app.config``).

The shipped setups and scenarios are package data (``configs/``, a top-level package), found
beside this one wherever it is installed. ``--config`` takes a path or the name of a shipped
setup (``sim``, ``kth_sml``).
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from supervisor.errors import OperatorError

# The shipped setups and scenarios: package data of ``supervisor``.
CONFIG_DIR = Path(__file__).resolve().parents[2] / "configs"  # beside the packages, installed too
SCENARIO_DIR = CONFIG_DIR / "scenarios"
DEFAULT_SETUP = CONFIG_DIR / "sim.toml"
# The API token of `serve` and of the terminal client, when not configured or given.
TOKEN_ENV = "UAVBAR_TOKEN"
OVERRIDE_SOURCE = "--set"


class ConfigError(OperatorError):
    """A setup that cannot be used: unreadable file, unknown key, wrong type or value."""


def shipped_setups() -> list[str]:
    """Names of the setups shipped with the package (``--config NAME``)."""
    return sorted(path.stem for path in CONFIG_DIR.glob("*.toml"))


def shipped_scenarios() -> list[str]:
    """Names of the scenarios shipped with the package (``simulate --scenario NAME``)."""
    return sorted(path.stem for path in SCENARIO_DIR.glob("*.toml"))


def setup_path(given: str | Path) -> Path:
    """``--config``'s value as a file: a path, or a shipped setup's name (no ``/``, no
    ``.toml``). Raises ``ConfigError`` for a name that is not shipped."""
    text = str(given)
    if "/" in text or text.endswith(".toml"):
        return Path(text).expanduser()
    path = CONFIG_DIR / f"{text}.toml"
    if not path.is_file():
        raise ConfigError(
            f"--config {text}: no such shipped setup ({', '.join(shipped_setups())}) "
            "and not a path (a path has a / or ends in .toml)"
        )
    return path


@dataclass(frozen=True)
class SetupData:
    """A setup before validation: the merged tables, and the source of every leaf key
    (dotted: ``api.port``) — the file that set it last, or ``--set``."""

    data: dict[str, Any]
    sources: dict[str, str]


def _leaves(node: Mapping[str, Any], prefix: str) -> list[str]:
    keys = []
    for key, value in node.items():
        dotted = f"{prefix}{key}"
        keys += _leaves(value, f"{dotted}.") if isinstance(value, Mapping) else [dotted]
    return keys


def _merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in over.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = _merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> SetupData:
    path = path.resolve()
    if path in seen:
        raise ConfigError(f"{path}: 'extends' loops back to itself")
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except OSError as error:
        raise ConfigError(f"cannot read config {path}: {error.strerror}") from error
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from error
    parent = data.pop("extends", None)
    own = {key: str(path) for key in _leaves(data, "")}
    if parent is None:
        return SetupData(data, own)
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: 'extends' must be a file name")
    base = _without_replaced_payload(_read_toml(path.parent / parent, (*seen, path)), data)
    return SetupData(_merge(base.data, data), {**base.sources, **own})


# The two ways a setup describes its payload: the paper's bar, or any rigid body.
_BAR_KEYS = ("bar_mass", "bar_d1", "bar_d2", "bar_inertia")
_RIGID_KEYS = ("payload",)


def _without_replaced_payload(base: SetupData, over: Mapping[str, Any]) -> SetupData:
    """``base`` without the payload description ``over`` replaces: a file that describes
    its payload one way replaces, as a whole, the one it extends described the other way
    (a three-UAV plate extending the bar's lab keeps the lab, not the bar)."""
    system = over.get("system", {})
    if not isinstance(system, Mapping) or not isinstance(base.data.get("system"), Mapping):
        return base
    replaced: tuple[str, ...]
    if any(key in system for key in _RIGID_KEYS):
        replaced = _BAR_KEYS
    elif any(key in system for key in _BAR_KEYS):
        replaced = _RIGID_KEYS
    else:
        return base
    data = {
        **base.data,
        "system": {k: v for k, v in base.data["system"].items() if k not in replaced},
    }
    prefixes = tuple(f"system.{key}" for key in replaced)
    sources = {
        key: source
        for key, source in base.sources.items()
        if not any(key == p or key.startswith(f"{p}.") for p in prefixes)
    }
    return SetupData(data, sources)


def parse_override(assignment: str) -> tuple[list[str], Any]:
    """Split ``section.key=value`` into its key path and the TOML literal's value."""
    key, sep, literal = assignment.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--set {assignment!r}: expected section.key=value")
    try:
        value = tomllib.loads(f"v = {literal.strip()}")["v"]
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(
            f"--set {key}: {literal.strip()!r} is not a TOML value ({error})"
        ) from error
    return key.split("."), value


def _apply_override(data: dict[str, Any], path: list[str], value: Any) -> None:
    node = data
    for part in path[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"--set {'.'.join(path)}: {part!r} is a value, not a section")
        node = child
    node[path[-1]] = value


def read_setup(path: Path, overrides: Sequence[str] = ()) -> SetupData:
    """Read and merge a setup file (and those it extends), then apply ``overrides``; no
    validation beyond TOML (``supervisor.app.config.load_config`` validates)."""
    setup = _read_toml(path)
    sources = dict(setup.sources)
    for assignment in overrides:
        key_path, value = parse_override(assignment)
        _apply_override(setup.data, key_path, value)
        dotted = ".".join(key_path)
        replaced = [key for key in sources if key == dotted or key.startswith(f"{dotted}.")]
        for key in replaced:
            del sources[key]
        below = _leaves(value, f"{dotted}.") if isinstance(value, Mapping) else [dotted]
        sources.update((key, OVERRIDE_SOURCE) for key in below)
    return SetupData(setup.data, sources)
