"""Numba kernels of the physics plant: the right-hand side, RK4 stepping, diagnostics.

Everything here works on flat float64 arrays so that many steps run inside one jitted call
with no Python objects in the loop. ``sim/plant.py`` packs the parameters
(``pack_parameters``) and wraps the state in a readable API. The number of UAVs N (2 to 8)
is read from the parameters (``G_NUAV``); every size and offset below follows from it.

State vector x, shape (state_size(N),) = (17 N + 13,), 47 for the bar's two UAVs:

* body b, offset 13 b: UAV b+1 for b < N, the payload for b = N:
  position ENU [m] (3), velocity ENU [m/s] (3), quaternion (w, x, y, z) body → ENU (4),
  angular velocity in the body frame [rad/s] (3);
* UAV i ∈ {0, …, N−1} actuators, offset actuator_offset(N) + 4 i: thrust after the lag
  [N] (1), body torque after the lag [N m] (3).

Commands ``cmd``, shape (4 N,): per UAV i at 4 i the saturated thrust [N] and torque [N m]
(3). External loads ``ext``, shape ((N + 1) × EXT_SIZE,): per body b at offset EXT_SIZE b,
a force at its CoM [N] (3) and a torque [N m] (3), both in the ENU world frame (a push, a
gust), held over a call like the commands.

Frames: ENU arena (z up); UAV bodies FLU with thrust along +z; the payload's body frame
has its origin at the CoM (the bar's x axis runs along it from end 1 to end 2). Cable c
ties UAV c+1 to the payload.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, cast

import numpy as np
from numba import njit

from geometry.arrays import FloatArray

_F = TypeVar("_F", bound=Callable[..., Any])


def _jit(fn: _F) -> _F:
    """``numba.njit(cache=True)`` with the function's type kept for mypy."""
    return cast(_F, njit(cache=True)(fn))


# --- State layout --------------------------------------------------------------------
BODY_SIZE = 13
POS, VEL, QUAT, RATES = 0, 3, 6, 10
ACT_SIZE = 4
EXT_SIZE = 6  # per body: world force (3), world torque (3)


@_jit
def actuator_offset(n: int) -> int:
    """Where the actuators start in the state of ``n`` UAVs: after the n + 1 bodies."""
    return (n + 1) * BODY_SIZE


@_jit
def state_size(n: int) -> int:
    """Length of the state vector of ``n`` UAVs and the payload."""
    return (n + 1) * BODY_SIZE + n * ACT_SIZE


# --- Parameter layout (pack_parameters in sim/plant.py writes it) -----------------------
G_NUAV = 0  # N, the number of UAVs (and cables)
G_GRAV = 1
G_GROUND = 2
G_NWIND = 3
OFF_BODIES = 4  # then one BODY_BLOCK per body, in the state's order

MAX_CONTACTS = 8
B_MASS = 0
B_J = 1  # inertia, row-major 3 × 3
B_JINV = 10  # its inverse
B_NCONT = 19  # number of ground contact points
B_CPTS = 20  # contact points in the body frame, MAX_CONTACTS × 3
B_CRAD = B_CPTS + 3 * MAX_CONTACTS  # contact sphere radius (bar ends); 0 for feet
B_KN = B_CRAD + 1
B_CN = B_CRAD + 2
B_MU = B_CRAD + 3
B_VEPS = B_CRAD + 4
B_CTMAX = B_CRAD + 5
B_MUROLL = B_CRAD + 6
B_WEPS = B_CRAD + 7
B_CRMAX = B_CRAD + 8
B_DRAG1 = B_CRAD + 9
B_DRAG2 = B_CRAD + 10
B_ANCHOR = B_CRAD + 11  # 1: kinematic anchor (held still), 0: free
BODY_BLOCK = B_CRAD + 12

C_L0 = 0
C_K = 1
C_C = 2
C_UAVPT = 3  # attachment on the UAV, its body frame
C_PAYLOADPT = 6  # attachment on the payload, its body frame
CABLE_BLOCK = 9

L_TAU_F = 0
L_TAU_T = 1
LAG_BLOCK = 2


@_jit
def body_block(b: int) -> int:
    """Offset of body b's parameters."""
    return OFF_BODIES + b * BODY_BLOCK


@_jit
def cable_block(n: int, c: int) -> int:
    """Offset of cable c's parameters among ``n``."""
    return OFF_BODIES + (n + 1) * BODY_BLOCK + c * CABLE_BLOCK


