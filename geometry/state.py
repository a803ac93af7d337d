"""The state layouts' parts that do not depend on the number of UAVs, named once.

N UAVs carrying one rigid payload (model (5), generalized), x ∈ R^(12 + 12N): the
payload's block (p_b, v_b, Θ_b, ω_b) comes first, then one block per UAV
(``geometry.formation.FormationLayout``, which names every per-UAV index).
One UAV with its payload as a point mass, the decentralized agent's model (Section II-A,
model (1)), x_i ∈ R^18:
    x_i = (p_i, v_i, Θ_i, ω_i, p_p, v_p),  u_i = (F_i, τ_i) ∈ R^4.

Positions [m] in the arena's ENU frame, z up; Euler angles Θ = (φ, θ, ψ) Z-Y-X [rad]; UAV
rates ω_i in the body frame (FLU), the payload's ω_b in the inertial frame [rad/s]. Points
fixed on the payload are given in its own frame, from its CoM (``payload_points``).

Accessors work on numpy arrays and on CasADi symbols alike where they only slice.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from geometry.arrays import FloatArray
from geometry.frames import rotation_from_euler_zyx

# The payload's block, first in every formation's state.
P_B, V_B, TH_B, W_B = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
PAYLOAD_PITCH, PAYLOAD_YAW = 7, 8

# The 18-state of one decentralized agent: its UAV and its payload.
AGENT_STATES = 18
AGENT_INPUTS = 4
P_I, V_I, TH_I, W_I = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)
P_P, V_P = slice(12, 15), slice(15, 18)
UAV_BLOCK = slice(0, 12)  # (p_i, v_i, Θ_i, ω_i): the same as a formation's UAV block, shifted
AGENT_YAW_INDICES = (PAYLOAD_YAW,)  # ψ_i: the UAV's block has the payload block's layout


def payload_position(x: Any) -> Any:
    """p_b [m] (a view)."""
    return x[P_B]


def payload_velocity(x: Any) -> Any:
    """v_b [m/s] (a view)."""
    return x[V_B]


def payload_yaw(x: FloatArray) -> float:
    """ψ_b [rad]."""
    return float(x[PAYLOAD_YAW])


def payload_points(x: FloatArray, offsets_m: Sequence[Sequence[float]]) -> list[FloatArray]:
    """Where the payload-frame points ``offsets_m`` (from the CoM, e.g. the cable
    attachments a_i) are: p_b + R(Θ_b) a [m], one (3,) array each."""
    R = rotation_from_euler_zyx(*x[TH_B])
    return [x[P_B] + R @ offset for offset in offsets_m]


def stacked_agent_slice(i: int) -> slice:
    """Agent ``i``'s 18-state within the agents' states stacked side by side."""
    return slice(AGENT_STATES * (i - 1), AGENT_STATES * i)
