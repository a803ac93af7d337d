"""Analytic linearization of the N-cable formation model: CasADi's exact Jacobians.

As ``controllers.linearization`` for the bar: A_c = ∂ẋ/∂x and B_c = ∂ẋ/∂u, generated once
per parameter set; the yaw angles enter through the linearization point. Discretize with
``controllers.linearization.discretize``.
"""

from __future__ import annotations

from functools import cache

import casadi as ca

from controllers.formation_model import FormationModel


@cache
def formation_jacobians(model: FormationModel) -> ca.Function:
    """``(x, u) -> (A_c, B_c)``, shapes (12 + 12N, 12 + 12N) and (12 + 12N, 4N)."""
    x = ca.SX.sym("x", model.layout.n_states)
    u = ca.SX.sym("u", model.layout.n_inputs)
    xdot = model.dynamics(x, u)
    return ca.Function(
        "formation_jac",
        [x, u],
        [ca.jacobian(xdot, x), ca.jacobian(xdot, u)],
        ["x", "u"],
        ["A_c", "B_c"],
    )
