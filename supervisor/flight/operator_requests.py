"""Operator requests, typed, and how the tick core answers them (between ticks).

Pure: a request in, a ``Reply`` out. The requests are pydantic models discriminated on
``kind``, so the REST body, the message between the processes and what the core receives
are one parse of one type; a setpoint is validated (arena, equilibrium) once, by the core.
The tick core's own checks decide; this module only translates.
"""

from __future__ import annotations

import math
from enum import StrEnum
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from geometry.formation import MAX_VEHICLES, MIN_VEHICLES
from supervisor.flight.modes import Event
from supervisor.flight.setpoints import Setpoint, SetpointError
from supervisor.flight.waypoint import Waypoint

if TYPE_CHECKING:  # the API process parses requests without loading the tick core
    from supervisor.flight.core import FlightCore

# The stated ranges of a setpoint's numbers. They bound what any request may carry; the
# arena and the equilibrium decide what can be flown. strict: a JSON true is not a number
# (ints still are); no NaN or infinity.
POSITION_LIMIT_M = 100.0  # |x|, |y|, |z|: far beyond any motion-capture hall
YAW_LIMIT_RAD = 2.0 * math.pi  # one turn either way (yaw is taken modulo 2π)
THETA_L_LIMIT_RAD = math.pi / 2.0  # θ_l in [0, π/2): horizontal cables hold nothing
DURATION_LIMIT_S = 3600.0  # hold and timeout: an hour
# The tick core's queue capacity (supervisor.flight.setpoints.SetpointQueue): no request
# can queue more, so a longer list is refused by its length before any entry is read.
MAX_SETPOINTS_PER_REQUEST = 32
MAX_WAYPOINTS_PER_PATH = 64  # a path is timed and checked between two ticks
SPEED_LIMIT_MPS = 10.0  # a path's limits: far beyond what a cable-suspended load flies
ACCELERATION_LIMIT_MPS2 = 20.0
JERK_LIMIT_MPS3 = 200.0

Coordinate = Annotated[
    float, Field(ge=-POSITION_LIMIT_M, le=POSITION_LIMIT_M, allow_inf_nan=False, strict=True)
]
Yaw = Annotated[float, Field(ge=-YAW_LIMIT_RAD, le=YAW_LIMIT_RAD, allow_inf_nan=False, strict=True)]
CableAngle = Annotated[float, Field(ge=0.0, lt=THETA_L_LIMIT_RAD, allow_inf_nan=False, strict=True)]
HoldTime = Annotated[float, Field(ge=0.0, le=DURATION_LIMIT_S, allow_inf_nan=False, strict=True)]
Timeout = Annotated[float, Field(gt=0.0, le=DURATION_LIMIT_S, allow_inf_nan=False, strict=True)]


class _Message(BaseModel):
    # NaN/inf never reach JSON: the serializer writes them as null.
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")


class SetpointFields(_Message):
    """One setpoint: bar centre [m, arena frame, each within ±100], bar yaw [rad, within
    ±2π], UAV yaws [rad, within ±2π] (default: the bar yaw), cable angle θ_l [rad, in
    [0, π/2)], hold time once reached [s, 0–3600], and how long to wait for it to be reached
    before the queue moves on anyway [s, up to 3600] (default: no limit)."""

    bar_position: Annotated[
        list[Coordinate],
        Field(
            min_length=3, max_length=3, description="the bar's centre (x, y, z) [m], arena frame"
        ),
    ]
    bar_yaw: Annotated[Yaw, Field(description="the bar's yaw [rad]")] = 0.0
    uav_yaw: Annotated[
        list[Yaw] | None,
        Field(
            min_length=MIN_VEHICLES,
            max_length=MAX_VEHICLES,
            description="each UAV's yaw [rad], UAV 1's first, one per UAV of the setup "
            "(default: the bar's)",
        ),
    ] = None
    theta_l: Annotated[CableAngle, Field(description="the cable angle θ_l [rad]")] = 0.0
    hold_s: Annotated[HoldTime, Field(description="how long to hold it once reached [s]")] = 5.0
    timeout_s: Annotated[
        Timeout | None,
        Field(description="how long it may take to be reached [s] (default: no limit)"),
    ] = None

    def to_setpoint(self) -> Setpoint:
        p = self.bar_position
        yaws = tuple(self.uav_yaw) if self.uav_yaw is not None else None
        return Setpoint(
            (p[0], p[1], p[2]), self.bar_yaw, yaws, self.theta_l, self.hold_s, self.timeout_s
        )

    @classmethod
    def of(cls, setpoint: Setpoint, n_vehicles: int) -> SetpointFields:
        """A setpoint of ``n_vehicles`` UAVs as the API shows it (the UAV yaws filled in);
        not validated again: it was when it was queued (the simulator's scenarios state
        their own ranges)."""
        return cls.model_construct(
            bar_position=list(setpoint.bar_position_m),
            bar_yaw=setpoint.bar_yaw_rad,
            uav_yaw=list(setpoint.uav_yaws(n_vehicles)),
            theta_l=setpoint.theta_l_rad,
            hold_s=setpoint.hold_s,
            timeout_s=setpoint.timeout_s,
        )


