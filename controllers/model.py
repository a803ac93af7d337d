"""The paper's nonlinear models, written once in CasADi (symbolic SX, built per parameter set).

* ``bar_system_dynamics``: the UAV–bar model (5)–(8), x ∈ R^36, u ∈ R^8, with the cable
  tensions T = M⁻¹λ derived from the constraint (7) (derivation: ``docs/model.md``).
* ``payload_dynamics``: the single UAV–payload model (1)–(4), x_i ∈ R^18, u_i ∈ R^4, used
  by the decentralized controller with the payload mass (13). Its parameter ``f_ext`` is a
  constant external force on the payload (zero in the paper; see ``docs/model.md``).

State layouts (the paper's order): ``geometry.state``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca

from controllers.params import BarSystemParams, UavParams
from geometry.state import (
    BAR_INPUTS,
    BAR_STATES,
    P_B,
    P_I,
    P_P,
    PAYLOAD_INPUTS,
    PAYLOAD_STATES,
    TH_B,
    TH_I,
    V_B,
    V_I,
    V_P,
    W_B,
    W_I,
    thrust_index,
    torque_slice,
    uav_slices,
)

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


def bar_axis(theta_b: ca.SX) -> ca.SX:
    """n_b = R(Θ_b) e_x: the unit vector along the bar, pointing to cable 2's attachment."""
    return rotation_zyx(theta_b)[:, 0]


def _rigid_uav_rates(uav: UavParams, omega: ca.SX, tau: ca.SX) -> ca.SX:
    """(1d)/(5d): J⁻¹(τ − ω × Jω)."""
    J = ca.diag(ca.DM(uav.inertia_kgm2))
    return ca.solve(J, tau - ca.cross(omega, J @ omega))


