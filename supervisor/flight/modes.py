"""Flight modes: a table-driven state machine whose default is the safe state.

Operator requests (``arm``, ``takeoff``, ``land``, ``disarm``, ``abort``, ``kill``) and
internal events (``airborne``, ``track``, ``hold``, ``landed``, ``disarmed``, ``fault``,
``blind``) move
the mode only along ``TRANSITIONS``. A request the table does not allow is refused with a reason
and changes nothing; a *fault* outside the table still ends in ``abort`` (h2's rule:
anything unexpected goes to the safe state). ``abort`` and ``kill`` are always accepted.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, StrEnum


class Mode(Enum):
    DISARMED = "disarmed"
    ARMED = "armed"
    TAKEOFF = "takeoff"
    HOVER = "hover"
    TRACKING = "tracking"
    LANDING = "landing"
    ABORT = "abort"
    DISARMING = "disarming"  # landed: the motors are stopped until every vehicle says disarmed
    PX4_LANDING = "px4_landing"  # blind: each PX4 lands on its own, the supervisor sends nothing
    KILLED = "killed"

    @property
    def airborne(self) -> bool:
        return self in AIRBORNE


AIRBORNE = frozenset(
    {Mode.TAKEOFF, Mode.HOVER, Mode.TRACKING, Mode.LANDING, Mode.ABORT, Mode.PX4_LANDING}
)


class Event(StrEnum):
    """What moves the mode: the operator's requests, then the tick core's own events."""

    ARM = "arm"
    DISARM = "disarm"
    TAKEOFF = "takeoff"
    LAND = "land"
    ABORT = "abort"
    KILL = "kill"
    AIRBORNE = "airborne"  # take-off reached its height
    TRACK = "track"  # a setpoint became active
    HOLD = "hold"  # the queue ran empty
    LANDED = "landed"  # motors stopped on the ground
    DISARMED = "disarmed"  # every vehicle is heard disarmed after a landing
    FAULT = "fault"  # a safety monitor asked for a landing
    BLIND = "blind"  # the mocap is lost: the vehicles are handed to PX4's own landing


OPERATOR_REQUESTS = (
    Event.ARM,
    Event.DISARM,
    Event.TAKEOFF,
    Event.LAND,
    Event.ABORT,
    Event.KILL,
)

TRANSITIONS: dict[tuple[Mode, Event], Mode] = {
    (Mode.DISARMED, Event.ARM): Mode.ARMED,
    (Mode.ARMED, Event.DISARM): Mode.DISARMED,
    (Mode.ARMED, Event.TAKEOFF): Mode.TAKEOFF,
    (Mode.TAKEOFF, Event.AIRBORNE): Mode.HOVER,
    (Mode.HOVER, Event.TRACK): Mode.TRACKING,
    (Mode.TRACKING, Event.HOLD): Mode.HOVER,
    (Mode.TAKEOFF, Event.LAND): Mode.LANDING,
    (Mode.HOVER, Event.LAND): Mode.LANDING,
    (Mode.TRACKING, Event.LAND): Mode.LANDING,
    # Landed, the system is disarmed only once every vehicle says so: until then the
    # status must not say a safer state than the vehicles are in.
    (Mode.LANDING, Event.LANDED): Mode.DISARMING,
    (Mode.ABORT, Event.LANDED): Mode.DISARMING,
    (Mode.DISARMING, Event.DISARMED): Mode.DISARMED,
    (Mode.DISARMING, Event.ABORT): Mode.DISARMING,
    (Mode.DISARMING, Event.FAULT): Mode.DISARMING,
    (Mode.KILLED, Event.DISARM): Mode.DISARMED,
    # abort: a coordinated landing from any airborne mode; on the ground it disarms.
    (Mode.DISARMED, Event.ABORT): Mode.DISARMED,
    (Mode.ARMED, Event.ABORT): Mode.DISARMED,
    (Mode.TAKEOFF, Event.ABORT): Mode.ABORT,
    (Mode.HOVER, Event.ABORT): Mode.ABORT,
    (Mode.TRACKING, Event.ABORT): Mode.ABORT,
    (Mode.LANDING, Event.ABORT): Mode.ABORT,
    (Mode.ABORT, Event.ABORT): Mode.ABORT,
    (Mode.KILLED, Event.ABORT): Mode.KILLED,
    # blind (mocap lost beyond the coast limit): nothing the supervisor commands is
    # better than PX4's own landing, so nothing leaves it, not even an abort.
    **{(mode, Event.BLIND): Mode.PX4_LANDING for mode in AIRBORNE},
    (Mode.PX4_LANDING, Event.ABORT): Mode.PX4_LANDING,
    (Mode.PX4_LANDING, Event.FAULT): Mode.PX4_LANDING,
    (Mode.PX4_LANDING, Event.LANDED): Mode.DISARMED,  # every PX4 landed and disarmed
    # faults detected by the safety monitors
    (Mode.ARMED, Event.FAULT): Mode.DISARMED,
    (Mode.DISARMED, Event.FAULT): Mode.DISARMED,
    (Mode.KILLED, Event.FAULT): Mode.KILLED,
}


@dataclass(frozen=True)
class Transition:
    """The answer to an event: whether it was accepted, the mode after it, and why not."""

    accepted: bool
    mode: Mode
    reason: str = ""


FLIGHT_ENDINGS = frozenset({Mode.ABORT, Mode.PX4_LANDING, Mode.KILLED})
"""The modes a flight can end in other than its landing."""


@dataclass(frozen=True)
class FlightEnding:
    """How the last flight since an arm ended: ``LANDING`` (the operator's landing), or
    the last of ``FLIGHT_ENDINGS`` it passed through; ``at_s`` when it was disarmed."""

    mode: Mode
    at_s: float


class FlightModes:
    """The current mode and its history of changes (time as an argument)."""

    def __init__(self, mode: Mode = Mode.DISARMED) -> None:
        self.mode = mode
        self.changed_at_s = 0.0
        self.last_flight: FlightEnding | None = None
        """How the last flight ended, as far as these modes saw it go (None: none seen, or
        armed since): made in ``px4_landing`` (a flight process waiting for vehicles a
        dead one left to PX4), they see that landing end nothing."""
        self._ending: Mode | None = None  # how the flight under way is ending

    def handle(self, event: Event, now_s: float) -> Transition:
        """Apply ``event``; ``kill`` goes to KILLED from anywhere, a fault outside the table
        to ABORT, anything else outside the table is refused."""
        if event is Event.KILL:
            target: Mode | None = Mode.KILLED
        elif event is Event.FAULT and (self.mode, event) not in TRANSITIONS:
            target = Mode.ABORT
        else:
            target = TRANSITIONS.get((self.mode, event))
        if target is None:
            reason = f"'{event.value}' is not allowed in mode '{self.mode.value}'"
            return Transition(False, self.mode, reason)
        if target is not self.mode:
            self._follow_the_flight(target, now_s)
            self.mode = target
            self.changed_at_s = now_s
        return Transition(True, self.mode)

    def _follow_the_flight(self, target: Mode, now_s: float) -> None:
        if target is Mode.ARMED:
            self._ending, self.last_flight = None, None
        elif target in FLIGHT_ENDINGS or (target is Mode.LANDING and self._ending is None):
            self._ending = target
        elif target is Mode.DISARMED and self._ending is not None:
            self.last_flight, self._ending = FlightEnding(self._ending, now_s), None
