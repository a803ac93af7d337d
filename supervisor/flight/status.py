"""The status, typed: one schema for every side that writes or reads it.

``FlightStatus`` is what the flight process publishes at 25 Hz (built by
``supervisor.flight.telemetry``, carried by ``supervisor.ipc.messages.TelemetryMessage``);
``Status`` is what ``GET /api/status`` answers (its ``response_model``) and the telemetry
WebSocket streams: the flight status, whether it is stale, ``serve``'s processes and the
simulated world. The API's waits, the terminal client and the dashboard read these models
(the dashboard their JSON); nothing reads the status by string keys.

Units are in each field's description: metres (arena frame, z up), radians, seconds,
milliseconds, volts. A number nobody knows yet (no estimate, no tick, no battery report)
is null: a non-finite value is made None as it is validated, since JSON has no NaN, so both
ends of a channel hold the same. Numbers are strict: a string or a boolean where a number
belongs is refused, naming the field.
"""

from __future__ import annotations

import math
from typing import Annotated, Self

from pydantic import (
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    StrictBool,
    StrictFloat,
    StrictInt,
    model_validator,
)

from geometry.formation import MAX_VEHICLES, MIN_VEHICLES
from supervisor.flight.modes import Mode
from supervisor.flight.operator_requests import ControllerName, SetpointFields
from supervisor.flight.phases import Phase


def _unknown_if_not_finite(value: object) -> object:
    """NaN and ±inf (numbers JSON cannot carry) are unknown: None."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


Real = Annotated[StrictFloat, Field(allow_inf_nan=False)]
"""A number that is always known."""
MaybeReal = Annotated[StrictFloat | None, BeforeValidator(_unknown_if_not_finite)]
"""A number, or None (null) while it is not known."""
Vector3 = Annotated[list[MaybeReal], Field(min_length=3, max_length=3)]
"""(x, y, z) or (roll, pitch, yaw); each None while not known."""
Count = Annotated[StrictInt, Field(ge=0)]
Refusals = dict[str, Count]
"""How many were refused, by reason (only reasons seen)."""


class _StatusPart(BaseModel):
    # As the channel's other messages: frozen, nothing unknown, NaN never written as NaN.
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")


class ArenaBox(_StatusPart):
    """The flight volume: two opposite corners."""

    min: Annotated[list[Real], Field(min_length=3, max_length=3, description="lowest corner [m]")]
    max: Annotated[list[Real], Field(min_length=3, max_length=3, description="highest corner [m]")]


class BarStatus(_StatusPart):
    """The payload as estimated (None throughout without an estimate)."""

    position: Annotated[Vector3, Field(description="its centre (x, y, z) [m]")]
    ends: Annotated[
        list[Vector3],
        Field(description="each cable's attachment point (x, y, z) [m], UAV 1's first"),
    ]
    yaw: Annotated[MaybeReal, Field(description="its yaw [rad]")]
    velocity: Annotated[Vector3, Field(description="its centre's velocity [m/s]")]
    error_m: Annotated[
        MaybeReal, Field(description="its centre's distance from the reference [m] (null: none)")
    ]


class UavStatus(_StatusPart):
    """One UAV: its estimated pose, and its vehicle as its link sees it."""

    position: Annotated[Vector3, Field(description="its position (x, y, z) [m]")]
    yaw: Annotated[MaybeReal, Field(description="its yaw [rad]")]
    attitude: Annotated[Vector3, Field(description="roll, pitch, yaw [rad]")]
    connected: Annotated[StrictBool, Field(description="its link hears heartbeats")]
    px4_mode: Annotated[str, Field(description='PX4\'s mode ("unknown" while not heard)')]
    battery_v: Annotated[MaybeReal, Field(description="its battery's voltage [V]")]
    status_text: Annotated[str, Field(description="PX4's latest text")]
    link_refused: Annotated[
        Refusals,
        Field(description="MAVLink frames its link refused, by reason (impostor, unsigned, ...)"),
    ]


class ReferenceStatus(_StatusPart):
    """What the controller flies to, and the formation's equilibrium there."""

    bar_position: Annotated[
        list[Real], Field(min_length=3, max_length=3, description="the bar's centre [m]")
    ]
    bar_yaw: Annotated[Real, Field(description="the bar's yaw [rad]")]
    uav_yaw: Annotated[list[Real], Field(description="each UAV's yaw [rad], UAV 1's first")]
    theta_l: Annotated[Real, Field(description="the cable angle θ_l [rad]")]
    uav_positions: Annotated[
        list[Vector3], Field(description="each UAV's position at the equilibrium [m]")
    ]
    bar_ends: Annotated[
        list[Vector3], Field(description="each attachment point at the equilibrium [m]")
    ]


