"""A flight log as one CSV table (PlotJuggler, spreadsheets): a row per tick, named columns.

The first column is ``t_s`` (PlotJuggler's time axis); then the state and the reference by
name (``state.bar.position_m.x``, ``reference.uav2.euler_rad.yaw``; the order of
``flight_messages``), the inputs (``inputs.uav1.thrust_n``, ``inputs.uav1.torque_nm.x``, …
``inputs.uavN.torque_nm.z`` for the log's N UAVs), the timings, and mode, controller and
plan status as text. A value that was not finite is an empty cell.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

from geometry.formation import FormationLayout
from supervisor.logs.flight_log import FlightLog
from supervisor.logs.flight_messages import EULER, VEC3, bodies, uav_names

_BODY_FIELDS = (
    ("position_m", VEC3),
    ("velocity_m_s", VEC3),
    ("euler_rad", EULER),
    ("rates_rad_s", VEC3),
)
_UAV_INPUTS = ("thrust_n", "torque_nm.x", "torque_nm.y", "torque_nm.z")
TIMINGS = ("solve_ms", "compute_ms", "lateness_ms", "mocap_age_ms")


def state_names(layout: FormationLayout) -> tuple[str, ...]:
    """Each state's name, in the state's order (``state.bar.position_m.x`` …)."""
    return tuple(
        f"{body}.{field}.{axis}"
        for body, _ in bodies(layout)
        for field, axes in _BODY_FIELDS
        for axis in axes
    )


def input_names(layout: FormationLayout) -> tuple[str, ...]:
    """Each input's name, in the inputs' order (``uav1.thrust_n`` … ``uavN.torque_nm.z``)."""
    return tuple(f"{uav}.{name}" for uav in uav_names(layout) for name in _UAV_INPUTS)


def columns(layout: FormationLayout) -> tuple[str, ...]:
    """The table's columns for a log of ``layout``'s formation."""
    states = state_names(layout)
    return (
        "t_s",
        *(f"state.{n}" for n in states),
        *(f"reference.{n}" for n in states),
        *(f"inputs.{n}" for n in input_names(layout)),
        *TIMINGS,
        "mode",
        "controller",
        "plan_status",
    )


def _cell(value: float) -> str:
    return repr(float(value)) if math.isfinite(value) else ""


def write_csv(log: FlightLog, path: Path) -> int:
    """Write ``log`` to ``path`` (``columns(log.layout)``); returns the number of rows."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle)
        writer.writerow(columns(log.layout))
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
