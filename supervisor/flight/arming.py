"""Every reason an arm would be refused right now, in words with the next step: the mode,
the motion capture and the resting pose (the tick core's pre-arm checks), each vehicle's
link and arming state, and the log folder's free space. The status's ``arm_blocked_by``
and the flight process's arm read this one list, so that an arm sent the moment it is
empty is taken. Pure."""

from __future__ import annotations

from collections.abc import Sequence

from supervisor.flight.core import FlightCore
from supervisor.flight.modes import TRANSITIONS, Event, Mode
from supervisor.flight.refusals import Request, refusal
from supervisor.vehicles.types import VehicleView


def vehicle_problems(vehicles: Sequence[VehicleView]) -> list[str]:
    """What keeps the vehicles from being armed by the supervisor: one not heard yet (its
    arming state unknown), or armed already (in PX4's own failsafe landing after a flight
    process died, or armed by someone else: not the supervisor's to fly)."""
    problems = []
    for i, view in enumerate(vehicles, start=1):
        if not view.connected:
            problems.append(
                f"UAV {i} is not heard (no heartbeat): wait a second after start, or check its link"
            )
        elif view.armed:
            problems.append(
                f"UAV {i} is armed already (PX4 in {view.px4_mode}): wait until it has "
                "landed and disarmed"
            )
    return problems


def arm_blockers(
    core: FlightCore, vehicles: Sequence[VehicleView], log_problem: str | None = None
) -> list[str]:
    """Why an arm would be refused now (empty: it would be taken)."""
    mode = core.modes.mode
    if (mode, Event.ARM) not in TRANSITIONS:
        refused = [refusal(mode, Request.ARM)]
        # Until every vehicle is heard disarmed, the one not heard or still armed is why.
        waiting = mode in (Mode.PX4_LANDING, Mode.DISARMING)
        return refused + vehicle_problems(vehicles) if waiting else refused
    problems = core.not_ready_to_arm() + vehicle_problems(vehicles)
    return problems + ([log_problem] if log_problem is not None else [])
