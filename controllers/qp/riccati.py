"""The QP of base.py without its boxes, as a linear map of the initial state.

Without boxes, (MPC) is a finite-horizon LQR problem: its optimal inputs are linear in
Δx₀ — U = K Δx₀ — with K fixed by (A, B, Q, R, Q_N) alone. A backward Riccati recursion
over the partially condensed blocks (partial_condensing.py) gives each block's feedback
U_k = K_k x_k; propagating the identity forward through the closed loop stacks them into
K, and the block-start states into a map of Δx₀ too. On a block with inputs U, start
state x, end state Ā x + B̄ U and cost-to-go x_endᵀ P x_end after it:

    [B̄ Ā]ᵀ P [B̄ Ā] = [[B̄ᵀPB̄, B̄ᵀPĀ], [·, ĀᵀPĀ]],   H = R̄ + B̄ᵀPB̄,   G = S̄ + B̄ᵀPĀ,
    K_k = −H⁻¹ G (H is positive definite: R̄ ⪰ R ≻ 0),   P ← Q̄ + ĀᵀPĀ + Gᵀ K_k.

The map depends on the model only, so it can be built before the state is known (the
"preparation" of a real-time MPC); applying it is a few matrix–vector products.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotrs

from controllers.qp.partial_condensing import CondensedBlock
from geometry.arrays import FloatArray


@dataclass(frozen=True)
class UnboxedSolutionMap:
    """``inputs`` (N·nu, nx): the box-free QP's optimal inputs, stacked, as a linear map
    of Δx₀; ``starts`` ((blocks + 1)·nx, nx): each block's start state and the final one."""

    inputs: FloatArray
    starts: FloatArray
    blocks: tuple[CondensedBlock, ...]
    horizon: int

    def solve(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(u (N, nu), x (N + 1, nx)) of the box-free QP from ``x0``."""
        nx = x0.size
        inputs = self.inputs @ x0
        starts = (self.starts @ x0).reshape(-1, nx)
        states, first = [], 0
        for k, block in enumerate(self.blocks):
            size = block.gamma.shape[1]
            states.append(block.states(starts[k], inputs[first : first + size]))
            first += size
        states.append(starts[-1:])
        return inputs.reshape(self.horizon, -1), np.vstack(states)


def _positive_definite_solve(H: FloatArray, G: FloatArray) -> FloatArray:
    """H⁻¹ G by Cholesky, straight through LAPACK (scipy's checked wrappers cost more than
    the factorization at these sizes). Raises ``LinAlgError`` if H is not positive definite."""
    factor, info = dpotrf(H, lower=False, clean=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"Hessian block not positive definite (dpotrf info {info})")
    solution, info = dpotrs(factor, G, lower=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotrs info {info}")
    result: FloatArray = solution
    return result


def unboxed_solution_map(
    blocks: Sequence[CondensedBlock], q_terminal_diag: FloatArray
) -> UnboxedSolutionMap:
    """The map for the horizon made of ``blocks`` (in order) with terminal weight Q_N."""
    nx = q_terminal_diag.size
    P = np.diag(q_terminal_diag)
    gains: list[FloatArray] = []
    for block in reversed(blocks):
        nu = block.B.shape[1]
        BA = np.hstack([block.B, block.A])
        BA_P_BA = BA.T @ (P @ BA)
        H = block.R + BA_P_BA[:nu, :nu]
        G = block.S + BA_P_BA[:nu, nu:]
        K = -_positive_definite_solve(H, G)
        P = block.Q + BA_P_BA[nu:, nu:] + G.T @ K
        P = 0.5 * (P + P.T)  # rounding must not let the cost-to-go drift from symmetric
        gains.append(K)
    gains.reverse()
    start = np.eye(nx)  # x_k as a map of x_0
    input_rows, start_rows = [], [start]
    for block, K in zip(blocks, gains, strict=True):
        U = K @ start
        input_rows.append(U)
        start = block.A @ start + block.B @ U
        start_rows.append(start)
    horizon = sum(block.phi.shape[0] for block in blocks) // nx
    return UnboxedSolutionMap(np.vstack(input_rows), np.vstack(start_rows), tuple(blocks), horizon)
