"""What an agent does about the others it no longer hears: pure decisions, time an argument.

- The ground station lost (its liveliness token gone): hold the last setpoint (nothing
  queued after it is flown) for ``agents.ground_loss_hold_s``, then land the payload: every
  agent decides the same from the same loss, so they land together.
- A peer lost (its token gone, or its ticks older than ``agents.peer_timeout_s``): its
  vehicle is a lost link to this agent's tick core, which sets the payload down with the
  rest (two vehicles: this one lowers its end): ``supervisor.agents.peer_vehicle``.
- Its own vehicle's link lost: its ticks say so (``AgentTick.own.connected``), and the
  others act as for a lost peer.
- A peer past its active setpoint: it ends its own too (``behind_the_peers``).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from enum import Enum

from supervisor.agents.messages import AgentTick


class GroundAction(Enum):
    FLY = "fly"  # the ground station is heard
    HOLD = "hold"  # lost: the last setpoint is held, nothing queued after it flown
    LAND = "land"  # lost for longer than the hold: land the payload


@dataclass(frozen=True)
class GroundWatch:
    """Since when the ground station is lost (None: it is heard)."""

    lost_since_s: float | None = None

    def heard(self, alive: bool, now_s: float) -> GroundWatch:
        """The watch after learning whether the ground station is alive at ``now_s``."""
        if alive:
            return GroundWatch(None)
        return self if self.lost_since_s is not None else GroundWatch(now_s)

    def action(self, now_s: float, hold_s: float) -> GroundAction:
        if self.lost_since_s is None:
            return GroundAction.FLY
        return GroundAction.HOLD if now_s - self.lost_since_s < hold_s else GroundAction.LAND


def behind_the_peers(queued: int, finished: int, peers: Iterable[AgentTick | None]) -> bool:
    """Whether a heard peer given the same setpoints (``queued`` of them) has ended more of
    them than this agent's ``finished``: each agent ends a setpoint when it sees it reached
    and held, on an estimate of its own, so one may see it a tick before another; the one
    behind then ends its active setpoint too, and the agents' references never part."""
    return any(
        tick is not None and tick.setpoints_queued == queued and tick.setpoints_finished > finished
        for tick in peers
    )
