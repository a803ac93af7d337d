"""Small 3-vector helpers for the tick path (numpy's ``cross`` costs ~40 µs per call)."""

from __future__ import annotations

import math

import numpy as np

from geometry.arrays import FloatArray


def cross3(a: FloatArray, b: FloatArray) -> FloatArray:
    """a × b of two 3-vectors."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def rotate_zyx(euler_rad: FloatArray, v: tuple[float, float, float]) -> FloatArray:
    """R(φ, θ, ψ) v of equation (2) (Z-Y-X Euler angles ``euler_rad``), without forming R."""
    cf, sf = math.cos(euler_rad[0]), math.sin(euler_rad[0])
    ct, st = math.cos(euler_rad[1]), math.sin(euler_rad[1])
    cp, sp = math.cos(euler_rad[2]), math.sin(euler_rad[2])
    x, y, z = v
    # R's rows, as in geometry.frames.rotation_from_euler_zyx.
    return np.array(
        [
            cp * ct * x + (cp * st * sf - sp * cf) * y + (cp * st * cf + sp * sf) * z,
            sp * ct * x + (sp * st * sf + cp * cf) * y + (sp * st * cf - cp * sf) * z,
            -st * x + ct * sf * y + ct * cf * z,
        ]
    )