@_jit
def lag_block(n: int, i: int) -> int:
    """Offset of UAV i's motor lag parameters among ``n``."""
    return OFF_BODIES + (n + 1) * BODY_BLOCK + n * CABLE_BLOCK + i * LAG_BLOCK


@_jit
def wind_offset(n: int) -> int:
    """Offset of the wind: mean (3), then amplitude, ω, phase, each 3 × K."""
    return OFF_BODIES + (n + 1) * BODY_BLOCK + n * (CABLE_BLOCK + LAG_BLOCK)


def parameter_size(n: int, n_wind: int) -> int:
    """Length of the parameter vector of ``n`` UAVs with ``n_wind`` sinusoids per wind
    axis."""
    return int(wind_offset(n)) + 3 + 9 * n_wind


# --- Diagnostics layout -------------------------------------------------------------------
# Four blocks of N per cable (block k at k N, cable c at + c), one of N + 1 per body at 4 N
# (body b at + b), then four energies [J] from energy_offset(N).
D_TENSION, D_STRETCH, D_STRETCH_RATE, D_SLACK = 0, 1, 2, 3  # D_SLACK: 1.0 = slack
D_ON_GROUND = 4  # 1.0 = a contact point penetrates
D_KINETIC, D_GRAVITY, D_CABLE_SPRING, D_CONTACT_SPRING = 0, 1, 2, 3


@_jit
def energy_offset(n: int) -> int:
    """Where the energies start in the diagnostics of ``n`` UAVs."""
    return 5 * n + 1


@_jit
def diagnostics_size(n: int) -> int:
    """Length of the diagnostics of ``n`` UAVs."""
    return 5 * n + 5


@_jit
def _rotations(x: FloatArray, R: FloatArray) -> None:
    """R[b] = rotation body → ENU of every body b from its (possibly not unit) quaternion."""
    for b in range(R.shape[0]):
        o = b * BODY_SIZE + QUAT
        qw, qx, qy, qz = x[o], x[o + 1], x[o + 2], x[o + 3]
        s = 2.0 / (qw * qw + qx * qx + qy * qy + qz * qz)
        R[b, 0, 0] = 1.0 - s * (qy * qy + qz * qz)
        R[b, 0, 1] = s * (qx * qy - qw * qz)
        R[b, 0, 2] = s * (qx * qz + qw * qy)
        R[b, 1, 0] = s * (qx * qy + qw * qz)
        R[b, 1, 1] = 1.0 - s * (qx * qx + qz * qz)
        R[b, 1, 2] = s * (qy * qz - qw * qx)
        R[b, 2, 0] = s * (qx * qz - qw * qy)
        R[b, 2, 1] = s * (qy * qz + qw * qx)
        R[b, 2, 2] = 1.0 - s * (qx * qx + qy * qy)


@_jit
def _point_velocity(
    x: FloatArray, R: FloatArray, b: int, rx: float, ry: float, rz: float
) -> tuple[float, float, float]:
    """World velocity [m/s] of the point at body-frame offset r from body b's CoM:
    v + R (ω_body × r)."""
    o = b * BODY_SIZE
    wx, wy, wz = x[o + RATES], x[o + RATES + 1], x[o + RATES + 2]
    ux = wy * rz - wz * ry
    uy = wz * rx - wx * rz
    uz = wx * ry - wy * rx
    vx = x[o + VEL] + R[b, 0, 0] * ux + R[b, 0, 1] * uy + R[b, 0, 2] * uz
    vy = x[o + VEL + 1] + R[b, 1, 0] * ux + R[b, 1, 1] * uy + R[b, 1, 2] * uz
    vz = x[o + VEL + 2] + R[b, 2, 0] * ux + R[b, 2, 1] * uy + R[b, 2, 2] * uz
    return vx, vy, vz


@_jit
def _apply_force(
    R: FloatArray,
    Fw: FloatArray,
    Tb: FloatArray,
    b: int,
    rx: float,
    ry: float,
    rz: float,
    fx: float,
    fy: float,
    fz: float,
) -> None:
    """Add the world force f [N] acting at body-frame offset r [m] of body b: to the
    resultant force (world) and, as r × Rᵀf, to the torque about the CoM (body frame)."""
    Fw[b, 0] += fx
    Fw[b, 1] += fy
    Fw[b, 2] += fz
    bx = R[b, 0, 0] * fx + R[b, 1, 0] * fy + R[b, 2, 0] * fz
    by = R[b, 0, 1] * fx + R[b, 1, 1] * fy + R[b, 2, 1] * fz
    bz = R[b, 0, 2] * fx + R[b, 1, 2] * fy + R[b, 2, 2] * fz
    Tb[b, 0] += ry * bz - rz * by
    Tb[b, 1] += rz * bx - rx * bz
    Tb[b, 2] += rx * by - ry * bx


