"""The equilibrium a cable angle θ_l implies, as plain numbers (CLI, API, dashboard)."""

from __future__ import annotations

from typing import Any

from controllers.equilibria import Reference, bar_equilibrium, theta_f_closed_form
from controllers.params import BarSystemParams


def equilibrium_summary(params: BarSystemParams, theta_l_rad: float) -> dict[str, Any]:
    """θ_f of Proposition 1 (mean UAV mass), and per UAV/cable the thrust [N], tension [N],
    tilt and cable angle [rad] and position [m] of the general equilibrium with the bar
    along x at the origin. Raises ``EquilibriumError`` for θ_l outside [0, π/2)."""
    eq = bar_equilibrium(params, Reference((0.0, 0.0, 0.0), 0.0, (0.0, 0.0), theta_l_rad))
    mean_uav_mass = (params.uavs[0].mass_kg + params.uavs[1].mass_kg) / 2.0
    return {
        "theta_l": theta_l_rad,
        "theta_f": theta_f_closed_form(theta_l_rad, mean_uav_mass, params.bar_mass_kg),
        "thrust": list(eq.thrusts_n),
        "tension": list(eq.tensions_n),
        "uav_positions": [eq.uav_position(i).tolist() for i in (1, 2)],
        "theta_f_per_uav": list(eq.theta_f_rad),
        "theta_l_per_cable": list(eq.theta_l_rad),
        "symmetric": params.is_symmetric,
    }
