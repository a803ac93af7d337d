"""The equilibrium a cable angle θ_l implies, as plain numbers (CLI, API, dashboard)."""

from __future__ import annotations

from typing import Any

from controllers.equilibria import theta_f_closed_form
from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from supervisor.flight.feasibility import SetpointBounds, equilibrium_problems, theta_l_problem


def equilibrium_summary(
    params: FormationParams, theta_l_rad: float, bounds: SetpointBounds | None = None
) -> dict[str, Any]:
    """θ_f of Proposition 1 (mean UAV mass, its N-UAV form), and per UAV/cable the thrust
    [N], tension [N], tilt and cable angle [rad] and position [m] of the general
    equilibrium at the cone angle ``theta_l_rad``, the payload at the origin at yaw 0 (a
    bar along x); with ``bounds``, ``refusals``: why a setpoint at this θ_l would be
    refused, in words (empty: it would be taken, the arena aside). Raises
    ``EquilibriumError`` for θ_l outside [0, π/2)."""
    layout = params.layout
    eq = formation_equilibrium(
        params,
        FormationReference((0.0, 0.0, 0.0), 0.0, (0.0,) * layout.n_vehicles, theta_l_rad),
    )
    mean_uav_mass = sum(uav.mass_kg for uav in params.uavs) / layout.n_vehicles
    refusals: dict[str, Any] = {}
    if bounds is not None:
        too_steep = theta_l_problem(theta_l_rad, bounds)
        problems = [too_steep] if too_steep else []
        refusals["refusals"] = problems + equilibrium_problems(eq, bounds)
    return {
        "theta_l": theta_l_rad,
        "theta_f": theta_f_closed_form(
            theta_l_rad, mean_uav_mass, params.payload.mass_kg, layout.n_vehicles
        ),
        "thrust": list(eq.thrusts_n),
        "tension": list(eq.tensions_n),
        "uav_positions": [eq.uav_position(i).tolist() for i in layout.vehicles],
        "theta_f_per_uav": list(eq.tilts_rad),
        "theta_l_per_cable": list(eq.cable_angles_rad),
        "symmetric": params.is_symmetric,
        **refusals,
    }
