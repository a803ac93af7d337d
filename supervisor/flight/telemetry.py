"""The telemetry message: what ``GET /api/status`` returns and the WebSocket streams.

Pure: built from the tick core, the last tick, the estimate and plain views of the links
and the mocap source. Angles in radians, positions in metres (arena frame), times in ms.
``mode_for_s``: how long the mode has been what it is [s] (a notice younger than that is
what put it there).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controllers.formation_equilibria import formation_equilibrium
from geometry.state import payload_points, payload_position, payload_velocity, payload_yaw
from supervisor.flight.arming import arm_blockers
from supervisor.flight.core import FlightCore, TickResult
from supervisor.flight.estimation import Estimate
from supervisor.flight.operator_requests import setpoint_json
from supervisor.vehicles.types import VehicleView


@dataclass(frozen=True)
class MocapView:
    """The motion-capture source as the client sees it; ``refused``: what was dropped as
    not the server's stream or refused by the fusion, by reason (only reasons seen)."""

    connected: bool
    rate_hz: float
    frames: int
    dropped: int
    refused: Mapping[str, int] = field(default_factory=dict)
    server: str = ""  # the QTM server's "host:port"
    last_error: str | None = None  # why the last connection to it ended


def _floats(values: Any) -> list[float | None]:
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, dtype=float)]


def build_telemetry(
    core: FlightCore,
    estimate: Estimate | None,
    last_tick: TickResult | None,
    vehicles: tuple[VehicleView, ...],
    mocap: MocapView,
    tick_summary: dict[str, float | int],
    now_s: float,
    log_problem: str | None = None,
) -> dict[str, Any]:
    """The status/telemetry message at ``now_s`` (monotonic seconds of the flight process);
    ``log_problem``: why no flight log could be written now (it blocks arming)."""
    layout = core.params.layout
    x = estimate.x if estimate is not None else np.full(layout.n_states, math.nan)
    reference = last_tick.reference if last_tick is not None else None
    plan = last_tick.plan if last_tick is not None else None
    reference_json = None
    if reference is not None:
        eq = formation_equilibrium(core.params, reference)
        reference_json = {
            "bar_position": list(reference.payload_position_m),
            "bar_yaw": reference.payload_yaw_rad,
            "uav_yaw": list(reference.uav_yaw_rad),
            "theta_l": reference.cone_angle_rad,
            "uav_positions": [_floats(eq.uav_position(i)) for i in layout.vehicles],
            "bar_ends": [_floats(end) for end in eq.attachments_m],
        }
    bar_error = (
        float(np.linalg.norm(payload_position(x) - np.asarray(reference.payload_position_m)))
        if reference is not None
        else None
    )
    return {
        "time_s": now_s,
        "mode": core.modes.mode.value,
        "mode_for_s": now_s - core.modes.changed_at_s,
        "phase": core.phase,
        "controller": core.controller,
        "armed": [v.armed for v in vehicles],
        "arm_blocked_by": "; ".join(arm_blockers(core, vehicles, log_problem)) or None,
        "arena": {"min": list(core.arena.min_m), "max": list(core.arena.max_m)},
        "bar": {
            "position": _floats(payload_position(x)),
            "ends": [_floats(end) for end in payload_points(x, core.params.payload.attachments_m)],
            "yaw": _floats([payload_yaw(x)])[0],
            "velocity": _floats(payload_velocity(x)),
            "error_m": bar_error,
        },
        "uavs": [
            {
                "position": _floats(layout.uav_position(x, i)),
                "yaw": _floats(layout.uav_euler(x, i)[2:])[0],
                "attitude": _floats(layout.uav_euler(x, i)),
                "connected": v.connected,
                "px4_mode": v.px4_mode,
                "battery_v": v.battery_v if math.isfinite(v.battery_v) else None,
                "status_text": v.status_text,
                "link_refused": dict(v.refused),
            }
            for i, v in enumerate(vehicles, start=1)
        ],
        "reference": reference_json,
        "mocap": {
            "healthy": bool(estimate is not None and estimate.healthy),
            "connected": mocap.connected,
            "server": mocap.server,
            "last_error": mocap.last_error,
            "rate_hz": mocap.rate_hz,
            "age_ms": estimate.age_s * 1e3
            if estimate is not None and math.isfinite(estimate.age_s)
            else None,
            "unhealthy": list(estimate.unhealthy) if estimate is not None else [],
            "frames": mocap.frames,
            "dropped": mocap.dropped,
            "refused": dict(mocap.refused),
        },
        "setpoints": {
            "active": setpoint_json(core.queue.active, layout.n_vehicles),
            "queued": [setpoint_json(s, layout.n_vehicles) for s in core.queue.queued],
        },
        "plan": {
            "status": plan.status.value if plan is not None else None,
            "solve_ms": plan.solve_time_s * 1e3 if plan is not None else None,
            "thrust_n": [c.thrust_n for c in last_tick.commands] if last_tick else None,
        },
        "faults": [f.message for f in last_tick.faults] if last_tick is not None else [],
        "notices": [{"age_s": now_s - t_s, "message": str(notice)} for t_s, notice in core.notices],
        "tick": tick_summary,
    }
