"""Statics of the plant's payload: where it hangs at rest from N fixed anchor points on its
elastic cables (``sim.plant.hanging_state`` places the UAVs around it).

Unknowns: the payload's CoM p and attitude R; equations: the cable forces carry its weight
and have no moment about its CoM. Cable c pulls its attachment e_c = p + q_c (q_c = R a_c)
towards its anchor A_c with f_c = k_c (1 − l_c/|d_c|) d_c, d_c = A_c − e_c: a two-sided
spring, smooth for Newton's method (the slack side of max(0, ·) has no stiffness); a
compressed cable is refused afterwards. A bar — every attachment on one line through its
CoM — has no moment about that line and no attitude about it: the turn about it is left
out (five equations).

Newton's method with the exact Jacobian in small world-frame increments (δp, δφ), R ←
exp([δφ]×) R: δd_c = −δp + [q_c]× δφ, δf_c = K_c δd_c with K_c = k_c ((1 − l_c/|d_c|) I +
(l_c/|d_c|) n_c n_cᵀ), and δ(q_c × f_c) = [f_c]×[q_c]× δφ + [q_c]× δf_c. Increments, not the
absolute pose, are what the solver varies, so no unknown is scaled by its own size (issue
33: SciPy's finite differences step each unknown relative to its value, and a pitch or a
position of 1e-16 — rounding where 0 was meant, with unequal cables or a turned setup —
gave a zero Jacobian column and no solution).
"""

from __future__ import annotations

import math

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import (
    quaternion_from_rotation_vector,
    rotation_from_euler_zyx,
    rotation_from_quaternion,
)

BAR_TOLERANCE_M = 1e-9
"""How far an attachment may be from the line through the CoM and the farthest attachment
for the payload to hang as a bar [m]."""

_MAX_NEWTON_STEPS = 100
_E_Z = np.array([0.0, 0.0, 1.0])


def cross_matrix(v: FloatArray) -> FloatArray:
    """[v]×, shape (3, 3): [v]× w = v × w."""
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def rotation_between(u: FloatArray, v: FloatArray) -> FloatArray:
    """The smallest rotation taking unit vector ``u`` to unit vector ``v``, shape (3, 3).
    For opposite vectors every half turn about an axis perpendicular to them is smallest:
    the one about the vertical where it is perpendicular (a bar turned end for end stays
    upright), else about the horizontal perpendicular."""
    axis = np.cross(u, v)
    sine = float(np.linalg.norm(axis))
    if sine >= 1e-15:
        return turned(np.eye(3), axis / sine * math.atan2(sine, float(u @ v)))
    if float(u @ v) > 0.0:
        return np.eye(3)
    up = _E_Z if abs(float(u[2])) < 0.9 else np.array([0.0, 1.0, 0.0])
    perpendicular = up - float(up @ u) * u
    return turned(np.eye(3), math.pi * perpendicular / float(np.linalg.norm(perpendicular)))


def turned(R: FloatArray, rotation_vector_rad: FloatArray) -> FloatArray:
    """exp([φ]×) R: R turned by φ [rad] about the world axes."""
    return rotation_from_quaternion(quaternion_from_rotation_vector(rotation_vector_rad)) @ R


def bar_axis(attachments_m: FloatArray) -> FloatArray | None:
    """The unit vector along the line through the CoM (the origin) on which every
    attachment (shape (N, 3)) lies, or None when they do not."""
    farthest = attachments_m[np.argmax(np.linalg.norm(attachments_m, axis=1))]
    axis: FloatArray = farthest / np.linalg.norm(farthest)
    off_line = attachments_m - np.outer(attachments_m @ axis, axis)
    return axis if np.linalg.norm(off_line, axis=1).max() <= BAR_TOLERANCE_M else None


