"""Analytic linearization (Section IV): CasADi's exact Jacobians, generated once.

A_c = ∂ẋ/∂x and B_c = ∂ẋ/∂u at an equilibrium, per parameter set; the yaw angles enter
through the linearization point, so the same generated function serves every tick. The
discrete model is the paper's first-order one, A = I + A_c h, B = B_c h.
"""

from __future__ import annotations

from functools import cache

import casadi as ca
import numpy as np

from controllers.formation_model import FormationModel
from controllers.model import PayloadModel
from geometry.arrays import FloatArray


@cache
def formation_jacobians(model: FormationModel) -> ca.Function:
    """``(x, u) -> (A_c, B_c)`` of the formation's model, shapes (12 + 12N, 12 + 12N) and
    (12 + 12N, 4N)."""
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


@cache
def payload_jacobians(model: PayloadModel) -> ca.Function:
    """``(x, u, f_ext) -> (A_c, B_c)`` of the UAV–payload model, shapes (18, 18), (18, 4)."""
    x = ca.SX.sym("x", model.dynamics.size1_in(0))
    u = ca.SX.sym("u", model.dynamics.size1_in(1))
    f_ext = ca.SX.sym("f_ext", 3)
    xdot = model.dynamics(x, u, f_ext)
    return ca.Function(
        "payload_jac",
        [x, u, f_ext],
        [ca.jacobian(xdot, x), ca.jacobian(xdot, u)],
        ["x", "u", "f_ext"],
        ["A_c", "B_c"],
    )


def discretize(A_c: FloatArray, B_c: FloatArray, h: float) -> tuple[FloatArray, FloatArray]:
    """The paper's first-order discretization: A = I + A_c h, B = B_c h."""
    return np.eye(A_c.shape[0]) + A_c * h, B_c * h
