"""How fast the connected UAVs lower their attachments in the ``set_down`` phase, once
one vehicle is left to its PX4's failsafe: a target height that descends at a bounded,
rate-limited speed. Pure: the tick core gives it the heights and velocities it sees."""

from __future__ import annotations

from dataclasses import dataclass

# The lost end lower than ours by more than this: it falls with its UAV's failsafe landing
# and reaches the ground first, and its impact jolts the bar. Lowering at 0.4-0.45 m/s then
# took the connected UAV to the 0.5 m/s landing bound and past it (0.49-0.52 m/s; 0.47 at 0.3).
BEHIND_M = 0.1
BEHIND_MPS = 0.3
# The lost UAV descending faster than any set-down rate, its attachment still off the
# ground: its PX4's failsafe landing (0.7 m/s on PX4's defaults) pulls its end down. The
# MPC, levelling the payload, follows a falling end down (0.48-0.51 m/s with an agent
# lowering at 0.3 m/s meanwhile), so the set-down holds its height until that end rests.
FAR_FALLING_MPS = 0.45
FAR_RESTING_M = 0.05  # the lost end this close to its resting height: on the ground


@dataclass(frozen=True)
class SetDownView:
    """What the tick sees of the payload [m, m/s]: the connected attachments' mean height
    (``own_z_m``), the lost UAV's attachment and that UAV's descent, and the height at which
    the attachments rest on the ground."""

    own_z_m: float
    lost_z_m: float
    lost_uav_descent_mps: float
    rest_z_m: float


class SetDownProfile:
    """The target height of the connected attachments, lowered each tick towards the
    ground: at ``descent_mps`` (the abort rate), or ``BEHIND_MPS`` while the lost end is
    lower or ``always_slower`` (an agent cannot tell a lost peer whose end falls from one
    cut off and setting its own end down), and held while the lost end falls. The speed
    changes by at most ``acceleration_mps2``."""

    def __init__(
        self,
        start_z_m: float,
        descent_mps: float,
        acceleration_mps2: float,
        always_slower: bool,
    ) -> None:
        self.target_z_m = start_z_m
        self.speed_mps = 0.0  # the target's descent now (accelerating to its rate)
        self.waiting = False  # held while the lost end falls
        self._descent_mps = descent_mps
        self._acceleration_mps2 = acceleration_mps2
        self._always_slower = always_slower

    def _wanted_mps(self, view: SetDownView) -> float:
        """The descent rate the target heads for now."""
        if self.waiting:
            return 0.0
        behind = view.own_z_m - view.lost_z_m > BEHIND_M
        return BEHIND_MPS if behind or self._always_slower else self._descent_mps

    def step(self, view: SetDownView, dt_s: float) -> tuple[float, float]:
        """Advance by one tick: the target height [m] and its descent [m/s] (0 at rest)."""
        falling = (
            view.lost_uav_descent_mps > FAR_FALLING_MPS
            and view.lost_z_m > view.rest_z_m + FAR_RESTING_M
        )
        if self.waiting and not falling:
            # Dragged below the held height meanwhile: go on down from where the end is,
            # rather than climb back first.
            self.target_z_m = min(self.target_z_m, view.own_z_m)
        self.waiting = falling
        wanted = self._wanted_mps(view)
        step_mps = self._acceleration_mps2 * dt_s
        self.speed_mps = max(self.speed_mps - step_mps, min(self.speed_mps + step_mps, wanted))
        self.target_z_m = max(view.rest_z_m, self.target_z_m - self.speed_mps * dt_s)
        speed = self.speed_mps if self.target_z_m > view.rest_z_m else 0.0
        return self.target_z_m, speed
