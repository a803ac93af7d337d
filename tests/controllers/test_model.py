"""The nonlinear models: cable constraints hold along trajectories, (3) is reproduced."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from controllers.equilibria import Reference, bar_equilibrium
from controllers.model import BarSystemModel, PayloadModel
from controllers.params import BarSystemParams, UavParams
from geometry.frames import rotation_from_euler_zyx
from geometry.state import P_B, TH_B, V_B, W_B, uav_slices
from tests.conftest import uneven_params

Vector = np.ndarray


def rk4(f: Callable[[Vector], Vector], x: Vector, h: float, steps: int) -> list[Vector]:
    trajectory = [x]
    for _ in range(steps):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        trajectory.append(x)
    return trajectory


def unit(v: Vector) -> Vector:
    result: Vector = v / np.linalg.norm(v)
    return result


def bar_axis(x: Vector) -> Vector:
    """n_b = R(Θ_b) e_x, computed independently of the CasADi model."""
    return rotation_from_euler_zyx(*x[TH_B])[:, 0]


def perturbed_consistent_state(params: BarSystemParams, rng: np.random.Generator) -> Vector:
    """A state away from equilibrium that satisfies (7) and its time derivative."""
    eq = bar_equilibrium(params, Reference((0.0, 0.0, 1.0), 0.3, (0.2, -0.5), math.radians(20)))
    x = eq.x.copy()
    x[TH_B] += (0.0, 0.15, 0.2)  # pitch the bar: ends at different heights
    x[V_B] = rng.normal(0.0, 0.3, 3)
    n_b = bar_axis(x)
    x[W_B] = np.cross(n_b, rng.normal(0.0, 0.5, 3))  # n_b · ω_b = 0, as (5g) assumes
    for i, sign, d, length in (
        (1, -1.0, params.d1_m, params.cable_lengths_m[0]),
        (2, 1.0, params.d2_m, params.cable_lengths_m[1]),
    ):
        p, v, th, w = uav_slices(i)
        end = x[P_B] + sign * d * n_b
        end_velocity = x[V_B] + sign * d * np.cross(x[W_B], n_b)
        n_i = unit(np.array([sign * 0.3, 0.1 * i, 1.0]))
        x[p] = end + length * n_i
        x[v] = end_velocity + np.cross(rng.normal(0.0, 0.4, 3), n_i)  # ṙ ⊥ r keeps |r| fixed
        x[th] += rng.normal(0.0, 0.1, 3)
        x[w] = rng.normal(0.0, 0.3, 3)
    return x


def cable_lengths(params: BarSystemParams, x: Vector) -> Vector:
    n_b = bar_axis(x)
    ends = (x[P_B] - params.d1_m * n_b, x[P_B] + params.d2_m * n_b)
    return np.array([np.linalg.norm(x[uav_slices(i)[0]] - ends[i - 1]) for i in (1, 2)])


def test_cable_lengths_hold_along_a_trajectory() -> None:
    """RK4 at 1 ms for 2 s from a perturbed, consistent state: |p_i − e_i| stays l_i."""
    params = uneven_params()
    model = BarSystemModel(params)
    x0 = perturbed_consistent_state(params, np.random.default_rng(7))
    np.testing.assert_allclose(cable_lengths(params, x0), params.cable_lengths_m, atol=1e-12)
    u = bar_equilibrium(params, Reference((0.0, 0.0, 1.0))).u + np.array(
        [1.5, 0.02, -0.01, 0.0, -1.0, 0.0, 0.03, 0.01]
    )
    f = model.dynamics

    trajectory = rk4(lambda z: np.asarray(f(z, u)).ravel(), x0, 1e-3, 2000)
    drift = max(np.abs(cable_lengths(params, x) - params.cable_lengths_m).max() for x in trajectory)
    assert drift < 1e-6
    moved = np.linalg.norm(trajectory[-1][P_B] - x0[P_B])
    assert moved > 0.1  # the system really moved, so the check has teeth
    tensions = [float(np.asarray(model.tensions(x, u))[0, 0]) for x in trajectory[::100]]
    assert min(tensions) > 0.0  # stayed a rigid-link motion (no slack the model cannot express)


def test_payload_tension_is_equation_3() -> None:
    """With f_ext = 0 the tension is the paper's (3) exactly."""
    model = PayloadModel(UavParams(1.15, (0.0348, 0.0459, 0.0977)), 0.2, 1.0)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.normal(0.0, 1.0, 18)
        x[12:15] = x[0:3] - unit(
            rng.normal(0.0, 1.0, 3) + np.array([0.0, 0.0, 3.0])
        )  # |p − p_p| = l = 1
        u = np.array([12.0, 0.1, 0.0, -0.1])
        phi, th, psi = x[6:9]
        Rez = np.array(
            [
                math.cos(psi) * math.sin(th) * math.cos(phi) + math.sin(psi) * math.sin(phi),
                math.sin(psi) * math.sin(th) * math.cos(phi) - math.cos(psi) * math.sin(phi),
                math.cos(th) * math.cos(phi),
            ]
        )
        n = x[0:3] - x[12:15]
        expected = 0.2 / 1.35 * (u[0] * Rez @ n + 1.15 * np.sum((x[3:6] - x[15:18]) ** 2))
        assert abs(float(model.tension(x, u, np.zeros(3))) - expected) < 1e-12 * max(
            1.0, abs(expected)
        )


def test_payload_cable_length_holds() -> None:
    model = PayloadModel(UavParams(1.15, (0.0348, 0.0459, 0.0977)), 0.2, 1.0)
    x0 = np.zeros(18)
    x0[0:3] = (0.0, 0.0, 1.0)
    x0[12:15] = x0[0:3] - unit(np.array([0.3, -0.2, 1.0]))
    x0[3:6] = np.cross([0.5, 0.2, -0.1], x0[0:3] - x0[12:15])
    u = np.array([13.0, 0.01, -0.02, 0.0])
    f_ext = np.array([0.3, 0.0, 0.0])
    f = model.dynamics
    trajectory = rk4(lambda z: np.asarray(f(z, u, f_ext)).ravel(), x0, 1e-3, 2000)
    drift = max(abs(np.linalg.norm(x[0:3] - x[12:15]) - 1.0) for x in trajectory)
    assert drift < 1e-6