def cable_forces_n(
    com_m: FloatArray,
    R: FloatArray,
    anchors_m: FloatArray,
    attachments_m: FloatArray,
    stiffness_n_per_m: FloatArray,
    lengths_m: FloatArray,
) -> FloatArray:
    """The two-sided spring forces of the cables on the payload [N], shape (N, 3)."""
    d = anchors_m - (com_m + attachments_m @ R.T)
    dist = np.linalg.norm(d, axis=1)
    forces: FloatArray = (stiffness_n_per_m * (1.0 - lengths_m / dist))[:, None] * d
    return forces


def _residual_and_jacobian(
    com_m: FloatArray,
    R: FloatArray,
    anchors_m: FloatArray,
    attachments_m: FloatArray,
    stiffness_n_per_m: FloatArray,
    lengths_m: FloatArray,
    weight_n: float,
) -> tuple[FloatArray, FloatArray]:
    """(net force [N], moment about the CoM [N m]) and its Jacobian in (δp, δφ), (6,) and
    (6, 6)."""
    residual = np.zeros(6)
    residual[2] = -weight_n
    jacobian = np.zeros((6, 6))
    for A, a, k, length in zip(anchors_m, attachments_m, stiffness_n_per_m, lengths_m, strict=True):
        q = R @ a
        d = A - (com_m + q)
        dist = float(np.linalg.norm(d))
        n = d / dist
        f = k * (1.0 - length / dist) * d
        K = k * ((1.0 - length / dist) * np.eye(3) + (length / dist) * np.outer(n, n))
        Q = cross_matrix(q)
        residual[:3] += f
        residual[3:] += np.cross(q, f)
        jacobian[:3, :3] -= K
        jacobian[:3, 3:] += K @ Q
        jacobian[3:, :3] -= Q @ K
        jacobian[3:, 3:] += cross_matrix(f) @ Q + Q @ K @ Q
    return residual, jacobian


