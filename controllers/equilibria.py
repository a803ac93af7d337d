"""Proposition 1 and what every equilibrium computation shares.

Proposition 1 (symmetric setup, Assumption 1) gives f_eq(θ_f, θ_l) = 0, equation (9).
Its root has a closed form, derived in ``docs/model.md``:

    tan θ_f = m_b tan θ_l / (m_b + 2 m_uav),

the balance of one UAV carrying half the bar's weight and the horizontal pull
(m_b g / 2) tan θ_l; with N UAVs sharing the load equally, 2 becomes N. The equilibria
themselves, for any formation and reference: ``controllers.formation_equilibria``.
"""

from __future__ import annotations

import math


class EquilibriumError(ValueError):
    """A reference with no equilibrium (a cone angle outside [0°, 90°), non-finite
    values, a payload that cannot hang level, a bound it would break)."""


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


def theta_f_closed_form(theta_l: float, m_uav: float, m_b: float, n_vehicles: int) -> float:
    """θ_f = atan(m_b tan θ_l / (m_b + N m_uav)): for N = 2 the root of f_eq for given
    θ_l; for N UAVs of mass ``m_uav`` each carrying 1/N of the payload ``m_b`` on a cable
    at θ_l, their thrust's tilt."""
    return math.atan(m_b * math.tan(theta_l) / (m_b + n_vehicles * m_uav))


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