class LoadsStatus(_StatusPart):
    """The constant external loads the force observer estimates, world frame (what the
    MPCs' equilibria carry: a push, wind, a mass or a CoM unlike the configured)."""

    bar_force_n: Annotated[Vector3, Field(description="on the payload's centre (x, y, z) [N]")]
    bar_torque_nm: Annotated[Vector3, Field(description="on the payload [N m]")]
    uav_forces_n: Annotated[list[Vector3], Field(description="on each UAV [N], UAV 1's first")]
    at_bound: Annotated[
        list[str],
        Field(description='the bodies whose load is at the observer\'s bound ("bar", "uav2", ...)'),
    ]


class MocapStatus(_StatusPart):
    """The motion capture: the source, and the estimate fused from it."""

    healthy: Annotated[StrictBool, Field(description="every body fresh in the estimate")]
    connected: Annotated[StrictBool, Field(description="connected to the QTM server")]
    server: Annotated[str, Field(description='the QTM server ("host:port")')]
    last_error: Annotated[
        str | None, Field(description="why the last connection to it ended (null: none did)")
    ]
    rate_hz: Annotated[Real, Field(description="frames received per second [Hz]")]
    age_ms: Annotated[MaybeReal, Field(description="the estimate's age [ms]")]
    unhealthy: Annotated[list[str], Field(description="the bodies not fresh")]
    frames: Annotated[Count, Field(description="frames received")]
    dropped: Annotated[Count, Field(description="frames missed (frame numbers skipped)")]
    refused: Annotated[
        Refusals, Field(description="frames dropped as not the server's, or refused by the fusion")
    ]


class SetpointsStatus(_StatusPart):
    """The setpoint flown now and those queued after it, as the API takes them."""

    active: Annotated[SetpointFields | None, Field(description="the one flown now")]
    queued: Annotated[list[SetpointFields], Field(description="the queue, next first")]


Point3 = Annotated[list[Real], Field(min_length=3, max_length=3)]
"""A point (x, y, z) [m] that is always known."""


class PathStatus(_StatusPart):
    """The path the active setpoint ends: its waypoints and limits, its timing, where it
    goes (for drawing) and how far along it the bar's reference is."""

    waypoints: Annotated[
        list[Point3], Field(description="the bar's centre at each waypoint (x, y, z) [m], in order")
    ]
    speed_mps: Annotated[Real, Field(description="its top speed [m/s]")]
    accel_mps2: Annotated[Real, Field(description="its top acceleration [m/s²]")]
    jerk_mps3: Annotated[Real, Field(description="its top jerk along it [m/s³]")]
    length_m: Annotated[Real, Field(description="its length from where it starts [m]")]
    duration_s: Annotated[Real, Field(description="how long it takes, rest to rest [s]")]
    elapsed_s: Annotated[
        MaybeReal,
        Field(
            description="time since it began [s] (beyond duration_s while its end is held; "
            "null: not begun, the bar still brought to its start)"
        ),
    ]
    points: Annotated[
        list[Point3],
        Field(
            description="the bar's centre along it (x, y, z) [m], to the millimetre, from its "
            "start every 0.25 s (a path over 500 s: 2000 points evenly) and its end"
        ),
    ]