def _bar_equations(
    axis_world: FloatArray, residual: FloatArray, jacobian: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A bar's five equations: its moment and its turn across ``axis_world`` only.
    Returns the residual (5,), its Jacobian (5, 5) and the map (6, 5) from the five
    unknowns to (δp, δφ)."""
    other = _E_Z if abs(axis_world[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(axis_world, other)
    e1 /= np.linalg.norm(e1)
    basis = np.zeros((6, 5))
    basis[:3, :3] = np.eye(3)
    basis[3:, 3] = e1
    basis[3:, 4] = np.cross(axis_world, e1)
    return basis.T @ residual, basis.T @ jacobian @ basis, basis


def solve_hanging(
    com_m: FloatArray,
    R: FloatArray,
    anchors_m: FloatArray,
    attachments_m: FloatArray,
    stiffness_n_per_m: FloatArray,
    lengths_m: FloatArray,
    weight_n: float,
) -> tuple[FloatArray, FloatArray]:
    """The payload's (CoM [m], rotation) in static equilibrium on its cables, by Newton's
    method from (``com_m``, ``R``); shapes (N, 3) for the anchors (world) and attachments
    (payload frame), (N,) for the cables. Raises ValueError when no equilibrium is found."""
    axis = bar_axis(attachments_m)

    def equations(com: FloatArray, R: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        residual, jacobian = _residual_and_jacobian(
            com, R, anchors_m, attachments_m, stiffness_n_per_m, lengths_m, weight_n
        )
        if axis is None:
            return residual, jacobian, np.eye(6)
        return _bar_equations(R @ axis, residual, jacobian)

    residual, jacobian, basis = equations(com_m, R)
    for _ in range(_MAX_NEWTON_STEPS):
        size = float(np.max(np.abs(residual)))
        try:
            step = basis @ np.linalg.solve(jacobian, -residual)
        except np.linalg.LinAlgError:
            break
        # Halve the step until the residual shrinks; none does at the rounding floor.
        scale = 1.0
        while scale > 1e-3:
            trial_com, trial_R = com_m + scale * step[:3], turned(R, scale * step[3:])
            trial = equations(trial_com, trial_R)
            if float(np.max(np.abs(trial[0]))) < size:
                com_m, R, (residual, jacobian, basis) = trial_com, trial_R, trial
                break
            scale *= 0.5
        else:
            break
    size = float(np.max(np.abs(residual)))
    if not size <= 1e-8 * max(1.0, weight_n):
        raise ValueError(f"no hanging equilibrium found (force and moment residual {size:.3g})")
    return com_m, R


def hanging_guess(
    anchors_m: FloatArray,
    attachments_m: FloatArray,
    lengths_m: FloatArray,
    yaw_rad: float,
) -> tuple[FloatArray, FloatArray]:
    """A starting pose for ``solve_hanging`` with every cable taut: the payload turned about
    the vertical so its attachments lie best under the anchors (a least-squares fit in the
    plane; ``yaw_rad`` when the anchors do not fix it), each attachment a cable's
    ``lengths_m`` (stretched) below its anchor, and the payload tilted to the plane that
    fits those heights best. Raises ValueError when an anchor is a cable's length or more
    to the side of its attachment."""
    anchors_xy = anchors_m[:, :2] - anchors_m[:, :2].mean(axis=0)
    points_xy = attachments_m[:, :2] - attachments_m[:, :2].mean(axis=0)
    sine = float(np.sum(points_xy[:, 0] * anchors_xy[:, 1] - points_xy[:, 1] * anchors_xy[:, 0]))
    cosine = float(np.sum(points_xy * anchors_xy))
    yaw = math.atan2(sine, cosine) if math.hypot(sine, cosine) > 1e-12 else yaw_rad
    level = rotation_from_euler_zyx(0.0, 0.0, yaw)
    offsets = attachments_m @ level.T
    centre_xy = anchors_m[:, :2].mean(axis=0) - offsets[:, :2].mean(axis=0)
    side = np.linalg.norm(anchors_m[:, :2] - (centre_xy + offsets[:, :2]), axis=1)
    for c, (reach, cable) in enumerate(zip(side, lengths_m, strict=True)):
        if reach >= cable:
            raise ValueError(
                f"no hanging equilibrium: UAV {c + 1}'s anchor is {reach:.3f} m to the side "
                f"of its attachment, on a {cable:.3f} m cable"
            )
    heights = anchors_m[:, 2] - np.sqrt(lengths_m**2 - side**2)
    # Heights of a payload tilted by its z axis (t_x, t_y, ·): z_c + p_z − t·(x_c, y_c).
    rows = np.column_stack((np.ones(len(offsets)), -offsets[:, 0], -offsets[:, 1]))
    p_z, t_x, t_y = np.linalg.lstsq(rows, heights - offsets[:, 2], rcond=None)[0]
    tilt = np.array([t_x, t_y])
    steepness = float(np.linalg.norm(tilt))
    if steepness > 0.9:  # a guess, not a solution: anything short of on its side does
        tilt *= 0.9 / steepness
    z_axis = np.array([tilt[0], tilt[1], math.sqrt(1.0 - float(tilt @ tilt))])
    return np.array([centre_xy[0], centre_xy[1], p_z]), rotation_between(_E_Z, z_axis) @ level


def no_roll(axis_body: FloatArray, axis_world: FloatArray) -> FloatArray:
    """The attitude of a bar along ``axis_body`` (its frame) pointing along ``axis_world``
    without roll about itself: Rz(ψ) Ry(θ) after the turn of ``axis_body`` onto x (none for
    the plant's bar, whose x axis it is)."""
    yaw = math.atan2(float(axis_world[1]), float(axis_world[0]))
    pitch = -math.asin(max(-1.0, min(1.0, float(axis_world[2]))))
    to_x = rotation_between(axis_body, np.array([1.0, 0.0, 0.0]))
    return rotation_from_euler_zyx(0.0, pitch, yaw) @ to_x