@_jit
def _cable(
    x: FloatArray, P: FloatArray, R: FloatArray, c: int
) -> tuple[float, float, float, float, float, float]:
    """Cable c (from UAV c+1 to its attachment on the payload): (stretch [m], stretch rate
    [m/s], length between the attachment points [m], then the vector from the payload's
    attachment to the UAV's [m] (3))."""
    n = int(P[G_NUAV])
    pc = cable_block(n, c)
    ou = c * BODY_SIZE
    ob = n * BODY_SIZE
    ux, uy, uz = P[pc + C_UAVPT], P[pc + C_UAVPT + 1], P[pc + C_UAVPT + 2]
    ex, ey, ez = P[pc + C_PAYLOADPT], P[pc + C_PAYLOADPT + 1], P[pc + C_PAYLOADPT + 2]
    ax = x[ou] + R[c, 0, 0] * ux + R[c, 0, 1] * uy + R[c, 0, 2] * uz
    ay = x[ou + 1] + R[c, 1, 0] * ux + R[c, 1, 1] * uy + R[c, 1, 2] * uz
    az = x[ou + 2] + R[c, 2, 0] * ux + R[c, 2, 1] * uy + R[c, 2, 2] * uz
    bx = x[ob] + R[n, 0, 0] * ex + R[n, 0, 1] * ey + R[n, 0, 2] * ez
    by = x[ob + 1] + R[n, 1, 0] * ex + R[n, 1, 1] * ey + R[n, 1, 2] * ez
    bz = x[ob + 2] + R[n, 2, 0] * ex + R[n, 2, 1] * ey + R[n, 2, 2] * ez
    dx, dy, dz = ax - bx, ay - by, az - bz
    dist = math.sqrt(dx * dx + dy * dy + dz * dz)
    stretch = dist - P[pc + C_L0]
    if dist < 1e-12:
        return stretch, 0.0, dist, dx, dy, dz
    va = _point_velocity(x, R, c, ux, uy, uz)
    vb = _point_velocity(x, R, n, ex, ey, ez)
    rate = ((va[0] - vb[0]) * dx + (va[1] - vb[1]) * dy + (va[2] - vb[2]) * dz) / dist
    return stretch, rate, dist, dx, dy, dz


@_jit
def _tension(P: FloatArray, c: int, stretch: float, rate: float) -> float:
    """Unilateral spring-damper: T = max(0, k s + c ṡ) when taut (s > 0), else 0 [N]."""
    if stretch <= 0.0:
        return 0.0
    pc = cable_block(int(P[G_NUAV]), c)
    T = P[pc + C_K] * stretch + P[pc + C_C] * rate
    return T if T > 0.0 else 0.0


