"""The flight process's status (``supervisor.flight.status.FlightStatus``), built.

Pure: built from the tick core, the last tick, the estimate and plain views of the links,
the mocap source and the flight process itself. The model states the units and the shape.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.state import payload_points, payload_position, payload_velocity, payload_yaw
from supervisor.flight.arming import arm_blockers
from supervisor.flight.core import FlightCore, TickResult
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import FlightEnding
from supervisor.flight.operator_requests import ControllerName, SetpointFields
from supervisor.flight.path_timing import SAMPLE_STEP_S, TimedPath
from supervisor.flight.status import (
    ArenaBox,
    BarStatus,
    FlightStatus,
    LastFlight,
    LiveViewPort,
    LoadsStatus,
    MocapStatus,
    PathStatus,
    PlanSummary,
    RecentNotice,
    ReferenceStatus,
    SetpointsStatus,
    TickSummary,
    UavStatus,
)
from supervisor.vehicles.types import VehicleView

PATH_POINT_STEP_S = 0.25  # the status's points along a path: fine enough to draw its bends
# ... and at most this many, so that a long path keeps each message small (the channel
# carries at most 1 MiB; 2000 points at the millimetre are about 35 kB of JSON).
MAX_PATH_POINTS = 2000


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


@dataclass(frozen=True)
class ShellView:
    """What the flight process around the tick core adds: whether setpoints stream to the
    vehicles, the flight log being written (its path) and why the last one stopped by
    itself, and the live Foxglove view's loopback port (None: no live view)."""

    streaming: bool
    log_path: str | None = None
    log_stopped: str | None = None
    live_view_port: int | None = None


def _vector(values: Any) -> list[float | None]:
    """An array as numbers (a non-finite one becomes None as the status validates it)."""
    numbers: list[float | None] = np.asarray(values, dtype=float).tolist()
    return numbers


def _reference(core: FlightCore, reference: FormationReference | None) -> ReferenceStatus | None:
    if reference is None:
        return None
    eq = formation_equilibrium(core.params, reference)
    return ReferenceStatus(
        bar_position=list(reference.payload_position_m),
        bar_yaw=reference.payload_yaw_rad,
        uav_yaw=list(reference.uav_yaw_rad),
        theta_l=reference.cone_angle_rad,
        uav_positions=[_vector(eq.uav_position(i)) for i in core.params.layout.vehicles],
        bar_ends=[_vector(end) for end in eq.attachments_m],
    )


def _bar(core: FlightCore, x: FloatArray, reference: FormationReference | None) -> BarStatus:
    error_m = None
    if reference is not None:
        error_m = float(
            np.linalg.norm(payload_position(x) - np.asarray(reference.payload_position_m))
        )
    return BarStatus(
        position=_vector(payload_position(x)),
        ends=[_vector(end) for end in payload_points(x, core.params.payload.attachments_m)],
        yaw=payload_yaw(x),
        velocity=_vector(payload_velocity(x)),
        error_m=error_m,
    )


def _uav(x: FloatArray, layout: FormationLayout, i: int, vehicle: VehicleView) -> UavStatus:
    attitude = _vector(layout.uav_euler(x, i))
    return UavStatus(
        position=_vector(layout.uav_position(x, i)),
        yaw=attitude[2],
        attitude=attitude,
        connected=vehicle.connected,
        px4_mode=vehicle.px4_mode,
        battery_v=vehicle.battery_v,
        status_text=vehicle.status_text,
        link_refused=dict(vehicle.refused),
    )


def _mocap(mocap: MocapView, estimate: Estimate | None) -> MocapStatus:
    return MocapStatus(
        healthy=estimate is not None and estimate.healthy,
        connected=mocap.connected,
        server=mocap.server,
        last_error=mocap.last_error,
        rate_hz=mocap.rate_hz,
        age_ms=estimate.age_s * 1e3 if estimate is not None else None,
        unhealthy=list(estimate.unhealthy) if estimate is not None else [],
        frames=mocap.frames,
        dropped=mocap.dropped,
        refused=dict(mocap.refused),
    )


def _plan(last_tick: TickResult | None) -> PlanSummary:
    plan = last_tick.plan if last_tick is not None else None
    return PlanSummary(
        status=plan.status.value if plan is not None else None,
        solve_ms=plan.solve_time_s * 1e3 if plan is not None else None,
        thrust_n=[c.thrust_n for c in last_tick.commands] if last_tick is not None else None,
    )