class PlanSummary(_StatusPart):
    """The MPC's last plan (all null before the first tick)."""

    status: Annotated[
        str | None,
        Field(description="where its input came from: optimal, equilibrium or shifted_*"),
    ]
    solve_ms: Annotated[MaybeReal, Field(description="its solve time [ms]")]
    thrust_n: Annotated[
        list[MaybeReal] | None, Field(description="each UAV's commanded thrust [N]")
    ]


class RecentNotice(_StatusPart):
    """A decision the safety monitors or the vehicles forced, in words."""

    age_s: Annotated[Real, Field(description="how long ago [s]")]
    message: Annotated[str, Field(description='"kind: text" (abort, swing, vehicle, ...)')]


class LastFlight(_StatusPart):
    """How the last flight since the last arm ended, kept until the next arm."""

    ended_in: Annotated[
        Mode,
        Field(description="landing, or abort, px4_landing or killed (the last it went through)"),
    ]
    age_s: Annotated[Real, Field(description="how long ago it was disarmed [s]")]


class TickSummary(_StatusPart):
    """The control loop's timing: totals since start, percentiles of the recent ticks."""

    count: Annotated[Count, Field(description="ticks run")]
    missed_deadlines: Annotated[
        Count, Field(description="ticks skipped, or whose commands went out after the next")
    ]
    compute_ms_p50: Annotated[MaybeReal, Field(description="median compute time [ms]")]
    compute_ms_p99: Annotated[MaybeReal, Field(description="99th-percentile compute time [ms]")]
    lateness_ms_p99: Annotated[
        MaybeReal, Field(description="99th-percentile start after the deadline [ms]")
    ]
    latency_ms_p50: Annotated[
        MaybeReal, Field(description="median time from a mocap frame to its setpoints [ms]")
    ]
    latency_ms_p99: Annotated[
        MaybeReal,
        Field(description="99th-percentile time from a mocap frame to its setpoints [ms]"),
    ]


class LiveViewPort(_StatusPart):
    """The flight process's live Foxglove view."""

    sdk_port: Annotated[StrictInt, Field(ge=1, le=65535, description="its loopback port")]


UavCount = Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)


class AgentStatus(_StatusPart):
    """One vehicle's agent, as its ground station hears it (docs/agents.md)."""

    vehicle: Annotated[StrictInt, Field(ge=1, le=MAX_VEHICLES, description="its UAV (1 … N)")]
    alive: Annotated[StrictBool, Field(description="heard within agents.peer_timeout_s")]
    host: Annotated[str, Field(description="the computer it runs on")] = ""
    pid: Annotated[StrictInt | None, Field(description="its process id (null: never heard)")]
    mode: Annotated[Mode | None, Field(description="its own flight mode (null: never heard)")]
    link_latency_ms: Annotated[
        MaybeReal, Field(description="the ground station's last Zenoh round trip to it [ms]")
    ]
    last_message_age_s: Annotated[
        MaybeReal, Field(description="since its last message [s] (null: never heard)")
    ]


class FlightStatus(_StatusPart):
    """The flight process's status at ``time_s``: the mode, the N vehicles (2 … 8, UAV 1's
    first in every list), the bar, the mocap, the setpoints and the path flown, the last
    plan, the timing and the flight log."""

    time_s: Annotated[Real, Field(description="the flight process's monotonic clock [s]")]
    mode: Annotated[Mode, Field(description="the flight mode")]
    mode_for_s: Annotated[Real, Field(description="how long the mode has been what it is [s]")]
    phase: Annotated[Phase, Field(description="the phase of the flight within the mode")]
    controller: Annotated[ControllerName, Field(description="the MPC flying the bar")]
    armed: Annotated[list[StrictBool], UavCount, Field(description="each vehicle armed")]
    arm_blocked_by: Annotated[
        str | None, Field(description="why an arm would be refused now (null: it would be taken)")
    ]
    arena: ArenaBox
    bar: BarStatus
    uavs: Annotated[list[UavStatus], UavCount]
    reference: Annotated[ReferenceStatus | None, Field(description="null: none yet")]
    mocap: MocapStatus
    setpoints: SetpointsStatus
    path: Annotated[
        PathStatus | None, Field(description="the active setpoint's path (null: it has none)")
    ]
    plan: PlanSummary
    loads: Annotated[
        LoadsStatus | None,
        Field(description="the estimated external loads (null: the force observer is off)"),
    ]
    faults: Annotated[list[str], Field(description="what the safety monitors saw last tick")]
    notices: Annotated[list[RecentNotice], Field(description="recent notices, oldest first")]
    last_flight: Annotated[
        LastFlight | None,
        Field(description="how the last flight ended (null: none since start, or armed since)"),
    ]
    tick: TickSummary
    streaming: Annotated[StrictBool, Field(description="setpoints stream to the vehicles")]
    log: Annotated[str | None, Field(description="the flight log being written (its path)")]
    log_stopped: Annotated[
        str | None, Field(description="why the last flight's log stopped by itself")
    ]
    live_view: Annotated[LiveViewPort | None, Field(description="null: no live view")]
    agents: Annotated[
        list[AgentStatus] | None,
        Field(description="each vehicle's agent process (null: one flight process flies all)"),
    ]

    @model_validator(mode="after")
    def _one_per_vehicle(self) -> Self:
        if len(self.armed) != len(self.uavs):
            raise ValueError(f"armed has {len(self.armed)} entries for {len(self.uavs)} uavs")
        return self


