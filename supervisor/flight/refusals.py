"""Why an operator request is refused in a mode, and what to do next: one table for every
request the mode decides (arm, disarm, take-off, land, setpoints), read by the mode table's
refusals and the setpoint queue's. Abort and kill are never refused; the controller may be
switched in every mode. Pure."""

from __future__ import annotations

from enum import StrEnum

from supervisor.flight.modes import Mode


class Request(StrEnum):
    """The operator requests a mode may refuse."""

    ARM = "arm"
    DISARM = "disarm"
    TAKEOFF = "takeoff"
    LAND = "land"
    SETPOINT = "setpoint"


STATE: dict[Mode, str] = {
    Mode.DISARMED: "disarmed on the ground",
    Mode.ARMED: "armed on the ground",
    Mode.TAKEOFF: "taking off",
    Mode.HOVER: "hovering",
    Mode.TRACKING: "flying to its setpoints",
    Mode.LANDING: "landing",
    Mode.ABORT: "aborting: the abort lands the bar",
    Mode.DISARMING: "landed, disarming: a vehicle is not yet heard disarmed",
    Mode.PX4_LANDING: "each PX4 lands its vehicle on its own, the supervisor sends nothing",
    Mode.KILLED: "the motors were killed",
}

_AFTER_LANDING = "wait until it has landed and disarmed itself, then arm and take off again"
_AFTER_PX4 = (
    "wait until every PX4 has landed and disarmed (the status shows each disarmed), "
    "then arm and take off again"
)
_UNTIL_DISARMED = (
    "wait until every vehicle shows disarmed (the status's armed flags), then arm and take "
    "off again"
)
_IN_THE_AIR = "land first (kill only in an emergency: the vehicles fall)"
_DISARMS_ITSELF = "it disarms itself on the ground (kill only in an emergency: the vehicles fall)"
_ACKNOWLEDGE_KILL = "disarm to acknowledge the kill, then arm and take off again"

NEXT_STEP: dict[tuple[Mode, Request], str] = {
    (Mode.DISARMED, Request.DISARM): "it is disarmed already",
    (Mode.DISARMED, Request.TAKEOFF): "arm first",
    (Mode.DISARMED, Request.LAND): "nothing to land: it is on the ground",
    (Mode.DISARMED, Request.SETPOINT): "arm first (setpoints queued once armed fly after the "
    "take-off)",
    (Mode.ARMED, Request.ARM): "armed already: take off, or disarm",
    (Mode.ARMED, Request.LAND): "nothing to land: disarm instead",
    (Mode.TAKEOFF, Request.ARM): "armed already: wait for the hover",
    (Mode.TAKEOFF, Request.TAKEOFF): "taking off already: wait for the hover",
    (Mode.TAKEOFF, Request.DISARM): _IN_THE_AIR,
    (Mode.HOVER, Request.ARM): "armed and flying already: send setpoints, or land",
    (Mode.HOVER, Request.TAKEOFF): "airborne already: send setpoints, or land",
    (Mode.HOVER, Request.DISARM): _IN_THE_AIR,
    (Mode.TRACKING, Request.ARM): "armed and flying already: send setpoints, or land",
    (Mode.TRACKING, Request.TAKEOFF): "airborne already: send setpoints, or land",
    (Mode.TRACKING, Request.DISARM): _IN_THE_AIR,
    (Mode.LANDING, Request.ARM): _AFTER_LANDING,
    (Mode.LANDING, Request.TAKEOFF): _AFTER_LANDING,
    (Mode.LANDING, Request.LAND): "landing already: it disarms itself on the ground",
    (Mode.LANDING, Request.DISARM): _DISARMS_ITSELF,
    (Mode.LANDING, Request.SETPOINT): _AFTER_LANDING,
    (Mode.ABORT, Request.ARM): _AFTER_LANDING,
    (Mode.ABORT, Request.TAKEOFF): _AFTER_LANDING,
    (Mode.ABORT, Request.LAND): "the abort lands it already: wait until it has disarmed itself",
    (Mode.ABORT, Request.DISARM): _DISARMS_ITSELF,
    (Mode.ABORT, Request.SETPOINT): _AFTER_LANDING,
    (Mode.DISARMING, Request.ARM): _UNTIL_DISARMED,
    (Mode.DISARMING, Request.TAKEOFF): _UNTIL_DISARMED,
    (Mode.DISARMING, Request.LAND): "landed already: it disarms itself",
    (Mode.DISARMING, Request.DISARM): "disarming already (PX4 also disarms by itself on the "
    "ground; kill only if a vehicle stays armed)",
    (Mode.DISARMING, Request.SETPOINT): _UNTIL_DISARMED,
    (Mode.PX4_LANDING, Request.ARM): _AFTER_PX4,
    (Mode.PX4_LANDING, Request.TAKEOFF): _AFTER_PX4,
    (Mode.PX4_LANDING, Request.LAND): "each PX4 lands already: wait until both have disarmed",
    (Mode.PX4_LANDING, Request.DISARM): "each PX4 disarms on the ground by itself (kill only "
    "in an emergency: the vehicles fall)",
    (Mode.PX4_LANDING, Request.SETPOINT): _AFTER_PX4,
    (Mode.KILLED, Request.ARM): _ACKNOWLEDGE_KILL,
    (Mode.KILLED, Request.TAKEOFF): _ACKNOWLEDGE_KILL,
    (Mode.KILLED, Request.LAND): _ACKNOWLEDGE_KILL,
    (Mode.KILLED, Request.SETPOINT): _ACKNOWLEDGE_KILL,
}


def refusal(mode: Mode, request: Request) -> str:
    """The refusal of ``request`` in ``mode``: the mode, what the system is doing, and the
    next step (``NEXT_STEP``; a pair missing from it is a bug the tests catch)."""
    return (
        f"'{request.value}' is not allowed in mode '{mode.value}' ({STATE[mode]}): "
        f"{NEXT_STEP[(mode, request)]}"
    )