@_jit
def derivative(
    t: float,
    x: FloatArray,
    P: FloatArray,
    cmd: FloatArray,
    ext: FloatArray,
    R: FloatArray,
    Fw: FloatArray,
    Tb: FloatArray,
    out: FloatArray,
) -> None:
    """ẋ at time t [s] into ``out`` (shape (state_size(N),)). ``cmd`` (4 N,) holds the
    saturated commands [F1, τ1 (3), …, FN, τN (3)], ``ext`` the external loads (world
    force and torque per body); R (N+1, 3, 3), Fw (N+1, 3), Tb (N+1, 3) are scratch space
    (rotations, world forces, body torques)."""
    n = int(P[G_NUAV])
    g = P[G_GRAV]
    _rotations(x, R)

    # Wind (uniform in space): mean + a sum of sinusoids per axis.
    K = int(P[G_NWIND])
    ow = wind_offset(n)
    w0 = P[ow]
    w1 = P[ow + 1]
    w2 = P[ow + 2]
    base = ow + 3
    for j in range(K):
        w0 += P[base + j] * math.sin(P[base + 3 * K + j] * t + P[base + 6 * K + j])
        w1 += P[base + K + j] * math.sin(P[base + 4 * K + j] * t + P[base + 7 * K + j])
        w2 += P[base + 2 * K + j] * math.sin(P[base + 5 * K + j] * t + P[base + 8 * K + j])

    # Gravity and drag at each CoM.
    for b in range(n + 1):
        o = b * BODY_SIZE
        pb = body_block(b)
        m = P[pb + B_MASS]
        rx = x[o + VEL] - w0
        ry = x[o + VEL + 1] - w1
        rz = x[o + VEL + 2] - w2
        cd = P[pb + B_DRAG1] + P[pb + B_DRAG2] * math.sqrt(rx * rx + ry * ry + rz * rz)
        Fw[b, 0] = -cd * rx
        Fw[b, 1] = -cd * ry
        Fw[b, 2] = -cd * rz - m * g
        # External load: the force as is, the world torque into the body frame (Rᵀ τ).
        e = b * EXT_SIZE
        Fw[b, 0] += ext[e]
        Fw[b, 1] += ext[e + 1]
        Fw[b, 2] += ext[e + 2]
        tx, ty, tz = ext[e + 3], ext[e + 4], ext[e + 5]
        Tb[b, 0] = R[b, 0, 0] * tx + R[b, 1, 0] * ty + R[b, 2, 0] * tz
        Tb[b, 1] = R[b, 0, 1] * tx + R[b, 1, 1] * ty + R[b, 2, 1] * tz
        Tb[b, 2] = R[b, 0, 2] * tx + R[b, 1, 2] * ty + R[b, 2, 2] * tz

    # Rotor thrust along body +z (1b) and body torque, after the motor lag.
    act = actuator_offset(n)
    for i in range(n):
        a = act + i * ACT_SIZE
        F = x[a]
        Fw[i, 0] += F * R[i, 0, 2]
        Fw[i, 1] += F * R[i, 1, 2]
        Fw[i, 2] += F * R[i, 2, 2]
        Tb[i, 0] += x[a + 1]
        Tb[i, 1] += x[a + 2]
        Tb[i, 2] += x[a + 3]

    # Cables: tension along the line between the attachment points.
    for c in range(n):
        stretch, rate, dist, dx, dy, dz = _cable(x, P, R, c)
        T = _tension(P, c, stretch, rate)
        if T > 0.0 and dist > 1e-12:
            pc = cable_block(n, c)
            ux, uy, uz = P[pc + C_UAVPT], P[pc + C_UAVPT + 1], P[pc + C_UAVPT + 2]
            ex, ey, ez = P[pc + C_PAYLOADPT], P[pc + C_PAYLOADPT + 1], P[pc + C_PAYLOADPT + 2]
            s = T / dist
            # d points from the payload's attachment to the UAV's: the payload is pulled
            # along +n, the UAV along −n (the T n_i terms of (5b), (5e)).
            fx, fy, fz = s * dx, s * dy, s * dz
            _apply_force(R, Fw, Tb, n, ex, ey, ez, fx, fy, fz)
            _apply_force(R, Fw, Tb, c, ux, uy, uz, -fx, -fy, -fz)

    # Ground contact at z = 0: penalty spring-damper normal force, regularized Coulomb
    # friction and rolling resistance at every contact point (feet, the payload's points).
    if P[G_GROUND] > 0.5:
        for b in range(n + 1):
            o = b * BODY_SIZE
            pb = body_block(b)
            rad = P[pb + B_CRAD]
            kn, cn, mu = P[pb + B_KN], P[pb + B_CN], P[pb + B_MU]
            for k in range(int(P[pb + B_NCONT])):
                cx = P[pb + B_CPTS + 3 * k]
                cy = P[pb + B_CPTS + 3 * k + 1]
                cz = P[pb + B_CPTS + 3 * k + 2]
                z = x[o + 2] + R[b, 2, 0] * cx + R[b, 2, 1] * cy + R[b, 2, 2] * cz - rad
                if z >= 0.0:
                    continue
                # The sphere touches at its lowest point: lever r − rad Rᵀe_z (body).
                lx = cx - rad * R[b, 2, 0]
                ly = cy - rad * R[b, 2, 1]
                lz = cz - rad * R[b, 2, 2]
                vx, vy, vz = _point_velocity(x, R, b, lx, ly, lz)
                N = -kn * z - cn * vz
                if N <= 0.0:
                    continue
                vreg = max(P[pb + B_VEPS], mu * N / P[pb + B_CTMAX])
                f = mu * N / math.sqrt(vx * vx + vy * vy + vreg * vreg)
                _apply_force(R, Fw, Tb, b, lx, ly, lz, -f * vx, -f * vy, N)
                mur = P[pb + B_MUROLL] * N * rad
                if mur > 0.0:
                    wx, wy, wz = x[o + RATES], x[o + RATES + 1], x[o + RATES + 2]
                    wreg = max(P[pb + B_WEPS], mur / P[pb + B_CRMAX])
                    tr = mur / math.sqrt(wx * wx + wy * wy + wz * wz + wreg * wreg)
                    Tb[b, 0] -= tr * wx
                    Tb[b, 1] -= tr * wy
                    Tb[b, 2] -= tr * wz

    # Newton–Euler per body: ṗ = v, v̇ = F/m, q̇ = ½ q ⊗ (0, ω), J ω̇ = τ − ω × J ω.
    for b in range(n + 1):
        o = b * BODY_SIZE
        pb = body_block(b)
        if P[pb + B_ANCHOR] > 0.5:
            for k in range(BODY_SIZE):
                out[o + k] = 0.0
            continue
        m = P[pb + B_MASS]
        out[o] = x[o + VEL]
        out[o + 1] = x[o + VEL + 1]
        out[o + 2] = x[o + VEL + 2]
        out[o + VEL] = Fw[b, 0] / m
        out[o + VEL + 1] = Fw[b, 1] / m
        out[o + VEL + 2] = Fw[b, 2] / m
        qw, qx, qy, qz = x[o + QUAT], x[o + QUAT + 1], x[o + QUAT + 2], x[o + QUAT + 3]
        wx, wy, wz = x[o + RATES], x[o + RATES + 1], x[o + RATES + 2]
        out[o + QUAT] = 0.5 * (-qx * wx - qy * wy - qz * wz)
        out[o + QUAT + 1] = 0.5 * (qw * wx + qy * wz - qz * wy)
        out[o + QUAT + 2] = 0.5 * (qw * wy - qx * wz + qz * wx)
        out[o + QUAT + 3] = 0.5 * (qw * wz + qx * wy - qy * wx)
        J = pb + B_J
        hx = P[J] * wx + P[J + 1] * wy + P[J + 2] * wz
        hy = P[J + 3] * wx + P[J + 4] * wy + P[J + 5] * wz
        hz = P[J + 6] * wx + P[J + 7] * wy + P[J + 8] * wz
        ex = Tb[b, 0] - (wy * hz - wz * hy)
        ey = Tb[b, 1] - (wz * hx - wx * hz)
        ez = Tb[b, 2] - (wx * hy - wy * hx)
        Ji = pb + B_JINV
        out[o + RATES] = P[Ji] * ex + P[Ji + 1] * ey + P[Ji + 2] * ez
        out[o + RATES + 1] = P[Ji + 3] * ex + P[Ji + 4] * ey + P[Ji + 5] * ez
        out[o + RATES + 2] = P[Ji + 6] * ex + P[Ji + 7] * ey + P[Ji + 8] * ez

    # First-order motor lag toward the saturated command; time constant 0 means the
    # state is the command itself (set by ``advance``), so it does not move here.
    for i in range(n):
        a = act + i * ACT_SIZE
        pl = lag_block(n, i)
        tau_f, tau_t = P[pl + L_TAU_F], P[pl + L_TAU_T]
        out[a] = (cmd[4 * i] - x[a]) / tau_f if tau_f > 0.0 else 0.0
        for k in range(1, 4):
            out[a + k] = (cmd[4 * i + k] - x[a + k]) / tau_t if tau_t > 0.0 else 0.0