OperatorEvent = Literal["arm", "disarm", "takeoff", "land", "abort", "kill"]
ControllerName = Literal["centralized", "decentralized"]
URGENT_EVENTS = frozenset({"abort", "kill"})


class ModeRequest(_Message):
    """A flight-mode request of the operator (the mode table decides)."""

    kind: OperatorEvent


class ControllerRequest(_Message):
    """Which MPC flies the bar (bumpless in flight)."""

    kind: Literal["controller"] = "controller"
    controller: ControllerName


class QueueRequest(_Message):
    """Queue setpoints, all or none."""

    kind: Literal["queue"] = "queue"
    setpoints: Annotated[
        list[SetpointFields], Field(min_length=1, max_length=MAX_SETPOINTS_PER_REQUEST)
    ]


Speed = Annotated[float, Field(gt=0.0, le=SPEED_LIMIT_MPS, allow_inf_nan=False, strict=True)]
Acceleration = Annotated[
    float, Field(gt=0.0, le=ACCELERATION_LIMIT_MPS2, allow_inf_nan=False, strict=True)
]
Jerk = Annotated[float, Field(gt=0.0, le=JERK_LIMIT_MPS3, allow_inf_nan=False, strict=True)]


class WaypointFields(_Message):
    """One point of a path: the bar's centre [m, arena frame, each within ±100], and the
    bar's yaw and the cable angle θ_l there [rad] (default: those of the point before)."""

    bar_position: Annotated[
        list[Coordinate],
        Field(min_length=3, max_length=3, description="the bar's centre (x, y, z) [m]"),
    ]
    bar_yaw: Annotated[Yaw | None, Field(description="the bar's yaw there [rad]")] = None
    theta_l: Annotated[CableAngle | None, Field(description="θ_l there [rad]")] = None

    def to_waypoint(self) -> Waypoint:
        p = self.bar_position
        return Waypoint((p[0], p[1], p[2]), self.bar_yaw, self.theta_l)


class PathFields(_Message):
    """A path: the bar through ``waypoints`` from where it is when the path starts (after
    what is queued), smooth, timed within the speed, acceleration and jerk along it
    (default: the setup's ``control.path_jerk_mps3``) and the flight rates' yaw and θ_l
    rates; at its end it is a setpoint held ``hold_s``."""

    waypoints: Annotated[
        list[WaypointFields], Field(min_length=1, max_length=MAX_WAYPOINTS_PER_PATH)
    ]
    speed_mps: Annotated[Speed, Field(description="the bar's top speed along it [m/s]")]
    accel_mps2: Annotated[Acceleration, Field(description="the bar's top acceleration [m/s²]")]
    jerk_mps3: Annotated[
        Jerk | None, Field(description="the bar's top jerk along it [m/s³] (default: the setup's)")
    ] = None
    hold_s: Annotated[HoldTime, Field(description="how long to hold its end once reached [s]")] = (
        0.0
    )