def _setpoints(core: FlightCore) -> SetpointsStatus:
    n_vehicles = core.params.n_vehicles
    active = core.queue.active
    return SetpointsStatus(
        active=SetpointFields.of(active, n_vehicles) if active is not None else None,
        queued=[SetpointFields.of(s, n_vehicles) for s in core.queue.queued],
    )


def _path_points(timed: TimedPath) -> list[list[float]]:
    """The timed path's positions [m] every ``PATH_POINT_STEP_S`` from its start and its
    end, at most ``MAX_PATH_POINTS`` (a longer path's evenly apart), to the millimetre."""
    positions = timed.positions_m
    last = len(positions) - 1
    stride = max(round(PATH_POINT_STEP_S / SAMPLE_STEP_S), math.ceil(last / (MAX_PATH_POINTS - 1)))
    chosen = np.vstack((positions[:-1:stride], positions[-1:]))
    points: list[list[float]] = np.round(chosen, 3).tolist()
    return points


def _path(core: FlightCore, now_s: float) -> PathStatus | None:
    """The active setpoint's path, and how long since it began (when it has)."""
    active = core.queue.active
    plan = active.path if active is not None else None
    if plan is None:
        return None
    progress = core.path_progress(now_s)  # the path begun last: this one's, once begun
    elapsed_s = progress[1] if progress is not None and progress[0] is plan else None
    timed, limits = plan.timed, plan.limits
    return PathStatus(
        waypoints=[list(point.bar_position_m) for point in plan.waypoints],
        speed_mps=limits.speed_mps,
        accel_mps2=limits.accel_mps2,
        jerk_mps3=limits.jerk_mps3,
        length_m=timed.length_m,
        duration_s=timed.duration_s,
        elapsed_s=elapsed_s,
        points=_path_points(timed),
    )


def _loads(core: FlightCore) -> LoadsStatus | None:
    """The force observer's estimate (None when it is off)."""
    observer = core.force_observer
    if observer.time_constant_s == 0.0:
        return None
    loads = observer.forces
    return LoadsStatus(
        bar_force_n=list(loads.payload_n),
        bar_torque_nm=list(loads.payload_torque_nm),
        uav_forces_n=[list(loads.on_uav(k)) for k in range(core.params.n_vehicles)],
        at_bound=observer.at_bound(),
    )


def build_telemetry(
    core: FlightCore,
    estimate: Estimate | None,
    last_tick: TickResult | None,
    vehicles: tuple[VehicleView, ...],
    mocap: MocapView,
    tick: TickSummary,
    shell: ShellView,
    now_s: float,
    log_problem: str | None = None,
) -> FlightStatus:
    """The status at ``now_s`` (monotonic seconds of the flight process); ``log_problem``:
    why no flight log could be written now (it blocks arming)."""
    layout = core.params.layout
    x = estimate.x if estimate is not None else np.full(layout.n_states, math.nan)
    reference = last_tick.reference if last_tick is not None else None
    live_view = shell.live_view_port
    return FlightStatus(
        time_s=now_s,
        mode=core.modes.mode,
        mode_for_s=now_s - core.modes.changed_at_s,
        phase=core.phase,
        # The core holds one of CONTROLLERS; the model checks it again.
        controller=cast(ControllerName, core.controller),
        armed=[v.armed for v in vehicles],
        arm_blocked_by="; ".join(arm_blockers(core, vehicles, log_problem)) or None,
        arena=ArenaBox(min=list(core.arena.min_m), max=list(core.arena.max_m)),
        bar=_bar(core, x, reference),
        uavs=[_uav(x, layout, i, v) for i, v in enumerate(vehicles, start=1)],
        reference=_reference(core, reference),
        mocap=_mocap(mocap, estimate),
        setpoints=_setpoints(core),
        path=_path(core, now_s),
        plan=_plan(last_tick),
        loads=_loads(core),
        faults=[f.message for f in last_tick.faults] if last_tick is not None else [],
        notices=[
            RecentNotice(age_s=now_s - t_s, message=str(notice)) for t_s, notice in core.notices
        ],
        last_flight=_last_flight(core.modes.last_flight, now_s),
        tick=tick,
        streaming=shell.streaming,
        log=shell.log_path,
        log_stopped=shell.log_stopped,
        live_view=LiveViewPort(sdk_port=live_view) if live_view is not None else None,
        agents=None,
    )


def _last_flight(ending: FlightEnding | None, now_s: float) -> LastFlight | None:
    if ending is None:
        return None
    return LastFlight(ended_in=ending.mode, age_s=now_s - ending.at_s)