@_jit
def advance(
    x: FloatArray, P: FloatArray, cmd: FloatArray, ext: FloatArray, t0: float, h: float, n: int
) -> None:
    """Integrate x (in place) over n fixed RK4 steps of h [s] from t0 [s], holding the
    commands ``cmd`` (4 N,) and the external loads ``ext``; quaternions are renormalized
    after every step."""
    n_uavs = int(P[G_NUAV])
    size = state_size(n_uavs)
    act = actuator_offset(n_uavs)
    R = np.empty((n_uavs + 1, 3, 3))
    Fw = np.empty((n_uavs + 1, 3))
    Tb = np.empty((n_uavs + 1, 3))
    k1 = np.empty(size)
    k2 = np.empty(size)
    k3 = np.empty(size)
    k4 = np.empty(size)
    xt = np.empty(size)
    for i in range(n_uavs):
        pl = lag_block(n_uavs, i)
        a = act + i * ACT_SIZE
        if P[pl + L_TAU_F] <= 0.0:
            x[a] = cmd[4 * i]
        if P[pl + L_TAU_T] <= 0.0:
            for k in range(1, 4):
                x[a + k] = cmd[4 * i + k]
    half = 0.5 * h
    for step in range(n):
        # Time from the step index, not by accumulation, so it never drifts.
        t = t0 + step * h
        derivative(t, x, P, cmd, ext, R, Fw, Tb, k1)
        for k in range(size):
            xt[k] = x[k] + half * k1[k]
        derivative(t + half, xt, P, cmd, ext, R, Fw, Tb, k2)
        for k in range(size):
            xt[k] = x[k] + half * k2[k]
        derivative(t + half, xt, P, cmd, ext, R, Fw, Tb, k3)
        for k in range(size):
            xt[k] = x[k] + h * k3[k]
        derivative(t + h, xt, P, cmd, ext, R, Fw, Tb, k4)
        sixth = h / 6.0
        for k in range(size):
            x[k] += sixth * (k1[k] + 2.0 * k2[k] + 2.0 * k3[k] + k4[k])
        for b in range(n_uavs + 1):
            o = b * BODY_SIZE + QUAT
            norm = math.sqrt(x[o] ** 2 + x[o + 1] ** 2 + x[o + 2] ** 2 + x[o + 3] ** 2)
            for k in range(4):
                x[o + k] /= norm


