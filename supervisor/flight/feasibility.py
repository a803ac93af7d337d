"""Setpoint feasibility: can the vehicles hold the equilibrium a setpoint asks for?

One place for the bounds every setpoint is checked against (the tick core, the API before
it forwards, scenarios before they fly, the dashboard's preview through
``GET /api/equilibria``): θ_l at most a configured maximum, and each UAV's equilibrium
thrust and tilt inside the thrust range and below the safety monitor's abort tilt, each
with a margin left for the transients of getting there. Each problem names its bound and
by how much it is missed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.formation_equilibria import FormationEquilibrium


@dataclass(frozen=True)
class FeasibilitySettings:
    """The configurable part: the largest θ_l [rad], the thrust margin as a fraction of the
    thrust range's top (kept from both ends of the range) and the tilt margin [rad] below
    the abort tilt."""

    max_theta_l_rad: float = math.radians(75.0)
    thrust_margin: float = 0.10
    tilt_margin_rad: float = math.radians(10.0)

    def __post_init__(self) -> None:
        if not 0.0 <= self.max_theta_l_rad < math.pi / 2.0:
            raise ValueError("max_theta_l_rad must lie in [0, π/2)")
        if not 0.0 <= self.thrust_margin < 0.5:
            raise ValueError("thrust_margin must lie in [0, 0.5)")
        if not 0.0 <= self.tilt_margin_rad < math.pi / 2.0:
            raise ValueError("tilt_margin_rad must lie in [0, π/2)")


@dataclass(frozen=True)
class SetpointBounds:
    """What a setpoint's equilibrium must respect: the thrust range of the input set U
    [N], the safety monitor's abort tilt [rad] and the margins and θ_l maximum."""

    thrust_min_n: float
    thrust_max_n: float
    max_tilt_rad: float
    settings: FeasibilitySettings = FeasibilitySettings()

    @property
    def thrust_band_n(self) -> tuple[float, float]:
        """The equilibrium thrusts accepted: the range less its margin at both ends."""
        margin = self.settings.thrust_margin * self.thrust_max_n
        return self.thrust_min_n + margin, self.thrust_max_n - margin

    @property
    def tilt_allowed_rad(self) -> float:
        """The largest equilibrium tilt accepted: the abort tilt less its margin."""
        return self.max_tilt_rad - self.settings.tilt_margin_rad


def theta_l_problem(theta_l_rad: float, bounds: SetpointBounds) -> str | None:
    """Why θ_l is not flown (None: within the configured maximum)."""
    limit = bounds.settings.max_theta_l_rad
    if theta_l_rad <= limit:
        return None
    return (
        f"θ_l {math.degrees(theta_l_rad):.1f}° exceeds the maximum "
        f"{math.degrees(limit):.1f}° by {math.degrees(theta_l_rad - limit):.1f}°"
    )


def equilibrium_problems(eq: FormationEquilibrium, bounds: SetpointBounds) -> list[str]:
    """Why the vehicles cannot hold ``eq`` (empty: they can): each UAV's thrust and tilt
    against their bounds, in words naming the bound and the excess."""
    problems = []
    low, high = bounds.thrust_band_n
    percent = f"{bounds.settings.thrust_margin * 100:.0f} %"
    tilt_limit = bounds.tilt_allowed_rad
    for k in range(len(eq.thrusts_n)):
        who = f"UAV {k + 1}"
        thrust = eq.thrusts_n[k]
        if thrust > high:
            problems.append(
                f"{who}'s equilibrium thrust {thrust:.1f} N is above the "
                f"{bounds.thrust_max_n:.1f} N limit less its {percent} margin ({high:.1f} N) "
                f"by {thrust - high:.1f} N"
            )
        elif thrust < low:
            problems.append(
                f"{who}'s equilibrium thrust {thrust:.1f} N is below the "
                f"{bounds.thrust_min_n:.1f} N minimum plus its {percent} margin ({low:.1f} N) "
                f"by {low - thrust:.1f} N"
            )
        tilt = eq.tilts_rad[k]
        if tilt > tilt_limit:
            problems.append(
                f"{who}'s equilibrium tilt {math.degrees(tilt):.1f}° is above the "
                f"{math.degrees(bounds.max_tilt_rad):.1f}° abort tilt less its "
                f"{math.degrees(bounds.settings.tilt_margin_rad):.1f}° margin "
                f"({math.degrees(tilt_limit):.1f}°) by {math.degrees(tilt - tilt_limit):.1f}°"
            )
    return problems
