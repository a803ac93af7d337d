"""A path's waypoint, a plain value (the API process reads requests without numerics)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Waypoint:
    """One point the bar's centre passes [m, arena frame], with the bar's yaw and the cable
    angle θ_l there [rad] (None: those of the point before)."""

    bar_position_m: tuple[float, float, float]
    bar_yaw_rad: float | None = None
    theta_l_rad: float | None = None
