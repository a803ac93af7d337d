"""A single-UAV geometric position controller for the phases the bar MPC does not model.

The MPCs assume taut cables. Before take-off (bar resting, cables slack) and after the
bar has been set down, each UAV flies alone: this controller tracks a position (and yaw)
with a PD law on the translational error, turns the desired force into a thrust and an
attitude, and tracks that attitude with a PD law on SO(3) (Lee, Leok & McClamroch, 2010).
Output: collective thrust F [N] and body torque τ [N m], the same input u_i as the MPC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.arrays import FloatArray


@dataclass(frozen=True)
class UavPdGains:
    """Gains per axis: position [1/s²], velocity [1/s], attitude [1/s²], rate [1/s]."""

    kp: float = 4.0
    kv: float = 3.0
    kr: float = 60.0
    kw: float = 12.0
    max_tilt_rad: float = math.radians(25.0)


def _vee(M: FloatArray) -> FloatArray:
    return np.array([M[2, 1], M[0, 2], M[1, 0]])


def uav_pd_control(
    position_m: FloatArray,
    velocity_mps: FloatArray,
    rotation: FloatArray,
    body_rates_radps: FloatArray,
    target_position_m: FloatArray,
    target_yaw_rad: float,
    mass_kg: float,
    inertia_kgm2: tuple[float, float, float],
    limits: tuple[float, float, float],
    extra_load_n: float = 0.0,
    gains: UavPdGains = UavPdGains(),
    gravity_mps2: float = 9.81,
) -> tuple[float, FloatArray, FloatArray]:
    """(F, τ, ω_d) bringing one UAV to ``target_position_m`` at rest with yaw ``target_yaw_rad``.

    ``rotation`` (3, 3) is body (FLU) → arena; ``extra_load_n`` a known downward load (a
    hanging cable's share of the bar) added to the weight; ``limits`` = (F_min, F_max,
    τ_max) as in the MPC's input set U. ω_d [rad/s] (FLU) is the body rate the attitude
    loop asks for, the setpoint to send a PX4 that takes body rates.
    """
    acceleration = gains.kp * (target_position_m - position_m) - gains.kv * velocity_mps
    force = mass_kg * acceleration + np.array([0.0, 0.0, mass_kg * gravity_mps2 + extra_load_n])
    horizontal = math.hypot(force[0], force[1])
    max_horizontal = math.tan(gains.max_tilt_rad) * max(force[2], 0.0)
    if horizontal > max_horizontal:  # keep the tilt bounded: scale the horizontal part
        force[0:2] *= max_horizontal / horizontal if horizontal > 0.0 else 0.0
    force[2] = max(force[2], 0.0)
    z_desired = (
        force / np.linalg.norm(force) if np.linalg.norm(force) > 0.0 else np.array([0.0, 0.0, 1.0])
    )
    x_course = np.array([math.cos(target_yaw_rad), math.sin(target_yaw_rad), 0.0])
    y_desired = np.cross(z_desired, x_course)
    y_desired /= np.linalg.norm(y_desired)
    R_desired = np.column_stack([np.cross(y_desired, z_desired), y_desired, z_desired])

    thrust = float(force @ rotation[:, 2])
    e_R = 0.5 * _vee(R_desired.T @ rotation - rotation.T @ R_desired)
    J = np.asarray(inertia_kgm2)
    torque = J * (-gains.kr * e_R - gains.kw * body_rates_radps) + np.cross(
        body_rates_radps, J * body_rates_radps
    )
    thrust_min, thrust_max, torque_max = limits
    desired_rates = -(gains.kr / gains.kw) * e_R
    return (
        float(np.clip(thrust, thrust_min, thrust_max)),
        np.clip(torque, -torque_max, torque_max),
        desired_rates,
    )
