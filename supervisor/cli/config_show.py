"""``uavbar-supervisor config show``: the effective configuration, each key with where it
came from (a setup file, ``--set``, or the default of ``supervisor.app.config``)."""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from supervisor.app.config import load_config
from supervisor.app.config_files import read_setup
from supervisor.cli.output import table

DEFAULT_SOURCE = "default"
SECRET_KEYS = frozenset({"api.token"})


def _flatten(node: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in node.items():
        dotted = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, f"{dotted}."))
        else:
            flat[dotted] = value
    return flat


def effective_config(path: Path, overrides: Sequence[str]) -> dict[str, dict[str, Any]]:
    """Every key of the validated setup: its value (secrets shown only as set or not) and
    its source. Raises ``ConfigError`` as ``load_config`` does."""
    config = load_config(path, overrides)
    sources = read_setup(path, overrides).sources
    values = _flatten(config.model_dump(mode="json"))
    shown = {}
    for key, value in values.items():
        if key in SECRET_KEYS and value is not None:
            value = "(set, not shown)"
        shown[key] = {"value": value, "source": sources.get(key, DEFAULT_SOURCE)}
    return shown


def _literal(value: Any) -> str:
    return "(unset)" if value is None else json.dumps(value, ensure_ascii=False)


def show_config(path: Path, overrides: Sequence[str], as_json: bool) -> int:
    """Print the effective configuration; returns the exit status."""
    shown = effective_config(path, overrides)
    if as_json:
        print(json.dumps(shown))
        return 0
    rows = [[key, _literal(entry["value"]), entry["source"]] for key, entry in shown.items()]
    print(f"setup {path}")
    print(table(["key", "value", "source"], rows))
    return 0
