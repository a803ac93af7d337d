"""The paper's state layouts, named once: every index into a 36- or 18-state is here.

Bar system (Section II-B, model (5)), x ∈ R^36:
    x = (p_b, v_b, Θ_b, ω_b, p_1, v_1, Θ_1, ω_1, p_2, v_2, Θ_2, ω_2)
UAV–payload (Section II-A, model (1)), x_i ∈ R^18:
    x_i = (p_i, v_i, Θ_i, ω_i, p_p, v_p)
Inputs: u = (F_1, τ_1, F_2, τ_2) ∈ R^8, u_i = (F_i, τ_i) ∈ R^4.

Positions [m] in the arena's ENU frame, z up; Euler angles Θ = (φ, θ, ψ) Z-Y-X [rad]; UAV
rates ω_i in the body frame (FLU), the bar's ω_b in the inertial frame [rad/s]. The bar's
body x axis points from cable 1's attachment to cable 2's, so its ends are p_b − d_1 n_b
and p_b + d_2 n_b with n_b = R(Θ_b) e_x (n_b depends on θ_b and ψ_b only).

Accessors work on numpy arrays and on CasADi symbols alike where they only slice.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from geometry.arrays import FloatArray

BAR_STATES = 36
BAR_INPUTS = 8
PAYLOAD_STATES = 18
PAYLOAD_INPUTS = 4

# The bar's block of the 36-state.
P_B, V_B, TH_B, W_B = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
BAR_PITCH, BAR_YAW = 7, 8
UAV_OFFSETS = (12, 24)
_UAV_SIZE = 12
_YAW_IN_BLOCK = 8  # ψ within a (p, v, Θ, ω) block

# The 18-state of one UAV with its payload.
P_I, V_I, TH_I, W_I = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
P_P, V_P = slice(12, 15), slice(15, 18)
UAV_BLOCK = slice(0, 12)  # (p_i, v_i, Θ_i, ω_i): the same in both layouts, shifted
PAYLOAD_YAW_INDICES = (_YAW_IN_BLOCK,)  # ψ_i

# Inputs of the bar system: UAV i's thrust F_i and torque τ_i.
_UAV_INPUTS = 4


def uav_offset(i: int) -> int:
    """Where UAV ``i``'s (1 or 2) block starts in the 36-state."""
    return UAV_OFFSETS[i - 1]


def uav_slices(i: int) -> tuple[slice, slice, slice, slice]:
    """(p_i, v_i, Θ_i, ω_i) slices of UAV ``i`` (1 or 2) in the 36-state."""
    o = uav_offset(i)
    return slice(o, o + 3), slice(o + 3, o + 6), slice(o + 6, o + 9), slice(o + 9, o + 12)


def uav_block(i: int) -> slice:
    """UAV ``i``'s whole (p_i, v_i, Θ_i, ω_i) block in the 36-state."""
    o = uav_offset(i)
    return slice(o, o + _UAV_SIZE)


def uav_yaw_index(i: int) -> int:
    """Index of ψ_i in the 36-state."""
    return uav_offset(i) + _YAW_IN_BLOCK


YAW_INDICES = (BAR_YAW, uav_yaw_index(1), uav_yaw_index(2))  # ψ_b, ψ_1, ψ_2


def thrust_index(i: int) -> int:
    """Index of F_i in the 8-input u."""
    return _UAV_INPUTS * (i - 1)


def torque_slice(i: int) -> slice:
    """τ_i's slice in the 8-input u."""
    start = thrust_index(i) + 1
    return slice(start, start + 3)


def uav_input_slice(i: int) -> slice:
    """(F_i, τ_i) in the 8-input u."""
    start = thrust_index(i)
    return slice(start, start + _UAV_INPUTS)


# ---- readings of a numeric 36-state -------------------------------------------------------
def bar_position(x: Any) -> Any:
    """p_b [m] (a view)."""
    return x[P_B]


def bar_velocity(x: Any) -> Any:
    """v_b [m/s] (a view)."""
    return x[V_B]


def bar_yaw(x: FloatArray) -> float:
    """ψ_b [rad]."""
    return float(x[BAR_YAW])


def uav_position(x: Any, i: int) -> Any:
    """p_i [m] (a view)."""
    return x[uav_slices(i)[0]]


def uav_velocity(x: Any, i: int) -> Any:
    """v_i [m/s] (a view)."""
    return x[uav_slices(i)[1]]


def uav_euler(x: Any, i: int) -> Any:
    """Θ_i = (φ_i, θ_i, ψ_i) [rad] (a view)."""
    return x[uav_slices(i)[2]]


def uav_yaws(x: FloatArray) -> tuple[float, float]:
    """(ψ_1, ψ_2) [rad]."""
    return float(x[uav_yaw_index(1)]), float(x[uav_yaw_index(2)])


def bar_axis_from_angles(pitch_rad: float, yaw_rad: float) -> FloatArray:
    """n_b = R(Θ_b) e_x from the bar's pitch θ_b and yaw ψ_b."""
    cos_pitch = math.cos(pitch_rad)
    return np.array(
        [math.cos(yaw_rad) * cos_pitch, math.sin(yaw_rad) * cos_pitch, -math.sin(pitch_rad)]
    )


def bar_axis(x: FloatArray) -> FloatArray:
    """n_b of a 36-state: the unit vector along the bar, towards cable 2's attachment."""
    return bar_axis_from_angles(float(x[BAR_PITCH]), float(x[BAR_YAW]))


def bar_ends(x: FloatArray, arms_m: tuple[float, float]) -> tuple[FloatArray, FloatArray]:
    """The attachments of cables 1 and 2: p_b − d_1 n_b and p_b + d_2 n_b [m]."""
    n_b = bar_axis(x)
    return x[P_B] - arms_m[0] * n_b, x[P_B] + arms_m[1] * n_b


def stacked_agent_slice(i: int) -> slice:
    """Agent ``i``'s 18-state within the two agents' states stacked side by side (36,)."""
    return slice(PAYLOAD_STATES * (i - 1), PAYLOAD_STATES * i)
