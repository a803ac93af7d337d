"""Flight modes: a table-driven state machine whose default is the safe state.

Operator requests (``arm``, ``takeoff``, ``land``, ``disarm``, ``abort``, ``kill``) and
internal events (``airborne``, ``track``, ``hold``, ``landed``, ``fault``) move the mode
only along ``TRANSITIONS``. A request the table does not allow is refused with a reason
and changes nothing; a *fault* outside the table still ends in ``abort`` (h2's rule:
anything unexpected goes to the safe state). ``abort`` and ``kill`` are always accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


class Mode(Enum):
    DISARMED = "disarmed"
    ARMED = "armed"
    TAKEOFF = "takeoff"
    HOVER = "hover"
    TRACKING = "tracking"
    LANDING = "landing"
    ABORT = "abort"
    KILLED = "killed"

    @property
    def airborne(self) -> bool:
        return self in AIRBORNE


AIRBORNE = frozenset({Mode.TAKEOFF, Mode.HOVER, Mode.TRACKING, Mode.LANDING, Mode.ABORT})

OPERATOR_REQUESTS = ("arm", "disarm", "takeoff", "land", "abort", "kill")

TRANSITIONS: dict[tuple[Mode, str], Mode] = {
    (Mode.DISARMED, "arm"): Mode.ARMED,
    (Mode.ARMED, "disarm"): Mode.DISARMED,
    (Mode.ARMED, "takeoff"): Mode.TAKEOFF,
    (Mode.TAKEOFF, "airborne"): Mode.HOVER,
    (Mode.HOVER, "track"): Mode.TRACKING,
    (Mode.TRACKING, "hold"): Mode.HOVER,
    (Mode.TAKEOFF, "land"): Mode.LANDING,
    (Mode.HOVER, "land"): Mode.LANDING,
    (Mode.TRACKING, "land"): Mode.LANDING,
    (Mode.LANDING, "landed"): Mode.DISARMED,
    (Mode.ABORT, "landed"): Mode.DISARMED,
    (Mode.KILLED, "disarm"): Mode.DISARMED,
    # abort: a coordinated landing from any airborne mode; on the ground it disarms.
    (Mode.DISARMED, "abort"): Mode.DISARMED,
    (Mode.ARMED, "abort"): Mode.DISARMED,
    (Mode.TAKEOFF, "abort"): Mode.ABORT,
    (Mode.HOVER, "abort"): Mode.ABORT,
    (Mode.TRACKING, "abort"): Mode.ABORT,
    (Mode.LANDING, "abort"): Mode.ABORT,
    (Mode.ABORT, "abort"): Mode.ABORT,
    (Mode.KILLED, "abort"): Mode.KILLED,
    # faults detected by the safety monitors
    (Mode.ARMED, "fault"): Mode.DISARMED,
    (Mode.DISARMED, "fault"): Mode.DISARMED,
    (Mode.KILLED, "fault"): Mode.KILLED,
}

_HINTS = {
    "takeoff": "arm first",
    "land": "only an airborne system can land",
    "disarm": "land first (or kill in an emergency)",
    "arm": "only a disarmed system can be armed",
}


@dataclass(frozen=True)
class Transition:
    """The answer to an event: whether it was accepted, the mode after it, and why not."""

    accepted: bool
    mode: Mode
    reason: str = ""


class FlightModes:
    """The current mode and its history of changes (time as an argument)."""

    def __init__(self, mode: Mode = Mode.DISARMED) -> None:
        self.mode = mode
        self.changed_at_s = 0.0

    def handle(self, event: str, now_s: float) -> Transition:
        """Apply ``event``; ``kill`` goes to KILLED from anywhere, a fault outside the table
        to ABORT, anything else outside the table is refused."""
        if event == "kill":
            target: Mode | None = Mode.KILLED
        elif event == "fault" and (self.mode, event) not in TRANSITIONS:
            target = Mode.ABORT
        else:
            target = TRANSITIONS.get((self.mode, event))
        if target is None:
            hint = _HINTS.get(event)
            reason = f"'{event}' is not allowed in mode '{self.mode.value}'" + (
                f": {hint}" if hint else ""
            )
            return Transition(False, self.mode, reason)
        if target is not self.mode:
            self.mode = target
            self.changed_at_s = now_s
        return Transition(True, self.mode)