@_jit
def diagnostics(x: FloatArray, P: FloatArray, out: FloatArray) -> None:
    """Cable tensions/stretch/slack, ground-contact flags and the energy terms of state x
    into ``out`` (diagnostics_size(N),); see the D_* offsets. Energies [J]: kinetic
    (translation + rotation), gravitational (zero at z = 0, CoM heights), cable springs
    ½ k s² (taut only) and ground springs ½ k δ² (penetrating points only)."""
    n = int(P[G_NUAV])
    R = np.empty((n + 1, 3, 3))
    _rotations(x, R)
    g = P[G_GRAV]
    spring = 0.0
    for c in range(n):
        stretch, rate, _, _, _, _ = _cable(x, P, R, c)
        T = _tension(P, c, stretch, rate)
        out[D_TENSION * n + c] = T
        out[D_STRETCH * n + c] = stretch
        out[D_STRETCH_RATE * n + c] = rate
        out[D_SLACK * n + c] = 1.0 if stretch <= 0.0 else 0.0
        if stretch > 0.0:
            spring += 0.5 * P[cable_block(n, c) + C_K] * stretch * stretch
    kinetic = 0.0
    gravity = 0.0
    contact = 0.0
    ground = P[G_GROUND] > 0.5
    for b in range(n + 1):
        o = b * BODY_SIZE
        pb = body_block(b)
        m = P[pb + B_MASS]
        v2 = x[o + VEL] ** 2 + x[o + VEL + 1] ** 2 + x[o + VEL + 2] ** 2
        wx, wy, wz = x[o + RATES], x[o + RATES + 1], x[o + RATES + 2]
        J = pb + B_J
        hx = P[J] * wx + P[J + 1] * wy + P[J + 2] * wz
        hy = P[J + 3] * wx + P[J + 4] * wy + P[J + 5] * wz
        hz = P[J + 6] * wx + P[J + 7] * wy + P[J + 8] * wz
        kinetic += 0.5 * m * v2 + 0.5 * (wx * hx + wy * hy + wz * hz)
        gravity += m * g * x[o + 2]
        touching = 0.0
        rad = P[pb + B_CRAD]
        for k in range(int(P[pb + B_NCONT])):
            cx = P[pb + B_CPTS + 3 * k]
            cy = P[pb + B_CPTS + 3 * k + 1]
            cz = P[pb + B_CPTS + 3 * k + 2]
            z = x[o + 2] + R[b, 2, 0] * cx + R[b, 2, 1] * cy + R[b, 2, 2] * cz - rad
            if ground and z < 0.0:
                touching = 1.0
                contact += 0.5 * P[pb + B_KN] * z * z
        out[D_ON_GROUND * n + b] = touching
    e = energy_offset(n)
    out[e + D_KINETIC] = kinetic
    out[e + D_GRAVITY] = gravity
    out[e + D_CABLE_SPRING] = spring
    out[e + D_CONTACT_SPRING] = contact
