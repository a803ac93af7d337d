"""External loads on the plant's bodies: a steady push, or a gust that rises and falls.

A load is a force at a body's centre of mass and a torque, both in the ENU world frame, in
effect from ``start_s`` for ``duration_s`` (None: until removed) on the plant's clock.
``steady`` holds them; ``gust`` scales them by (1 − cos 2π s)/2 over the duration (s the
elapsed fraction): zero at both ends, the full force and torque at the middle, a smooth
shape whose impulse is half the steady one's. Mind a torque about the bar's own axis: its
axial inertia is tiny (a thin tube, m r²), so even 0.1 N m spins it up to rates the 1 kHz
integrator does not follow within seconds once it is off the ground.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, Literal

from geometry.formation import MAX_VEHICLES

BODIES: Final = ("bar", "payload", *(f"uav{i}" for i in range(1, MAX_VEHICLES + 1)))
"""Every body a plant may have; a plant refuses a load on one it does not have."""
Profile = Literal["steady", "gust"]


@dataclass(frozen=True)
class ExternalLoad:
    """A force [N] and torque [N m] (world frame) on ``body`` from ``start_s`` [s]; the
    body is "uav1" … "uavN", or the payload: "bar", or "payload" for one that is not."""

    body: str
    force_n: tuple[float, float, float]
    torque_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    start_s: float = 0.0
    duration_s: float | None = None
    profile: Profile = "steady"

    def __post_init__(self) -> None:
        if self.body not in BODIES:
            raise ValueError(f"body must be one of {BODIES}, got {self.body!r}")
        values = (*self.force_n, *self.torque_nm, self.start_s)
        if len(self.force_n) != 3 or len(self.torque_nm) != 3:
            raise ValueError("force_n and torque_nm take three numbers each (world frame)")
        if not all(math.isfinite(v) for v in values):
            raise ValueError("a load's force, torque and start must be finite")
        if self.duration_s is not None and not (
            math.isfinite(self.duration_s) and self.duration_s > 0.0
        ):
            raise ValueError(f"duration_s must be a positive number, got {self.duration_s}")
        if self.profile not in ("steady", "gust"):
            raise ValueError(f"profile must be 'steady' or 'gust', got {self.profile!r}")
        if self.profile == "gust" and self.duration_s is None:
            raise ValueError("a gust needs a duration_s")

    @property
    def ends_s(self) -> float:
        """When it stops acting (inf: until removed)."""
        return math.inf if self.duration_s is None else self.start_s + self.duration_s

    def scale(self, t_s: float) -> float:
        """The fraction of the force and torque acting at ``t_s``."""
        if not self.start_s <= t_s < self.ends_s:
            return 0.0
        if self.profile == "steady" or self.duration_s is None:
            return 1.0
        return 0.5 * (1.0 - math.cos(2.0 * math.pi * (t_s - self.start_s) / self.duration_s))
