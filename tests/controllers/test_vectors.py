"""The tick path's small vector helpers against numpy and geometry.frames."""

from __future__ import annotations

import numpy as np

from controllers.vectors import cross3, rotate_zyx
from geometry.frames import rotation_from_euler_zyx


def test_the_helpers_are_numpy_s_cross_product_and_equation_2() -> None:
    rng = np.random.default_rng(4)
    for _ in range(50):
        a, b, euler = rng.normal(size=3), rng.normal(size=3), rng.uniform(-3.0, 3.0, 3)
        np.testing.assert_allclose(cross3(a, b), np.cross(a, b), atol=1e-15)
        v = (float(b[0]), float(b[1]), float(b[2]))
        np.testing.assert_allclose(
            rotate_zyx(euler, v), rotation_from_euler_zyx(*euler) @ b, atol=1e-15
        )
