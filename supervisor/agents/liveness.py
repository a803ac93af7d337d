"""What an agent does about the others it no longer hears: pure decisions, time an argument.

- The ground station lost (its liveliness token gone): hold the last setpoint (nothing
  queued after it is flown) for ``agents.ground_loss_hold_s``, then land the payload: every
  agent decides the same from the same loss, so they land together.
- A peer lost (its token gone, or its ticks older than ``agents.peer_timeout_s``): its
  vehicle is a lost link to this agent's tick core, which sets the payload down with the
  rest (two vehicles: this one lowers its end): ``supervisor.agents.peer_vehicle``.
- Its own vehicle's link lost: its ticks say so (``AgentTick.own.connected``), and the
  others act as for a lost peer.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum


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