class PathRequest(PathFields):
    """Queue a path (all of it or nothing)."""

    kind: Literal["path"] = "path"


class ClearSetpointsRequest(_Message):
    """Drop the queue and the active setpoint."""

    kind: Literal["clear_setpoints"] = "clear_setpoints"


class SetpointsQuery(_Message):
    """The active setpoint and the queue."""

    kind: Literal["setpoints"] = "setpoints"


Request = Annotated[
    ModeRequest
    | ControllerRequest
    | QueueRequest
    | PathRequest
    | ClearSetpointsRequest
    | SetpointsQuery,
    Field(discriminator="kind"),
]


class Outcome(StrEnum):
    """How a request ended: ``ok``; ``refused`` (well-formed, but the mode table, the queue,
    the arena or the equilibrium said no: HTTP 409); ``invalid`` (the request does not fit
    its type: 422); ``unavailable`` (no flight process answering: 503)."""

    OK = "ok"
    REFUSED = "refused"
    INVALID = "invalid"
    UNAVAILABLE = "unavailable"


class Reply(_Message):
    """The answer to a request: its outcome, why (when not ok) and what it returns."""

    outcome: Outcome
    reason: str = ""
    data: dict[str, Any] = Field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.outcome is Outcome.OK


def is_urgent(request: Request) -> bool:
    """Abort and kill: they never wait behind anything else."""
    return isinstance(request, ModeRequest) and request.kind in URGENT_EVENTS


def setpoint_json(setpoint: Setpoint | None, n_vehicles: int) -> dict[str, Any] | None:
    """A setpoint of ``n_vehicles`` UAVs as the API shows it (radians, metres, seconds)."""
    return None if setpoint is None else SetpointFields.of(setpoint, n_vehicles).model_dump()


def handle_request(core: FlightCore, request: Request, now_s: float) -> Reply:
    """Apply one request to ``core``; returns the reply (shutdown is the shell's)."""
    if isinstance(request, ModeRequest):
        transition = core.request(Event(request.kind), now_s)
        data = {"mode": transition.mode.value}
        if transition.accepted:
            return Reply(outcome=Outcome.OK, data=data)
        return Reply(outcome=Outcome.REFUSED, reason=transition.reason, data=data)
    if isinstance(request, ControllerRequest):
        transition = core.set_controller(request.controller, now_s)
        data = {"controller": core.controller, "mode": core.modes.mode.value}
        if transition.accepted:
            return Reply(outcome=Outcome.OK, data=data)
        return Reply(outcome=Outcome.REFUSED, reason=transition.reason, data=data)
    if isinstance(request, QueueRequest):
        try:
            core.queue_setpoints([entry.to_setpoint() for entry in request.setpoints])
        except SetpointError as error:  # not in this mode, queue full, outside the arena, ...
            return Reply(outcome=Outcome.REFUSED, reason=str(error))
        return Reply(outcome=Outcome.OK, data={"queued": len(core.queue.queued)})
    if isinstance(request, PathRequest):
        try:
            setpoint = core.queue_path(
                [point.to_waypoint() for point in request.waypoints],
                request.speed_mps,
                request.accel_mps2,
                request.jerk_mps3,
                request.hold_s,
            )
        except SetpointError as error:
            return Reply(outcome=Outcome.REFUSED, reason=str(error))
        assert setpoint.path is not None
        timed = setpoint.path.timed
        return Reply(
            outcome=Outcome.OK,
            data={
                "queued": len(core.queue.queued),
                "duration_s": timed.duration_s,
                "length_m": timed.length_m,
            },
        )
    if isinstance(request, ClearSetpointsRequest):
        core.clear_setpoints()
        return Reply(outcome=Outcome.OK)
    if isinstance(request, SetpointsQuery):
        n = core.params.n_vehicles
        active = setpoint_json(core.queue.active, n)
        queued = [setpoint_json(s, n) for s in core.queue.queued]
        return Reply(outcome=Outcome.OK, data={"active": active, "queued": queued})
    return Reply(outcome=Outcome.INVALID, reason=f"{request.kind!r} is not for the tick core")