class ProcessStatus(_StatusPart):
    """One of ``serve``'s processes."""

    pid: Annotated[StrictInt | None, Field(description="its process id (null: none running)")]
    alive: StrictBool
    restarts: Annotated[Count, Field(description="times started again")]
    last_exit: Annotated[str | None, Field(description="how it last ended (null: it has not)")]


FaultParameter = StrictInt | StrictFloat | str | list[StrictFloat]


class FaultStatus(_StatusPart):
    """A fault in effect in the simulated world (its times in world seconds)."""

    kind: Annotated[str, Field(description="mocap_silent, link_lost, push, ... (docs/faults.md)")]
    params: Annotated[
        dict[str, FaultParameter],
        Field(description="its kind's fields (body, vehicle, offset_m [m], force_n [N], ...)"),
    ]
    duration_s: Annotated[
        MaybeReal, Field(description="how long it lasts [s] (null: until cleared)")
    ]
    started_s: Annotated[Real, Field(description="when it started, world time [s]")]
    remaining_s: Annotated[
        MaybeReal, Field(description="how long it still lasts [s] (null: until cleared)")
    ]


class StallSummary(_StatusPart):
    """The simulated world's own stalls: moments this computer did not run it."""

    count: Annotated[Count, Field(description="stalls seen")]
    worst_ms: Annotated[Real, Field(description="the longest [ms]")]
    last_ms: Annotated[Real, Field(description="the newest one's length [ms]")]
    last_age_s: Annotated[MaybeReal, Field(description="how long ago it was [s] (null: none)")]


class WorldStatus(_StatusPart):
    """The embedded simulated world, as the API last saw it."""

    embedded: Annotated[StrictBool, Field(description="serve runs a simulated world")]
    reachable: Annotated[StrictBool, Field(description="its process answers")] = False
    time_s: Annotated[MaybeReal, Field(description="its clock [s] (null: not asked yet)")] = None
    faults: Annotated[list[FaultStatus], Field(description="the faults in effect")] = []
    stalls: StallSummary | None = None


class Status(FlightStatus):
    """``GET /api/status`` and each message of the telemetry WebSocket: the flight
    process's latest status, whether it is stale, ``serve``'s processes and the world."""

    stale: Annotated[
        StrictBool,
        Field(description="no telemetry from the flight process for 0.5 s, or not connected"),
    ]
    processes: Annotated[
        dict[str, ProcessStatus], Field(description="serve's processes by name (api, flight, ...)")
    ] = {}
    world: WorldStatus

    @classmethod
    def of(
        cls,
        flight: FlightStatus,
        *,
        stale: bool,
        processes: dict[str, ProcessStatus],
        world: WorldStatus,
    ) -> Status:
        """``flight`` with what the API process knows besides."""
        return cls(**dict(flight), stale=stale, processes=processes, world=world)
