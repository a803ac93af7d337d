"""Flight phases: what the tick core does inside a mode, and the only ways between them.

* ``ground`` — motors off (disarmed, armed, killed).
* ``climb`` — take-off: each UAV flies alone (``uav_pd``) to just above its bar end until
  the cables are taut; ``lift`` — the MPC raises the bar to the take-off height.
* ``hover`` / ``tracking`` — the MPC regulates to the rate-limited reference.
* ``lower`` — landing or abort: the MPC sets the bar down; ``descend`` — each UAV flies
  alone, moves clear of its bar end and descends; motors stop on the ground.
* ``set_down`` — one vehicle's link lost with the bar hanging: the connected UAV's own
  (decentralized) MPC sets its bar end down while the lost one is left to its PX4's
  failsafe landing; then ``descend``.
* ``px4`` — blind: each PX4 lands on its own (AUTO.LAND); the supervisor sends nothing. A
  flight process also starts here, until every vehicle is heard disarmed.

A landing or abort that starts while the UAVs still fly alone (``climb``) goes straight to
``descend``: the bar has not been lifted. A change outside ``PHASE_TRANSITIONS`` is a bug of
the tick core and raises ``PhaseError``.
"""

from __future__ import annotations

from enum import StrEnum

from supervisor.errors import LocalError


class Phase(StrEnum):
    GROUND = "ground"
    CLIMB = "climb"
    LIFT = "lift"
    HOVER = "hover"
    TRACKING = "tracking"
    LOWER = "lower"
    SET_DOWN = "set_down"
    DESCEND = "descend"
    PX4 = "px4"


_AIRBORNE = (
    Phase.CLIMB,
    Phase.LIFT,
    Phase.HOVER,
    Phase.TRACKING,
    Phase.LOWER,
    Phase.SET_DOWN,
    Phase.DESCEND,
    Phase.PX4,
)

PHASE_TRANSITIONS: frozenset[tuple[Phase, Phase]] = frozenset(
    {
        (Phase.GROUND, Phase.CLIMB),
        (Phase.GROUND, Phase.HOVER),  # a simulation that starts in the air
        (Phase.CLIMB, Phase.LIFT),
        (Phase.CLIMB, Phase.DESCEND),
        (Phase.LIFT, Phase.HOVER),
        (Phase.LIFT, Phase.LOWER),
        (Phase.HOVER, Phase.TRACKING),
        (Phase.HOVER, Phase.LOWER),
        (Phase.TRACKING, Phase.HOVER),
        (Phase.TRACKING, Phase.LOWER),
        (Phase.LOWER, Phase.DESCEND),
        *((phase, Phase.SET_DOWN) for phase in (Phase.LIFT, Phase.HOVER, Phase.TRACKING)),
        (Phase.LOWER, Phase.SET_DOWN),
        (Phase.SET_DOWN, Phase.DESCEND),
        *((phase, Phase.GROUND) for phase in _AIRBORNE),  # landed, or killed
        *((phase, Phase.PX4) for phase in _AIRBORNE),  # blind
        (Phase.GROUND, Phase.PX4),  # a flight process starting: the vehicles not yet heard
        *((phase, phase) for phase in Phase),  # e.g. an abort during a landing
    }
)


class PhaseError(LocalError):
    """The tick core tried a phase change the table does not have."""


def next_phase(current: Phase, target: Phase) -> Phase:
    """``target`` when the table allows the change from ``current``."""
    if (current, target) not in PHASE_TRANSITIONS:
        raise PhaseError(f"no phase change from {current.value!r} to {target.value!r}")
    return target
