"""The equilibrium a cable angle θ_l implies, as plain numbers (CLI, API, dashboard)."""

from __future__ import annotations

from typing import Any

from controllers.equilibria import Reference, bar_equilibrium, theta_f_closed_form
from controllers.params import BarSystemParams
from supervisor.flight.feasibility import SetpointBounds, equilibrium_problems, theta_l_problem


def equilibrium_summary(
    params: BarSystemParams, theta_l_rad: float, bounds: SetpointBounds | None = None
) -> dict[str, Any]:
    """θ_f of Proposition 1 (mean UAV mass), and per UAV/cable the thrust [N], tension [N],
    tilt and cable angle [rad] and position [m] of the general equilibrium with the bar
    along x at the origin; with ``bounds``, ``refusals``: why a setpoint at this θ_l would
    be refused, in words (empty: it would be taken, the arena aside). Raises
    ``EquilibriumError`` for θ_l outside [0, π/2)."""
    eq = bar_equilibrium(params, Reference((0.0, 0.0, 0.0), 0.0, (0.0, 0.0), theta_l_rad))
    mean_uav_mass = (params.uavs[0].mass_kg + params.uavs[1].mass_kg) / 2.0
    refusals: dict[str, Any] = {}
    if bounds is not None:
        too_steep = theta_l_problem(theta_l_rad, bounds)
        problems = [too_steep] if too_steep else []
        refusals["refusals"] = problems + equilibrium_problems(eq, bounds)
    return {
        "theta_l": theta_l_rad,
        "theta_f": theta_f_closed_form(theta_l_rad, mean_uav_mass, params.bar_mass_kg),
        "thrust": list(eq.thrusts_n),
        "tension": list(eq.tensions_n),
        "uav_positions": [eq.uav_position(i).tolist() for i in (1, 2)],
        "theta_f_per_uav": list(eq.theta_f_rad),
        "theta_l_per_cable": list(eq.theta_l_rad),
        "symmetric": params.is_symmetric,
        **refusals,
    }
