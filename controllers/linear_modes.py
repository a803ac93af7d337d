"""Modes of a controller's linear closed loop at an equilibrium of the formation: which
motions the MPC damps, and how fast, at a given reference (``benchmarks/modes.py`` prints
them; ``tests/controllers/test_closed_loop_modes.py`` checks them).

The plant is the formation model's Jacobian at the equilibrium, discretized exactly
(zero-order hold over one tick, not the controllers' first-order A = I + A_c h); the
controller enters by its gain, probed by finite differences of its own ``step`` (so the
real MPC and QP back-end are measured, not a textbook LQR). A mode is physical when it
keeps every cable's length (the index-reduced model also has modes that stretch a cable)
and, for a bar, does more than spin the bar about its own axis (a free rotation nothing
acts on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from controllers.codegen import NumericFunction
from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.linearization import formation_jacobians
from controllers.mpc import CentralizedMpc, DecentralizedMpc, agent_state
from geometry.state import P_I, P_P, PAYLOAD_YAW, TH_B, W_B

# φ_b and ω_b,x: a bar's rotation about its own axis (formation_from_bar's bar lies along
# the payload's x axis).
BAR_SPIN = (TH_B.start, W_B.start)
PAYLOAD_YAW_MOTION = (PAYLOAD_YAW, W_B.stop - 1)  # ψ_b and ω_b,z


@dataclass(frozen=True)
class ClosedLoopMode:
    magnitude: float
    """|λ| of the discrete closed loop; above 1 the mode grows."""
    frequency_hz: float
    shape: np.ndarray
    """The eigenvector, scaled to unit length."""

    def growth_per_s(self, dt_s: float) -> float:
        """The mode's exponential growth rate (negative: decay) [1/s]."""
        return math.log(self.magnitude) / dt_s


def zero_order_hold(A_c: np.ndarray, B_c: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """The exact discretization of ẋ = A_c x + B_c u with u held over ``h``."""
    n, m = B_c.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = A_c * h, B_c * h
    exponential = expm(augmented)
    return exponential[:n, :n], exponential[:n, n:]


def probed_gain(
    controller: CentralizedMpc | DecentralizedMpc,
    x_eq: np.ndarray,
    reference: FormationReference,
) -> np.ndarray:
    """K with u ≈ u_eq − K Δx near the equilibrium, from one-sided differences of ``step``."""
    delta = 1e-5
    controller.reset()
    u_eq = controller.step(x_eq.copy(), reference, 0.0).u
    gain = np.zeros((u_eq.size, x_eq.size))
    for j in range(x_eq.size):
        controller.reset()  # every probe is a first tick: no warm start from the others
        x = x_eq.copy()
        x[j] += delta
        gain[:, j] = -(controller.step(x, reference, 0.0).u - u_eq) / delta
    return gain


def _cable_lengths(state: np.ndarray, params: FormationParams) -> np.ndarray:
    ends = (agent_state(state, params, i) for i in params.layout.vehicles)
    return np.array([np.linalg.norm(x_i[P_I] - x_i[P_P]) for x_i in ends])


def _cable_length_jacobian(x: np.ndarray, params: FormationParams) -> np.ndarray:
    delta = 1e-7
    base = _cable_lengths(x, params)
    columns = []
    for j in range(x.size):
        moved = x.copy()
        moved[j] += delta
        columns.append((_cable_lengths(moved, params) - base) / delta)
    return np.array(columns).T


def physical_closed_loop_modes(
    controller: CentralizedMpc | DecentralizedMpc,
    params: FormationParams,
    reference: FormationReference,
) -> list[ClosedLoopMode]:
    """The physical modes of ``controller`` closing the loop at ``reference``'s
    equilibrium, fastest-growing first."""
    eq = formation_equilibrium(params, reference)
    A_c, B_c = NumericFunction(formation_jacobians(FormationModel(params)))(eq.x, eq.u)
    dt = controller.settings.dt_s
    A, B = zero_order_hold(np.asarray(A_c), np.asarray(B_c), dt)
    values, vectors = np.linalg.eig(A - B @ probed_gain(controller, eq.x, reference))
    stretch = _cable_length_jacobian(eq.x, params)
    spin = BAR_SPIN if params.payload.is_bar else ()
    others = [j for j in range(eq.x.size) if j not in spin]
    modes = []
    for value, vector in zip(values, vectors.T, strict=True):
        shape = vector / np.linalg.norm(vector)
        keeps_cables = np.abs(stretch @ shape).max() < 1e-6
        if keeps_cables and np.linalg.norm(shape[others]) > 1e-6:
            frequency_hz = abs(np.angle(value)) / (2 * math.pi * dt)
            modes.append(ClosedLoopMode(abs(value), frequency_hz, shape))
    return sorted(modes, key=lambda mode: -mode.magnitude)
