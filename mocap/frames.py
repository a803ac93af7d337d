"""Every frame, unit and rotation convention conversion of the project, in one place.

Conventions:
* Arena frame: ENU-like, z up (the paper's inertial frame {E}); metres.
* Body frame: FLU (x forward, y left, z up; thrust along +z as in (1b)).
* PX4 uses NED (world) and FRD (body).
* Quaternions are (w, x, y, z), Hamilton, rotating body vectors into the world frame.
* Euler angles are the paper's Z-Y-X (roll φ, pitch θ, yaw ψ), R = Rz(ψ) Ry(θ) Rx(φ), (2).
* Motion capture (QTM) reports millimetres.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

MM_PER_M = 1000.0

# ENU ↔ NED swaps x/y and negates z; FLU ↔ FRD negates y and z. Both are involutions.
ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
FLU_TO_FRD = np.diag([1.0, -1.0, -1.0])


def mm_to_m(values_mm: FloatArray) -> FloatArray:
    """Millimetres (QTM) to metres."""
    return np.asarray(values_mm, dtype=float) / MM_PER_M


def m_to_mm(values_m: FloatArray) -> FloatArray:
    """Metres to millimetres (QTM)."""
    return np.asarray(values_m, dtype=float) * MM_PER_M


def enu_to_ned(vector_enu: FloatArray) -> FloatArray:
    """A world vector (position, velocity) from ENU to NED; also NED to ENU."""
    result: FloatArray = ENU_TO_NED @ np.asarray(vector_enu, dtype=float)
    return result


def flu_to_frd(vector_flu: FloatArray) -> FloatArray:
    """A body vector (rates, torque) from FLU to FRD; also FRD to FLU."""
    result: FloatArray = FLU_TO_FRD @ np.asarray(vector_flu, dtype=float)
    return result


def rotation_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """R(φ, θ, ψ) of the paper's equation (2), shape (3, 3)."""
    cf, sf = math.cos(roll_rad), math.sin(roll_rad)
    ct, st = math.cos(pitch_rad), math.sin(pitch_rad)
    cp, sp = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array(
        [
            [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
            [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
            [-st, ct * sf, ct * cf],
        ]
    )


def euler_zyx_from_rotation(R: FloatArray) -> FloatArray:
    """(φ, θ, ψ) [rad] of a rotation matrix, inverting (2); θ in [−π/2, π/2]."""
    pitch = math.asin(max(-1.0, min(1.0, -float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    yaw = math.atan2(float(R[1, 0]), float(R[0, 0]))
    return np.array([roll, pitch, yaw])


def quaternion_from_rotation(R: FloatArray) -> FloatArray:
    """Unit quaternion (w, x, y, z) with w ≥ 0 of a rotation matrix."""
    m = np.asarray(R, dtype=float)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        q = np.array(
            [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        )
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array(
            [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        )
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array(
            [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        )
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array(
            [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
        )
    q /= np.linalg.norm(q)
    return q if q[0] >= 0.0 else -q


def rotation_from_quaternion(q: FloatArray) -> FloatArray:
    """Rotation matrix of a (w, x, y, z) quaternion (normalized first), shape (3, 3)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def quaternion_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """(w, x, y, z) of R(φ, θ, ψ)."""
    return quaternion_from_rotation(rotation_from_euler_zyx(roll_rad, pitch_rad, yaw_rad))


def euler_zyx_from_quaternion(q: FloatArray) -> FloatArray:
    """(φ, θ, ψ) [rad] of a (w, x, y, z) quaternion."""
    return euler_zyx_from_rotation(rotation_from_quaternion(q))


def rotation_enu_flu_to_ned_frd(R_enu_flu: FloatArray) -> FloatArray:
    """A body attitude (FLU body → ENU world) as PX4 sees it (FRD body → NED world)."""
    result: FloatArray = ENU_TO_NED @ np.asarray(R_enu_flu, dtype=float) @ FLU_TO_FRD
    return result


def rotation_ned_frd_to_enu_flu(R_ned_frd: FloatArray) -> FloatArray:
    """Inverse of ``rotation_enu_flu_to_ned_frd``."""
    result: FloatArray = ENU_TO_NED @ np.asarray(R_ned_frd, dtype=float) @ FLU_TO_FRD
    return result


def wrap_angle(angle_rad: float) -> float:
    """An angle wrapped to (−π, π]."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped
