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
from collections.abc import Sequence

import numpy as np

from geometry.arrays import FloatArray

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
    return _euler_zyx(
        float(R[0, 0]), float(R[1, 0]), float(R[2, 0]), float(R[2, 1]), float(R[2, 2])
    )


def _euler_zyx(r00: float, r10: float, r20: float, r21: float, r22: float) -> FloatArray:
    """(φ, θ, ψ) from the five entries of R that fix them."""
    pitch = math.asin(max(-1.0, min(1.0, -r20)))
    return np.array([math.atan2(r21, r22), pitch, math.atan2(r10, r00)])


def quaternion_from_rotation(R: FloatArray) -> FloatArray:
    """Unit quaternion (w, x, y, z) with w ≥ 0 of a rotation matrix."""
    # Python floats: this runs for every body of every mocap frame, and numpy's per-element
    # indexing costs more than the arithmetic.
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = np.asarray(R, dtype=float).tolist()
    trace = m00 + m11 + m22
    if trace > 0.0:
        s = 2.0 * math.sqrt(trace + 1.0)
        w, x, y, z = 0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        w, x, y, z = (m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        w, x, y, z = (m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        w, x, y, z = (m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    sign = 1.0 if w >= 0.0 else -1.0
    return np.array([w, x, y, z]) * (sign / norm)


def rotation_from_quaternion(q: FloatArray) -> FloatArray:
    """Rotation matrix of a (w, x, y, z) quaternion (normalized first), shape (3, 3)."""
    w, x, y, z = _unit_quaternion(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _unit_quaternion(q: FloatArray) -> tuple[float, float, float, float]:
    w, x, y, z = np.asarray(q, dtype=float).tolist()
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    return w / norm, x / norm, y / norm, z / norm


def quaternion_from_euler_zyx(roll_rad: float, pitch_rad: float, yaw_rad: float) -> FloatArray:
    """(w, x, y, z) of R(φ, θ, ψ)."""
    return quaternion_from_rotation(rotation_from_euler_zyx(roll_rad, pitch_rad, yaw_rad))


def euler_zyx_from_quaternion(q: FloatArray) -> FloatArray:
    """(φ, θ, ψ) [rad] of a (w, x, y, z) quaternion: ``euler_zyx_from_rotation`` of its
    rotation matrix, from only the entries that one reads."""
    w, x, y, z = _unit_quaternion(q)
    return _euler_zyx(
        1 - 2 * (y * y + z * z),
        2 * (x * y + w * z),
        2 * (x * z - w * y),
        2 * (y * z + w * x),
        1 - 2 * (x * x + y * y),
    )


def rotation_enu_flu_to_ned_frd(R_enu_flu: FloatArray) -> FloatArray:
    """A body attitude (FLU body → ENU world) as PX4 sees it (FRD body → NED world)."""
    result: FloatArray = ENU_TO_NED @ np.asarray(R_enu_flu, dtype=float) @ FLU_TO_FRD
    return result


def wrap_angle(angle_rad: float) -> float:
    """An angle wrapped to (−π, π]."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped == -math.pi else wrapped


# --- QTM rotation conventions (docs/reference/qtm-rt.md §1.4) ------------------------------------


def rotation_from_qtm_matrix(matrix: Sequence[float]) -> FloatArray:
    """The 3×3 rotation (rigid body → QTM global) of QTM's 9 rotation floats, shape (3, 3).

    QTM sends the matrix column-major: R = [[m0, m3, m6], [m1, m4, m7], [m2, m5, m8]]
    (Qualisys' own ``qfly/pose.py``; docs/reference/qtm-rt.md §1.4). No orthonormalization:
    the caller decides what to do with a non-finite or degenerate matrix.
    """
    m = np.asarray(matrix, dtype=float)
    if m.shape != (9,):
        raise ValueError(f"a QTM rotation has 9 elements, got shape {m.shape}")
    result: FloatArray = m.reshape(3, 3, order="F")
    return result


def qtm_matrix_from_rotation(R: FloatArray) -> tuple[float, ...]:
    """Inverse of ``rotation_from_qtm_matrix``: the 9 floats in QTM's column-major order."""
    return tuple(float(v) for v in np.asarray(R, dtype=float).reshape(3, 3).flatten(order="F"))


def rotation_from_qtm_euler_deg(roll_deg: float, pitch_deg: float, yaw_deg: float) -> FloatArray:
    """Rotation (rigid body → QTM global), shape (3, 3), of QTM's "Qualisys standard" Euler angles.

    The standard applies roll (about x), then pitch (about the rotated y′), then yaw (about
    the twice-rotated z″), all right-handed, in degrees: R = Rx(roll)·Ry(pitch)·Rz(yaw)
    (docs.qualisys.com "Rotation angles in QTM"; docs/reference/qtm-rt.md §1.4). This is *not* the
    paper's Z-Y-X convention of ``rotation_from_euler_zyx`` and only holds while QTM's Euler
    definition is left at its default.
    """
    a, b, c = math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)
    ca, sa, cb, sb, cc, sc = (
        math.cos(a),
        math.sin(a),
        math.cos(b),
        math.sin(b),
        math.cos(c),
        math.sin(c),
    )
    return np.array(
        [
            [cb * cc, -cb * sc, sb],
            [sa * sb * cc + ca * sc, -sa * sb * sc + ca * cc, -sa * cb],
            [-ca * sb * cc + sa * sc, ca * sb * sc + sa * cc, ca * cb],
        ]
    )


def qtm_euler_deg_from_rotation(R: FloatArray) -> FloatArray:
    """(roll, pitch, yaw) [deg] in QTM's "Qualisys standard" of a rotation, shape (3,).

    Inverts ``rotation_from_qtm_euler_deg``; pitch in [−90°, 90°], roll and yaw in
    (−180°, 180°]. At pitch = ±90° (gimbal lock) roll is set to 0 and yaw carries the rest.
    """
    m = np.asarray(R, dtype=float)
    pitch = math.asin(max(-1.0, min(1.0, float(m[0, 2]))))
    if math.hypot(float(m[0, 0]), float(m[0, 1])) < 1e-9:
        # cos(pitch) ≈ 0: only roll ± yaw is observable; put it all in yaw.
        roll = 0.0
        yaw = math.atan2(float(m[1, 0]), float(m[1, 1]))
    else:
        roll = math.atan2(-float(m[1, 2]), float(m[2, 2]))
        yaw = math.atan2(-float(m[0, 1]), float(m[0, 0]))
    return np.array([math.degrees(roll), math.degrees(pitch), math.degrees(yaw)])


# --- Quaternion algebra (w, x, y, z), Hamilton -----------------------------------------------


def quaternion_multiply(q1: FloatArray, q2: FloatArray) -> FloatArray:
    """Hamilton product q1 ⊗ q2 of two (w, x, y, z) quaternions, shape (4,)."""
    # Python floats here and below: the filters run these for every body of every frame.
    w1, x1, y1, z1 = np.asarray(q1, dtype=float).tolist()
    w2, x2, y2, z2 = np.asarray(q2, dtype=float).tolist()
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quaternion_conjugate(q: FloatArray) -> FloatArray:
    """Conjugate (the inverse of a unit quaternion), shape (4,)."""
    w, x, y, z = np.asarray(q, dtype=float).tolist()
    return np.array([w, -x, -y, -z])


def quaternion_from_rotation_vector(rotation_vector_rad: FloatArray) -> FloatArray:
    """Unit quaternion of a rotation vector (axis · angle [rad]), shape (3,) → (4,).

    With q_body→world, ``q ⊗ quaternion_from_rotation_vector(ω·dt)`` turns the body by a
    constant body-frame rate ω [rad/s] over dt [s] (exact, not first order).
    """
    x, y, z = np.asarray(rotation_vector_rad, dtype=float).tolist()
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        # Second-order series avoids 0/0 and keeps the result unit length to machine precision.
        w = 1.0 - angle * angle / 8.0
        x, y, z = 0.5 * x, 0.5 * y, 0.5 * z
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        return np.array([w / norm, x / norm, y / norm, z / norm])
    half = 0.5 * angle
    scale = math.sin(half) / angle
    return np.array([math.cos(half), scale * x, scale * y, scale * z])


def rotation_vector_from_quaternion(q: FloatArray) -> FloatArray:
    """Rotation vector (axis · angle [rad], angle in [0, π]) of a quaternion, shape (4,) → (3,).

    q and −q give the same result (the shorter of the two rotations).
    """
    w, x, y, z = _unit_quaternion(q)
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    sin_half = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 if sin_half < 1e-12 else 2.0 * math.atan2(sin_half, w) / sin_half
    return np.array([scale * x, scale * y, scale * z])
