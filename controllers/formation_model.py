"""N UAVs carrying one rigid payload on N rigid, massless cables, in CasADi (symbolic SX).

The generalization of the UAV–bar model (5)–(8): one constraint (7) per cable,
|p_i − e_i| = l_i with the attachment e_i = p_b + R(Θ_b) a_i, and the tensions T ∈ R^N
from the constraints' second derivatives, M T = λ (derivation: ``docs/model.md``, "N
cables"). For two cables on a bar it is (5)–(8) exactly.

The payload's attitude is Z-Y-X Euler Θ_b with the inertial rate ω_b (H^E of (6)); its
rotation follows Euler's equation in the inertial frame, J_w ω̇ = Σ_j q_j × T_j n_j − ω × J_w ω
with J_w = R J Rᵀ and q_j = R a_j. A bar (``PayloadParams.is_bar``) follows (5g) instead:
ω̇ = J_b⁻¹ Σ_j q_j × T_j n_j, its spin about its own axis left out.

State layout: ``geometry.formation``.

``forced_dynamics`` adds constant external loads d = (f_b, τ_b, f_1, …, f_N) (6 + 3N,),
world frame: the force f_b [N] at the payload's CoM, the torque τ_b [N m] on it, f_i [N]
on UAV i. Each force enters its body's v̇ as f/m and the constraint's λ_i as
n_i·(f_i/m_i − f_b/m_b); the torque enters ω̇_b as K τ_b and λ_i as −g_i·K τ_b (a bar
takes only its part across the bar: (5g) has no spin about its axis). The
disturbance-force observer (``controllers.force_observer``) estimates them.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np

from controllers.formation_params import FormationParams
from controllers.model import (
    E_Z,
    body_rates_to_euler_rates,
    inertial_rates_to_euler_rates,
    rotation_zyx,
)
from geometry.formation import FormationLayout
from geometry.state import P_B, TH_B, V_B, W_B


@dataclass(frozen=True)
class _PayloadKinematics:
    """What the tensions and the accelerations share at one state (all SX)."""

    q: list[ca.SX]  # attachment offsets R a_i [m]
    n: list[ca.SX]  # cable directions r_i / l_i
    r_dot: list[ca.SX]  # ṙ_i [m/s]
    arm: list[ca.SX]  # g_i = q_i × n_i: the payload torque per newton of T_i [m]
    gain: ca.SX  # K: ω̇_b = K Σ_j T_j g_j + bias
    bias: ca.SX  # −J_w⁻¹ (ω × J_w ω); zero for a bar, as (5g)


@dataclass(frozen=True)
class FormationModel:
    """The N-cable rigid-payload model for one parameter set, as CasADi functions.

    ``dynamics(x, u) -> ẋ`` and ``tensions(x, u) -> T`` (N,) [N]; x and u as in
    ``geometry.formation``. Both are SX functions built once and evaluable numerically or
    symbolically.
    """

    params: FormationParams

    @cached_property
    def layout(self) -> FormationLayout:
        """The state and input layout for this formation's N."""
        return FormationLayout(self.params.n_vehicles)

    @cached_property
    def n_forces(self) -> int:
        """The size of d: the payload's force and torque and each UAV's force, 6 + 3N."""
        return 6 + 3 * self.layout.n_vehicles

    @cached_property
    def _symbols(self) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX, ca.SX]:
        x = ca.SX.sym("x", self.layout.n_states)
        u = ca.SX.sym("u", self.layout.n_inputs)
        d = ca.SX.sym("d", self.n_forces)
        kinematics = self._kinematics(x)
        tensions = self._tension_expr(x, u, d, kinematics)
        return x, u, d, self._xdot_expr(x, u, d, kinematics, tensions), tensions

    @cached_property
    def forced_dynamics(self) -> ca.Function:
        """ẋ = f(x, u, d): ``dynamics`` with the constant external loads d (6 + 3N,)."""
        x, u, d, xdot, _ = self._symbols
        return ca.Function("formation_fd", [x, u, d], [xdot], ["x", "u", "d"], ["xdot"])

    @cached_property
    def dynamics(self) -> ca.Function:
        """ẋ = f(x, u): (5a)–(5f) per UAV and for the payload's translation, the rigid-body
        (or (5g)) rotation, with the tensions M⁻¹λ."""
        x, u, d, xdot, _ = self._symbols
        free = ca.substitute(xdot, d, ca.SX.zeros(self.n_forces))
        return ca.Function("formation_f", [x, u], [free], ["x", "u"], ["xdot"])

    @cached_property
    def tensions(self) -> ca.Function:
        """T = M⁻¹λ [N], shape (N,), with no external forces."""
        x, u, d, _, tensions = self._symbols
        free = ca.substitute(tensions, d, ca.SX.zeros(self.n_forces))
        return ca.Function("formation_tensions", [x, u], [free], ["x", "u"], ["T"])

    def _kinematics(self, x: ca.SX) -> _PayloadKinematics:
        prm, layout = self.params, self.layout
        R_b = rotation_zyx(x[TH_B])
        w_b = x[W_B]
        q, n, r_dot, arm = [], [], [], []
        for i, (a_i, length) in enumerate(
            zip(prm.payload.attachments_m, prm.cable_lengths_m, strict=True), start=1
        ):
            p_i, v_i, _, _ = layout.uav_slices(i)
            q_i = R_b @ ca.DM(a_i)
            n_i = (x[p_i] - x[P_B] - q_i) / length
            q.append(q_i)
            n.append(n_i)
            r_dot.append(x[v_i] - x[V_B] - ca.cross(w_b, q_i))
            arm.append(ca.cross(q_i, n_i))
        if prm.payload.is_bar:
            # Σ q_j × T_j n_j is perpendicular to the bar, so (5g)'s J_b⁻¹ n_b × (…) is
            # the pseudo-inverse (I − n_b n_bᵀ)/J_b of the rod's inertia acting on it.
            gain = ca.SX.eye(3) / prm.payload.perpendicular_inertia_kgm2
            bias = ca.SX.zeros(3)
        else:
            J = prm.payload.inertia_matrix()
            J_w = R_b @ ca.DM(J) @ R_b.T
            gain = R_b @ ca.DM(np.linalg.inv(J)) @ R_b.T
            bias = -gain @ ca.cross(w_b, J_w @ w_b)
        return _PayloadKinematics(q, n, r_dot, arm, gain, bias)

    def _payload_torque(self, d: ca.SX, kin: _PayloadKinematics) -> ca.SX:
        """τ_b of d; a bar's without its part along the bar."""
        torque = d[3:6]
        if not self.params.payload.is_bar:
            return torque
        axis = kin.q[-1] - kin.q[0]
        axis = axis / ca.norm_2(axis)
        return torque - axis * ca.dot(axis, torque)

    def _tension_expr(self, x: ca.SX, u: ca.SX, d: ca.SX, kin: _PayloadKinematics) -> ca.SX:
        """Differentiate each (7) twice, insert the dynamics, solve M T = λ (docs/model.md)."""
        prm, layout = self.params, self.layout
        n_cables = layout.n_vehicles
        w_b = x[W_B]
        f_b = d[0:3]
        spin_up = kin.gain @ self._payload_torque(d, kin)
        M = ca.SX(n_cables, n_cables)
        lam = ca.SX(n_cables, 1)
        for i in range(n_cables):
            uav = prm.uavs[i]
            R_i = rotation_zyx(x[layout.uav_slices(i + 1)[2]])
            lam[i] = (
                u[layout.thrust_index(i + 1)] * ca.dot(kin.n[i], R_i @ E_Z) / uav.mass_kg
                - ca.dot(kin.n[i], ca.cross(w_b, ca.cross(w_b, kin.q[i])))
                - ca.dot(kin.arm[i], kin.bias)
                + ca.dot(kin.r_dot[i], kin.r_dot[i]) / prm.cable_lengths_m[i]
                + ca.dot(
                    kin.n[i], d[6 + 3 * i : 9 + 3 * i] / uav.mass_kg - f_b / prm.payload.mass_kg
                )
                - ca.dot(kin.arm[i], spin_up)
            )
            for j in range(n_cables):
                M[i, j] = (
                    (1.0 / uav.mass_kg if i == j else 0.0)
                    + ca.dot(kin.n[i], kin.n[j]) / prm.payload.mass_kg
                    + ca.dot(kin.arm[i], kin.gain @ kin.arm[j])
                )
        return ca.solve(M, lam)

    def _xdot_expr(
        self, x: ca.SX, u: ca.SX, d: ca.SX, kin: _PayloadKinematics, tensions: ca.SX
    ) -> ca.SX:
        prm, layout = self.params, self.layout
        g = prm.gravity_mps2
        cables = range(layout.n_vehicles)
        pull = sum((tensions[j] * kin.n[j] for j in cables), ca.SX.zeros(3))
        torque = sum((tensions[j] * kin.arm[j] for j in cables), ca.SX.zeros(3))
        parts = [
            x[V_B],
            (pull + d[0:3]) / prm.payload.mass_kg - g * E_Z,
            inertial_rates_to_euler_rates(x[TH_B]) @ x[W_B],
            kin.gain @ (torque + self._payload_torque(d, kin)) + kin.bias,
        ]
        for i in layout.vehicles:
            uav = prm.uavs[i - 1]
            _, v_i, th_i, w_i = layout.uav_slices(i)
            thrust, tau = u[layout.thrust_index(i)], u[layout.torque_slice(i)]
            J_i = ca.diag(ca.DM(uav.inertia_kgm2))
            w = x[w_i]
            parts += [
                x[v_i],
                (
                    thrust * rotation_zyx(x[th_i]) @ E_Z
                    - tensions[i - 1] * kin.n[i - 1]
                    + d[3 + 3 * i : 6 + 3 * i]
                )
                / uav.mass_kg
                - g * E_Z,
                body_rates_to_euler_rates(x[th_i]) @ w,
                ca.solve(J_i, tau - ca.cross(w, J_i @ w)),  # (5d)
            ]
        return ca.vertcat(*parts)
