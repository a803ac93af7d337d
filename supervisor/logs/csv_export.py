"""A flight log as one CSV table (PlotJuggler, spreadsheets): a row per tick, named columns.

The first column is ``t_s`` (PlotJuggler's time axis); then the state and the reference by
name (``state.bar.position_m.x``, ``reference.uav2.euler_rad.yaw``; the order of
``flight_messages``), the inputs (``inputs.uav1.thrust_n``, ``inputs.uav1.torque_nm.x``), the
timings, and mode, controller and plan status as text. A value that was not finite is an
empty cell.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from supervisor.logs.flight_log import FlightLog
from supervisor.logs.flight_messages import BODIES, EULER, VEC3

_BODY_FIELDS = (
    ("position_m", VEC3),
    ("velocity_m_s", VEC3),
    ("euler_rad", EULER),
    ("rates_rad_s", VEC3),
)
STATE_NAMES = tuple(
    f"{body}.{field}.{axis}" for body, _ in BODIES for field, axes in _BODY_FIELDS for axis in axes
)
INPUT_NAMES = tuple(
    f"uav{i}.{name}"
    for i in (1, 2)
    for name in ("thrust_n", "torque_nm.x", "torque_nm.y", "torque_nm.z")
)
TIMINGS = ("solve_ms", "compute_ms", "lateness_ms", "mocap_age_ms")
COLUMNS = (
    "t_s",
    *(f"state.{n}" for n in STATE_NAMES),
    *(f"reference.{n}" for n in STATE_NAMES),
    *(f"inputs.{n}" for n in INPUT_NAMES),
    *TIMINGS,
    "mode",
    "controller",
    "plan_status",
)


def _cell(value: float) -> str:
    return repr(float(value)) if math.isfinite(value) else ""


def write_csv(log: FlightLog, path: Path) -> int:
    """Write ``log`` to ``path`` (``COLUMNS``); returns the number of rows."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(COLUMNS)
        for k in range(len(log.t_s)):
            numbers = [
                log.t_s[k],
                *log.state[k],
                *log.state_ref[k],
                *log.inputs[k],
                *(getattr(log, name)[k] for name in TIMINGS),
            ]
            writer.writerow(
                [
                    *(_cell(v) for v in numbers),
                    log.modes[k],
                    log.controllers[k],
                    log.plan_status[k],
                ]
            )
    return len(log.t_s)
