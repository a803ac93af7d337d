"""The decentralized agent's model (1)–(4): (3) is reproduced, its cable keeps its length.
(The formation's model: ``test_formation_model``.)"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from controllers.model import PayloadModel
from controllers.params import UavParams

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
