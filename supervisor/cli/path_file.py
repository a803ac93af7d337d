"""``path FILE``: a path's TOML file read into the body of ``POST /api/path``. Standard
library only (the terminal client starts without pydantic). The file holds the body's own
fields, in SI units and radians (``FILE_FORMAT``, which ``path --help`` shows).

The keys and that each value is a finite number are checked here, naming the file and the
key (a usage error); the ranges are the service's to check (422, naming the field).
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Any

from supervisor.cli.usage import UsageError

FILE_FORMAT = """\
  speed_mps = 0.4                  # the bar's top speed along it [m/s]
  accel_mps2 = 0.3                 # its top acceleration [m/s²]
  jerk_mps3 = 1.0                  # optional: its top jerk [m/s³] (default: the setup's)
  hold_s = 2.0                     # optional: how long its end is held [s] (default: 0)

  [[waypoints]]                    # one table per point, in order
  bar_position = [0.5, 0.0, 1.2]   # the bar's centre [m], arena frame
  bar_yaw = 0.3                    # optional: its yaw [rad] (default: the point before's)
  theta_l = 0.2                    # optional: the cable angle θ_l [rad] (likewise)"""

# Each key of the file and of a waypoint: whether it is required.
PATH_KEYS = {
    "speed_mps": True,
    "accel_mps2": True,
    "jerk_mps3": False,
    "hold_s": False,
    "waypoints": True,
}
WAYPOINT_KEYS = {"bar_position": True, "bar_yaw": False, "theta_l": False}


def read_path_file(file: Path) -> dict[str, Any]:
    """The REST body of the path in ``file``; raises ``UsageError`` naming the file and the
    key when it cannot be read, is not TOML, or has a key missing, unknown or not a number."""
    try:
        with file.open("rb") as handle:
            document = tomllib.load(handle)
    except OSError as error:
        raise UsageError(f"{file}: cannot read the path file: {error.strerror or error}") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise UsageError(f"{file}: not valid TOML: {error}") from None
    where = str(file)
    _check_keys(where, "", document, PATH_KEYS)
    body: dict[str, Any] = {
        key: _number(where, key, document[key])
        for key in PATH_KEYS
        if key != "waypoints" and key in document
    }
    waypoints = document["waypoints"]
    if not isinstance(waypoints, list) or not all(isinstance(w, dict) for w in waypoints):
        raise UsageError(f"{where}: waypoints: one [[waypoints]] table per point")
    body["waypoints"] = [_waypoint(where, index, point) for index, point in enumerate(waypoints)]
    return body


def _check_keys(file: str, prefix: str, table: dict[str, Any], keys: dict[str, bool]) -> None:
    """Every key of ``table`` known and every required one there (``prefix``: where the
    table is, for the message)."""
    for key in table:
        if key not in keys:
            raise UsageError(f"{file}: {prefix}{key}: unknown key (known: {', '.join(keys)})")
    for key, required in keys.items():
        if required and key not in table:
            raise UsageError(f"{file}: {prefix}{key}: missing")


def _number(file: str, key: str, value: Any) -> float | int:
    """``value`` when it is a finite number (not a boolean: JSON keeps them apart)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise UsageError(f"{file}: {key}: {value!r} is not a finite number")
    return value


def _waypoint(file: str, index: int, point: dict[str, Any]) -> dict[str, Any]:
    """The ``index``-th waypoint as the body has it."""
    prefix = f"waypoints[{index}]."
    _check_keys(file, prefix, point, WAYPOINT_KEYS)
    position = point["bar_position"]
    if not isinstance(position, list) or len(position) != 3:
        raise UsageError(
            f"{file}: {prefix}bar_position: three numbers [x, y, z] in metres, not {position!r}"
        )
    body: dict[str, Any] = {
        "bar_position": [_number(file, f"{prefix}bar_position", v) for v in position]
    }
    body.update(
        (key, _number(file, prefix + key, point[key]))
        for key in WAYPOINT_KEYS
        if key != "bar_position" and key in point
    )
    return body
