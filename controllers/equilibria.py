"""Equilibria of the UAV–bar system: Proposition 1 and its generalization.

Proposition 1 (symmetric setup, Assumption 1) gives f_eq(θ_f, θ_l) = 0, equation (9).
Its root has a closed form, derived in ``docs/model.md``:

    tan θ_f = m_b tan θ_l / (m_b + 2 m_uav).

``bar_equilibrium`` builds the full (x_eq, u_eq) for any bar position, bar yaw, UAV yaws
and θ_l, and for asymmetric setups (d1 ≠ d2, l1 ≠ l2, m1 ≠ m2) as well: the bar hangs
level with its cables in the bar's vertical plane; each cable carries the vertical load
of (13), both carry the same horizontal pull H = (m_b g / 2) tan θ_l, so the cable
angles θ_l,i = atan(H / V_i) equal θ_l exactly when the setup is symmetric. Every UAV
tilts its thrust along its own cable's horizontal direction, whatever its yaw, which takes
roll and pitch together (Section IV's x_eq, ±θ_f on pitch alone, holds only when the
UAV's x axis lies along the bar).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from controllers.params import BarSystemParams
from controllers.vectors import cross3
from geometry.arrays import FloatArray
from geometry.state import (
    BAR_INPUTS,
    BAR_STATES,
    P_B,
    P_P,
    PAYLOAD_STATES,
    TH_B,
    UAV_BLOCK,
    V_B,
    V_P,
    W_B,
    thrust_index,
    uav_block,
    uav_input_slice,
    uav_slices,
)


class EquilibriumError(ValueError):
    """A reference with no equilibrium (θ_l outside [0°, 90°), non-finite values)."""


def f_eq(theta_f: float, theta_l: float, m_uav: float, m_b: float, g: float) -> float:
    """Equation (9), Proposition 1: zero exactly at the equilibria of a symmetric setup."""
    M = m_b + 2.0 * m_uav
    tension_term = (
        m_b
        * g
        * math.cos(theta_f - theta_l)
        * M
        / (2.0 * math.cos(theta_f) * (2.0 * m_uav * math.cos(theta_l) ** 2 + m_b))
    )
    lateral = math.sin(theta_f) * M * g / (2.0 * math.cos(theta_f)) - tension_term * math.sin(
        theta_l
    )
    vertical = m_b * g / 2.0 - tension_term * math.cos(theta_l)
    return lateral**2 + vertical**2


def theta_f_closed_form(theta_l: float, m_uav: float, m_b: float) -> float:
    """The root of f_eq for given θ_l: θ_f = atan(m_b tan θ_l / (m_b + 2 m_uav))."""
    return math.atan(m_b * math.tan(theta_l) / (m_b + 2.0 * m_uav))


@dataclass(frozen=True)
class Reference:
    """What the operator asks for: bar centre [m], bar yaw, UAV yaws and θ_l [rad].

    ``velocity_mps`` (default zero) makes it a steady translation of the whole formation
    (a relative equilibrium: with no drag, x_eq + v t solves (5) with the same u_eq); a
    moving reference uses it so the MPC tracks it without a velocity-induced lag.
    ``yaw_rates_radps`` (bar, UAV 1, UAV 2; default zero) adds the turn rates of a turning
    reference the same way: the bar turns about its centre (its ends' UAVs move with it)
    and each UAV about its own vertical axis. That is a feed-forward, not an equilibrium:
    the centripetal and gyroscopic terms it leaves out are O(ψ̇²), 0.1 m/s² at 20°/s.
    ``theta_l_rate_radps`` (default zero) is how fast θ_l moves: the UAVs' velocities along
    the equilibrium family (each cable swinging outward at its own θ_l,i rate), a
    feed-forward in the same sense. Without it a θ_l ramp is tracked with a lag of about
    two seconds: 20° at 10°/s (issue 19).
    """

    bar_position_m: tuple[float, float, float]
    bar_yaw_rad: float = 0.0
    uav_yaw_rad: tuple[float, float] = (0.0, 0.0)
    theta_l_rad: float = 0.0
    velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw_rates_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    theta_l_rate_radps: float = 0.0

    def with_yaws(self, bar_yaw_rad: float, uav_yaw_rad: tuple[float, float]) -> Reference:
        """The same equilibrium family, turned to other yaw angles."""
        return Reference(
            self.bar_position_m,
            bar_yaw_rad,
            uav_yaw_rad,
            self.theta_l_rad,
            self.velocity_mps,
            self.yaw_rates_radps,
            self.theta_l_rate_radps,
        )

    def at_rest(self) -> Reference:
        """The same reference with zero velocity and turn rates (where it will stop)."""
        return Reference(self.bar_position_m, self.bar_yaw_rad, self.uav_yaw_rad, self.theta_l_rad)


@dataclass(frozen=True)
class Equilibrium:
    """A fixed point of the UAV–bar model (5) and what it implies.

    ``x`` has shape (36,), ``u`` shape (8,). ``theta_l_rad``/``theta_f_rad`` hold the
    cable and thrust tilts per cable/UAV; ``payload_force_n[i]`` is the horizontal pull the
    rest of the bar exerts on end i+1 (the decentralized model's ``f_ext``).
    """

    x: FloatArray
    u: FloatArray
    tensions_n: tuple[float, float]
    thrusts_n: tuple[float, float]
    theta_l_rad: tuple[float, float]
    theta_f_rad: tuple[float, float]
    bar_ends_m: tuple[FloatArray, FloatArray]
    payload_force_n: tuple[FloatArray, FloatArray]

    def uav_position(self, i: int) -> FloatArray:
        """Position of UAV ``i`` (1 or 2) [m]."""
        return self.x[uav_slices(i)[0]].copy()

    def payload_state(self, i: int) -> FloatArray:
        """The decentralized controller's x_i ∈ R^18 at this equilibrium."""
        x_i = np.zeros(PAYLOAD_STATES)
        x_i[UAV_BLOCK] = self.x[uav_block(i)]
        x_i[P_P] = self.bar_ends_m[i - 1]
        x_i[V_P] = self.x[V_B] + cross3(self.x[W_B], self.bar_ends_m[i - 1] - self.x[P_B])
        return x_i

    def payload_input(self, i: int) -> FloatArray:
        """The decentralized controller's u_i ∈ R^4 at this equilibrium."""
        return self.u[uav_input_slice(i)].copy()


def tilt_to_euler(
    thrust_direction: tuple[float, float, float], yaw_rad: float
) -> tuple[float, float]:
    """Roll and pitch that point R(φ, θ, ψ) e_z along ``thrust_direction`` at yaw ψ.

    Rz(−ψ) R e_z = (sθ cφ, −sφ, cθ cφ), equation (2), solved for φ and θ.
    """
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    norm = math.hypot(*thrust_direction)
    zx, zy, zz = (component / norm for component in thrust_direction)
    bx, by = c * zx + s * zy, -s * zx + c * zy
    roll = math.atan2(-by, math.hypot(bx, zz))
    pitch = math.atan2(bx, zz)
    return roll, pitch


def _check_reference(reference: Reference) -> None:
    values = (
        *reference.bar_position_m,
        *reference.velocity_mps,
        *reference.yaw_rates_radps,
        reference.theta_l_rate_radps,
        reference.bar_yaw_rad,
        *reference.uav_yaw_rad,
        reference.theta_l_rad,
    )
    if not all(math.isfinite(v) for v in values):
        raise EquilibriumError("reference values must be finite")
    if not 0.0 <= reference.theta_l_rad < math.pi / 2.0:
        raise EquilibriumError(
            f"theta_l = {math.degrees(reference.theta_l_rad):.2f}° has no equilibrium: "
            "it must lie in [0°, 90°)"
        )


def bar_equilibrium(params: BarSystemParams, reference: Reference) -> Equilibrium:
    """The equilibrium (x_eq, u_eq) of Section IV for ``reference``, in closed form.

    Raises ``EquilibriumError`` for θ_l outside [0°, 90°) or non-finite values. A tick asks
    for the same reference more than once (safety, controller), so recent answers are
    kept (callers get their own x and u; the bar ends and forces are read-only).
    """
    _check_reference(reference)
    cached = _cached_equilibrium(params, reference)
    return replace(cached, x=cached.x.copy(), u=cached.u.copy())


@lru_cache(maxsize=8)
def _cached_equilibrium(params: BarSystemParams, reference: Reference) -> Equilibrium:
    # Scalar arithmetic throughout: the bench and every relinearized tick come here.
    g = params.gravity_mps2
    psi_b = reference.bar_yaw_rad
    cos_b, sin_b = math.cos(psi_b), math.sin(psi_b)
    bx, by, bz = reference.bar_position_m
    vx, vy, vz = reference.velocity_mps
    pull = params.bar_mass_kg * g / 2.0 * math.tan(reference.theta_l_rad)
    # d(pull)/dt for a moving θ_l: m_b g/2 · sec²θ_l · θ̇_l.
    pull_rate = (
        params.bar_mass_kg
        * g
        / 2.0
        * reference.theta_l_rate_radps
        / math.cos(reference.theta_l_rad) ** 2
    )
    bar_rate, *uav_rates = reference.yaw_rates_radps

    x = np.zeros(BAR_STATES)
    u = np.zeros(BAR_INPUTS)
    x[P_B] = (bx, by, bz)
    x[V_B] = (vx, vy, vz)
    x[TH_B] = (0.0, 0.0, psi_b)
    x[W_B] = (0.0, 0.0, bar_rate)  # inertial; perpendicular to the level bar
    tensions, thrusts, theta_ls, theta_fs, ends, forces = [], [], [], [], [], []
    for k, sign in enumerate((-1.0, 1.0)):
        vertical = params.payload_mass_kg(k + 1) * g
        theta_l_i = math.atan2(pull, vertical)
        outward = sign * math.sin(theta_l_i)  # n_i = outward n_b + cos θ_l,i e_z
        n_x, n_y, n_z = outward * cos_b, outward * sin_b, math.cos(theta_l_i)
        arm = sign * params.arms_m[k]
        end = (bx + arm * cos_b, by + arm * sin_b, bz)
        tension = math.hypot(pull, vertical)
        thrust_vector = (tension * n_x, tension * n_y, params.uavs[k].mass_kg * g + tension * n_z)
        thrust = math.hypot(*thrust_vector)
        yaw = reference.uav_yaw_rad[k]
        roll, pitch = tilt_to_euler(thrust_vector, yaw)

        p_i, v_i, th_i, w_i = uav_slices(k + 1)
        cable = params.cable_lengths_m[k]
        px, py = end[0] + cable * n_x, end[1] + cable * n_y
        x[p_i] = (px, py, end[2] + cable * n_z)
        # The formation turning about the bar centre at ψ̇_b: ψ̇_b e_z × (p_i − p_b); the
        # cable swinging outward at θ̇_l,i = vertical · d(pull)/dt / T² (θ_l,i = atan2(pull,
        # vertical)): l θ̇_l,i (sign cos θ_l,i n_b − sin θ_l,i e_z).
        swing = cable * vertical * pull_rate / tension**2
        out = sign * swing * math.cos(theta_l_i)
        x[v_i] = (
            vx - bar_rate * (py - by) + out * cos_b,
            vy + bar_rate * (px - bx) + out * sin_b,
            vz - swing * math.sin(theta_l_i),
        )
        x[th_i] = (roll, pitch, yaw)
        # A turn about the vertical at ψ̇, in the body frame: ψ̇ Rᵀ e_z, with R of (2).
        cos_pitch = math.cos(pitch)
        x[w_i] = (
            -uav_rates[k] * math.sin(pitch),
            uav_rates[k] * math.sin(roll) * cos_pitch,
            uav_rates[k] * math.cos(roll) * cos_pitch,
        )
        u[thrust_index(k + 1)] = thrust

        tensions.append(tension)
        thrusts.append(thrust)
        theta_ls.append(theta_l_i)
        theta_fs.append(math.atan2(pull, thrust_vector[2]))
        ends.append(np.array(end))
        forces.append(np.array((-sign * pull * cos_b, -sign * pull * sin_b, 0.0)))
    for array in (*ends, *forces):
        array.setflags(write=False)
    return Equilibrium(
        x=x,
        u=u,
        tensions_n=(tensions[0], tensions[1]),
        thrusts_n=(thrusts[0], thrusts[1]),
        theta_l_rad=(theta_ls[0], theta_ls[1]),
        theta_f_rad=(theta_fs[0], theta_fs[1]),
        bar_ends_m=(ends[0], ends[1]),
        payload_force_n=(forces[0], forces[1]),
    )
