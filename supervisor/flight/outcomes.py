"""A request's outcome, read from the status: the CLI's ``--wait`` (polling ``GET
/api/status``, ``supervisor/cli/awaiting.py``) and the REST API's ``?wait_s=`` (reading the
flight process's telemetry) decide alike.

A ``Goal`` reads one status (``supervisor.flight.status.Status``) and says whether the
system is there (``REACHED``), can no longer get there (``FAILED``, with the reason: the
newest notice since the request, such as an abort's or PX4's refusal, else the mode it
ended in), or is on its way (None).
Pure: ``judge`` and ``Staleness`` take the times as arguments.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

from supervisor.flight.modes import Mode

if TYPE_CHECKING:  # the terminal client imports this module, never pydantic at its start
    from supervisor.flight.operator_requests import SetpointFields
    from supervisor.flight.status import Status

# Mocap or the flight process silent this long while waiting: say so rather than wait on.
STALE_LIMIT_S = 3.0
# The poll after which a setpoint never seen in the queue counts as flown (see _Setpoint).
UNSEEN_SETPOINT_S = 1.0
COMING_DOWN = frozenset(
    {Mode.LANDING, Mode.ABORT, Mode.PX4_LANDING, Mode.DISARMING, Mode.DISARMED, Mode.KILLED}
)
AIRBORNE_UNDER_THE_MPC = frozenset({Mode.HOVER, Mode.TRACKING})


class Verdict(Enum):
    REACHED = "reached"
    FAILED = "failed"


@dataclass(frozen=True)
class Outcome:
    """How a wait ended, in words."""

    verdict: Verdict
    message: str

    @property
    def reached(self) -> bool:
        return self.verdict is Verdict.REACHED


def notices_since(status: Status, elapsed_s: float) -> list[str]:
    """The notices made since the request (sent ``elapsed_s`` ago), oldest first."""
    return [notice.message for notice in status.notices if notice.age_s <= elapsed_s]


def _failed(status: Status, elapsed_s: float, what: str) -> Outcome:
    notices = notices_since(status, elapsed_s)
    reason = notices[-1] if notices else f"the system is in mode {status.mode.value}"
    return Outcome(Verdict.FAILED, f"{what}: {reason}")


Goal = Callable[["Status", float], Outcome | None]


def armed(status: Status, elapsed_s: float) -> Outcome | None:
    """``arm``: armed, and every PX4 says so; a vehicle's notice (it refused, or disarmed
    by itself) is a failure. (The REST answer already carries PX4's refusal to arm.)"""
    if status.mode is Mode.ARMED and all(status.armed):
        return Outcome(Verdict.REACHED, "armed")
    if notices_since(status, elapsed_s):
        return _failed(status, elapsed_s, "not armed")
    return None


def hovering(status: Status, elapsed_s: float) -> Outcome | None:
    """``takeoff``: airborne and hovering under the MPC (tracking counts: the queue, filled
    while armed, took over right after the hover began); an abort, a landing, PX4's
    landing or the ground is a failure."""
    if status.mode in AIRBORNE_UNDER_THE_MPC:
        return Outcome(Verdict.REACHED, f"airborne, {status.mode.value}")
    if status.mode in COMING_DOWN:
        return _failed(status, elapsed_s, "take-off failed")
    return None


def landed(status: Status, elapsed_s: float) -> Outcome | None:
    """``land``: on the ground and disarmed (also after an abort or PX4's own landing, said
    in the message); killed is a failure (the motors were stopped in the air)."""
    if status.mode is Mode.DISARMED and not any(status.armed):
        notices = notices_since(status, elapsed_s)
        return Outcome(
            Verdict.REACHED, "landed and disarmed" + (f" ({notices[-1]})" if notices else "")
        )
    if status.mode is Mode.KILLED:
        return _failed(status, elapsed_s, "not landed")
    return None


def controller(name: str) -> Goal:
    """``mode NAME``: the status shows ``NAME`` flying."""

    def switched(status: Status, elapsed_s: float) -> Outcome | None:
        if status.controller == name:
            return Outcome(Verdict.REACHED, f"controller {name}")
        return None

    return switched


def _same_setpoint(shown: SetpointFields, wanted: SetpointFields) -> bool:
    """The same bar position, bar yaw, θ_l and hold (the UAV yaws are filled in when
    shown)."""
    pairs = [
        *zip(shown.bar_position, wanted.bar_position, strict=True),
        (shown.bar_yaw, wanted.bar_yaw),
        (shown.theta_l, wanted.theta_l),
        (shown.hold_s, wanted.hold_s),
    ]
    return all(math.isclose(a, b, abs_tol=1e-9) for a, b in pairs)


@dataclass
class _Setpoint:
    """``setpoint``: flown, i.e. gone from the queue (reached and held) after having been
    seen in it, or never seen while nothing is queued for a second (reached and held
    between two polls); the system coming down first is a failure."""

    wanted: SetpointFields
    seen: bool = field(default=False)

    def __call__(self, status: Status, elapsed_s: float) -> Outcome | None:
        if status.mode in COMING_DOWN:
            return _failed(status, elapsed_s, "setpoint not flown")
        active = status.setpoints.active
        shown = [*([active] if active is not None else []), *status.setpoints.queued]
        if any(_same_setpoint(entry, self.wanted) for entry in shown):
            self.seen = True
            return None
        idle = status.mode is Mode.HOVER and not shown
        if self.seen or (idle and elapsed_s > UNSEEN_SETPOINT_S):
            return Outcome(Verdict.REACHED, "setpoint reached and held")
        return None


def setpoint_flown(wanted: SetpointFields) -> Goal:
    """The goal of ``setpoint`` for the setpoint that was queued."""
    return _Setpoint(wanted)


def _same_points(shown: Sequence[Sequence[float]], wanted: Sequence[Sequence[float]]) -> bool:
    """The same waypoints (x, y, z) [m], in the same order."""
    return len(shown) == len(wanted) and all(
        math.isclose(a, b, abs_tol=1e-9)
        for point, other in zip(shown, wanted, strict=True)
        for a, b in zip(point, other, strict=True)
    )


@dataclass
class _Path:
    """``path``: flown, i.e. its end reached and held: the status's ``path`` seen with
    these waypoints and then gone, or never seen while nothing is queued for a second (flown
    between two polls); the system coming down first is a failure."""

    waypoints_m: list[list[float]]
    seen: bool = field(default=False)

    def __call__(self, status: Status, elapsed_s: float) -> Outcome | None:
        if status.mode in COMING_DOWN:
            return _failed(status, elapsed_s, "path not flown")
        shown = status.path
        if shown is not None and _same_points(shown.waypoints, self.waypoints_m):
            self.seen = True
            return None
        setpoints = status.setpoints
        idle = status.mode is Mode.HOVER and setpoints.active is None and not setpoints.queued
        if self.seen or (idle and elapsed_s > UNSEEN_SETPOINT_S):
            return Outcome(Verdict.REACHED, "path flown, its end reached and held")
        return None


def path_flown(waypoints_m: Sequence[Sequence[float]]) -> Goal:
    """The goal of ``path`` for the path through ``waypoints_m`` (each (x, y, z) [m])."""
    return _Path([list(point) for point in waypoints_m])


def judge(
    goal: Goal, status: Status, elapsed_s: float, stale_for_s: float | None, timeout_s: float
) -> Outcome | None:
    """One status, read ``elapsed_s`` after the request: its outcome, or None to read on.
    ``stale_for_s``: how long the status has been stale (None: it is fresh)."""
    if stale_for_s is not None and stale_for_s > STALE_LIMIT_S:
        return Outcome(
            Verdict.FAILED,
            f"the flight process has not reported for {STALE_LIMIT_S:.0f} s "
            "(status stale): outcome unknown",
        )
    if stale_for_s is None:
        outcome = goal(status, elapsed_s)
        if outcome is not None:
            return outcome
    if elapsed_s > timeout_s:
        return Outcome(
            Verdict.FAILED,
            f"not there after {timeout_s:g} s (mode {status.mode.value}, "
            f"phase {status.phase.value})",
        )
    return None


class Staleness:
    """Since when the statuses read have been stale."""

    def __init__(self) -> None:
        self.since_s: float | None = None

    def stale_for_s(self, status: Status, now_s: float) -> float | None:
        if not status.stale:
            self.since_s = None
            return None
        self.since_s = now_s if self.since_s is None else self.since_s
        return now_s - self.since_s
