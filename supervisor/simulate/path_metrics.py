"""How a simulated flight followed its paths, against the world's truth: the bar centre's
3D RMSE against each path's timed position while that moves, and how far the bar passed
each path's end along the path's last direction before the next setpoint began."""

from __future__ import annotations

import math

import numpy as np

from geometry.arrays import FloatArray
from supervisor.flight.paths import PathPlan

_MOVING_MPS = 1e-3  # the path moves while its own speed is above this


class PathTracking:
    """Fed every tick with the core's path progress and the bar's true centre."""

    def __init__(self) -> None:
        self._squared_errors_m2: list[float] = []
        self._overshoot_m: float | None = None
        self._ending: tuple[PathPlan, FloatArray] | None = None  # a path and its last direction

    def update(self, progress: tuple[PathPlan, float] | None, bar_position_m: FloatArray) -> None:
        """``progress``: the path flown now (or last) and the time since it began, as
        ``FlightCore.path_progress`` gives it; ``bar_position_m`` the bar's true centre."""
        if progress is None:
            return
        plan, t_s = progress
        timed = plan.timed
        if t_s <= timed.duration_s:
            sample = timed.sample(t_s)
            if float(np.linalg.norm(sample.velocity_mps)) > _MOVING_MPS:
                error = bar_position_m - sample.position_m
                self._squared_errors_m2.append(float(error @ error))
            return
        if self._ending is None or self._ending[0] is not plan:
            self._ending = plan, _final_direction(plan)
        past = float((bar_position_m - timed.positions_m[-1]) @ self._ending[1])
        self._overshoot_m = max(self._overshoot_m or 0.0, past)

    @property
    def moving_rmse_m(self) -> float | None:
        """The bar centre's 3D RMSE against the paths while they move (None: no path)."""
        if not self._squared_errors_m2:
            return None
        return math.sqrt(sum(self._squared_errors_m2) / len(self._squared_errors_m2))

    @property
    def overshoot_m(self) -> float | None:
        """The furthest the bar passed a path's end along its last direction (≥ 0; None:
        no path ended)."""
        return self._overshoot_m


def _final_direction(plan: PathPlan) -> FloatArray:
    """The unit direction of a path's last motion."""
    velocities = plan.timed.velocities_mps
    speeds = np.linalg.norm(velocities, axis=1)
    moving = np.flatnonzero(speeds > _MOVING_MPS)
    if moving.size == 0:
        return np.zeros(3)
    last: FloatArray = velocities[moving[-1]] / speeds[moving[-1]]
    return last