@dataclass(frozen=True)
class BarSystemModel:
    """The UAV–bar model (5)–(8) for one parameter set, as CasADi functions.

    ``dynamics(x, u) -> ẋ`` and ``tensions(x, u) -> (T1, T2)``; both are SX functions
    built once (``cached_property``) and evaluable numerically or symbolically.
    """

    params: BarSystemParams

    @cached_property
    def _symbols(self) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
        x = ca.SX.sym("x", BAR_STATES)
        u = ca.SX.sym("u", BAR_INPUTS)
        tensions = self._tension_expr(x, u)
        return x, u, self._xdot_expr(x, u, tensions), tensions

    @cached_property
    def dynamics(self) -> ca.Function:
        """ẋ = f(x, u), equations (5a)–(5g) with (8)."""
        x, u, xdot, _ = self._symbols
        return ca.Function("bar_system_f", [x, u], [xdot], ["x", "u"], ["xdot"])

    @cached_property
    def tensions(self) -> ca.Function:
        """(T1, T2) = M⁻¹λ, equation (8) [N]."""
        x, u, _, tensions = self._symbols
        return ca.Function("bar_system_tensions", [x, u], [tensions], ["x", "u"], ["T"])

    def _geometry(self, x: ca.SX) -> tuple[ca.SX, list[ca.SX], list[ca.SX]]:
        """n_b, the cable vectors r_i = p_i − e_i, and their rates ṙ_i."""
        n_b = bar_axis(x[TH_B])
        w_b = x[W_B]
        n_b_dot = ca.cross(w_b, n_b)
        r, r_dot = [], []
        for i, (sign, d) in enumerate(zip((-1.0, 1.0), self.params.arms_m, strict=True), start=1):
            p_i, v_i, _, _ = uav_slices(i)
            r.append(x[p_i] - (x[P_B] + sign * d * n_b))
            r_dot.append(x[v_i] - (x[V_B] + sign * d * n_b_dot))
        return n_b, r, r_dot

    def _tension_expr(self, x: ca.SX, u: ca.SX) -> ca.SX:
        """Equation (8): differentiate (7) twice and solve the 2×2 system (docs/model.md)."""
        prm = self.params
        n_b, r, r_dot = self._geometry(x)
        w_b = x[W_B]
        n = [r[k] / prm.cable_lengths_m[k] for k in range(2)]
        signs = (-1.0, 1.0)
        projector = ca.DM.eye(3) - n_b @ n_b.T
        centripetal = ca.cross(w_b, ca.cross(w_b, n_b))
        M = ca.SX(2, 2)
        lam = ca.SX(2, 1)
        for i in range(2):
            uav = prm.uavs[i]
            thrust = u[thrust_index(i + 1)]
            R_i = rotation_zyx(x[uav_slices(i + 1)[2]])
            lam[i] = (
                thrust * ca.dot(n[i], R_i @ E_Z) / uav.mass_kg
                - signs[i] * prm.arms_m[i] * ca.dot(n[i], centripetal)
                + ca.dot(r_dot[i], r_dot[i]) / prm.cable_lengths_m[i]
            )
            for j in range(2):
                M[i, j] = (
                    (1.0 / uav.mass_kg if i == j else 0.0)
                    + ca.dot(n[i], n[j]) / prm.bar_mass_kg
                    + signs[i]
                    * signs[j]
                    * prm.arms_m[i]
                    * prm.arms_m[j]
                    * ca.dot(n[i], projector @ n[j])
                    / prm.bar_inertia_kgm2
                )
        return ca.solve(M, lam)

    def _xdot_expr(self, x: ca.SX, u: ca.SX, tensions: ca.SX) -> ca.SX:
        prm = self.params
        g = prm.gravity_mps2
        n_b, r, _ = self._geometry(x)
        n = [r[k] / prm.cable_lengths_m[k] for k in range(2)]
        T1, T2 = tensions[0], tensions[1]
        d1, d2 = prm.arms_m
        parts = [
            x[V_B],
            (T1 * n[0] + T2 * n[1]) / prm.bar_mass_kg - g * E_Z,
            inertial_rates_to_euler_rates(x[TH_B]) @ x[W_B],
            ca.cross(n_b, d2 * T2 * n[1] - d1 * T1 * n[0]) / prm.bar_inertia_kgm2,
        ]
        for i in (1, 2):
            uav = prm.uavs[i - 1]
            _, v_i, th_i, w_i = uav_slices(i)
            thrust, tau = u[thrust_index(i)], u[torque_slice(i)]
            R_i = rotation_zyx(x[th_i])
            parts += [
                x[v_i],
                (thrust * R_i @ E_Z - tensions[i - 1] * n[i - 1]) / uav.mass_kg - g * E_Z,
                body_rates_to_euler_rates(x[th_i]) @ x[w_i],
                _rigid_uav_rates(uav, x[w_i], tau),
            ]
        return ca.vertcat(*parts)


@dataclass(frozen=True)
class PayloadModel:
    """The UAV with a point-mass payload, (1)–(4), for the decentralized controller.

    ``dynamics(x, u, f_ext) -> ẋ``: x ∈ R^18, u = (F, τ) ∈ R^4, ``f_ext`` ∈ R^3 a constant
    external force on the payload [N] (the pull of the bar's other end at θ_l ≠ 0; zero
    reproduces the paper's (1f) and (3) exactly).
    """

    uav: UavParams
    payload_mass_kg: float
    cable_length_m: float
    gravity_mps2: float = 9.81

    @cached_property
    def _symbols(self) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX]:
        x = ca.SX.sym("x", PAYLOAD_STATES)
        u = ca.SX.sym("u", PAYLOAD_INPUTS)
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


def payload_model_for(params: BarSystemParams, i: int) -> PayloadModel:
    """The decentralized model of UAV ``i`` (1 or 2): its bar end as a payload of mass (13)."""
    return PayloadModel(
        uav=params.uavs[i - 1],
        payload_mass_kg=params.payload_mass_kg(i),
        cable_length_m=params.cable_lengths_m[i - 1],
        gravity_mps2=params.gravity_mps2,
    )
