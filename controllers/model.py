"""The paper's rigid-body kinematics and the decentralized agent's model, in CasADi
(symbolic SX, built per parameter set).

* R (2), H (4) and H^E (6): rotations and Euler-angle rates, shared with the formation's
  model (``controllers.formation_model``: N UAVs and the payload, the generalization of
  the UAV–bar model (5)–(8)).
* ``PayloadModel``: the single UAV–payload model (1)–(4), x_i ∈ R^18, u_i ∈ R^4, used by
  the decentralized controller with its cable's share of the payload's weight (13). Its
  parameter ``f_ext`` is a constant external force on the payload (zero in the paper; see
  ``docs/model.md``).

State layouts (the paper's order): ``geometry.state``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca

from controllers.params import UavParams
from geometry.state import AGENT_INPUTS, AGENT_STATES, P_I, P_P, TH_I, V_I, V_P, W_I

E_Z = ca.DM([0.0, 0.0, 1.0])


def rotation_zyx(theta: ca.SX) -> ca.SX:
    """R(φ, θ, ψ) of equation (2): body → inertial, Z-Y-X Euler angles."""
    phi, th, psi = theta[0], theta[1], theta[2]
    cf, sf, ct, st, cp, sp = (
        ca.cos(phi),
        ca.sin(phi),
        ca.cos(th),
        ca.sin(th),
        ca.cos(psi),
        ca.sin(psi),
    )
    return ca.vertcat(
        ca.horzcat(cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf),
        ca.horzcat(sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf),
        ca.horzcat(-st, ct * sf, ct * cf),
    )


def body_rates_to_euler_rates(theta: ca.SX) -> ca.SX:
    """H of equation (4): Θ̇ = H ω with ω in the body frame."""
    phi, th = theta[0], theta[1]
    cf, sf, ct, tt = ca.cos(phi), ca.sin(phi), ca.cos(th), ca.tan(th)
    return ca.vertcat(
        ca.horzcat(1.0, sf * tt, cf * tt),
        ca.horzcat(0.0, cf, -sf),
        ca.horzcat(0.0, sf / ct, cf / ct),
    )


def inertial_rates_to_euler_rates(theta: ca.SX) -> ca.SX:
    """H^{E} of equation (6): Θ̇ = H^{E} ω with ω in the inertial frame."""
    th, psi = theta[1], theta[2]
    ct, tt, cp, sp = ca.cos(th), ca.tan(th), ca.cos(psi), ca.sin(psi)
    return ca.vertcat(
        ca.horzcat(cp / ct, sp / ct, 0.0),
        ca.horzcat(-sp, cp, 0.0),
        ca.horzcat(cp * tt, sp * tt, 1.0),
    )


def _rigid_uav_rates(uav: UavParams, omega: ca.SX, tau: ca.SX) -> ca.SX:
    """(1d)/(5d): J⁻¹(τ − ω × Jω)."""
    J = ca.diag(ca.DM(uav.inertia_kgm2))
    return ca.solve(J, tau - ca.cross(omega, J @ omega))


@dataclass(frozen=True)
class PayloadModel:
    """The UAV with a point-mass payload, (1)–(4), for the decentralized controller.

    ``dynamics(x, u, f_ext) -> ẋ``: x ∈ R^18, u = (F, τ) ∈ R^4, ``f_ext`` ∈ R^3 a constant
    external force on the payload [N] (the pull of the rest of the payload at a cone angle
    ≠ 0; zero reproduces the paper's (1f) and (3) exactly).
    """

    uav: UavParams
    payload_mass_kg: float
    cable_length_m: float
    gravity_mps2: float = 9.81

    @cached_property
    def _symbols(self) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX]:
        x = ca.SX.sym("x", AGENT_STATES)
        u = ca.SX.sym("u", AGENT_INPUTS)
        f_ext = ca.SX.sym("f_ext", 3)
        tension = self._tension_expr(x, u, f_ext)
        return x, u, f_ext, self._xdot_expr(x, u, f_ext, tension), tension

    @cached_property
    def dynamics(self) -> ca.Function:
        """ẋ = f(x, u, f_ext), equations (1a)–(1f)."""
        x, u, f_ext, xdot, _ = self._symbols
        return ca.Function("payload_f", [x, u, f_ext], [xdot], ["x", "u", "f_ext"], ["xdot"])

    @cached_property
    def tension(self) -> ca.Function:
        """The cable tension T [N], equation (3) (plus the f_ext term)."""
        x, u, f_ext, _, tension = self._symbols
        return ca.Function("payload_T", [x, u, f_ext], [tension], ["x", "u", "f_ext"], ["T"])

    def _tension_expr(self, x: ca.SX, u: ca.SX, f_ext: ca.SX) -> ca.SX:
        m, m_p, length = self.uav.mass_kg, self.payload_mass_kg, self.cable_length_m
        n = (x[P_I] - x[P_P]) / length
        dv = x[V_I] - x[V_P]
        thrust_along_cable = u[0] * ca.dot(rotation_zyx(x[TH_I]) @ E_Z, n)
        return (m_p * (thrust_along_cable + m * ca.dot(dv, dv) / length) - m * ca.dot(f_ext, n)) / (
            m + m_p
        )

    def _xdot_expr(self, x: ca.SX, u: ca.SX, f_ext: ca.SX, tension: ca.SX) -> ca.SX:
        m, m_p, g = self.uav.mass_kg, self.payload_mass_kg, self.gravity_mps2
        n = (x[P_I] - x[P_P]) / self.cable_length_m
        R = rotation_zyx(x[TH_I])
        return ca.vertcat(
            x[V_I],
            (u[0] * R @ E_Z - tension * n) / m - g * E_Z,
            body_rates_to_euler_rates(x[TH_I]) @ x[W_I],
            _rigid_uav_rates(self.uav, x[W_I], u[1:4]),
            x[V_P],
            (tension * n + f_ext) / m_p - g * E_Z,
        )
