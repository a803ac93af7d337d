"""Partial condensing of the time-invariant OCP-QP of base.py into blocks of stages.

A block of M stages starting at state x, with inputs U = (u_0, …, u_{M−1}), has the
states x_j = Φ_j x + Γ_j U (Φ_j = A^j; Γ_j holds A^{j−1−i} B in column block i < j) and
ends at A^M x + [A^{M−1} B … B] U. Its cost Σ_j x_jᵀ Q x_j + u_jᵀ R u_j is then

    [U; x]ᵀ [R̄  S̄; S̄ᵀ Q̄] [U; x],  R̄ = blkdiag(R) + Σ Γ_jᵀ Q Γ_j,  S̄ = Σ Γ_jᵀ Q Φ_j,
                                    Q̄ = Σ Φ_jᵀ Q Φ_j,

so the horizon of N stages becomes a shorter one of blocks with M·nu inputs each — fewer,
larger stages, which the Riccati recursion handles with far fewer operations per state.
A and B are the same on every stage, so every block of the same length has the same data:
one condensing per tick and per block length.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from geometry.arrays import FloatArray


def block_lengths(horizon: int, block_stages: int) -> tuple[int, ...]:
    """Stages per block: full blocks of ``block_stages``, a shorter last one if needed."""
    if block_stages < 1:
        raise ValueError("a block holds at least one stage")
    full, rest = divmod(horizon, block_stages)
    return (block_stages,) * full + ((rest,) if rest else ())


@dataclass(frozen=True)
class CondensedBlock:
    """One block's data. Shapes: A (nx, nx), B (nx, M·nu), R (M·nu, M·nu), S (M·nu, nx),
    Q (nx, nx); ``phi`` (M·nx, nx) and ``gamma`` (M·nx, M·nu) give the block's states."""

    A: FloatArray
    B: FloatArray
    R: FloatArray
    S: FloatArray
    Q: FloatArray
    phi: FloatArray
    gamma: FloatArray

    def states(self, x_start: FloatArray, inputs: FloatArray) -> FloatArray:
        """The block's M states (x_0 = ``x_start`` first), shape (M, nx)."""
        nx = x_start.size
        stacked: FloatArray = self.phi @ x_start + self.gamma @ inputs
        return stacked.reshape(-1, nx)


def condense(
    A: FloatArray, B: FloatArray, q_diag: FloatArray, r_diag: FloatArray, stages: int
) -> CondensedBlock:
    """The condensed data of a block of ``stages`` stages of (A, B, diag q, diag r)."""
    nx, nu = B.shape
    powers = [np.eye(nx)]
    for _ in range(stages):
        powers.append(A @ powers[-1])
    phi = np.vstack(powers[:stages])
    impulse = [powers[j] @ B for j in range(stages)]  # A^j B
    gamma = np.zeros((stages * nx, stages * nu))
    for j in range(1, stages):
        for i in range(j):
            gamma[j * nx : (j + 1) * nx, i * nu : (i + 1) * nu] = impulse[j - 1 - i]
    weight = np.tile(q_diag, stages)[:, None]
    weighted_gamma = weight * gamma
    R = gamma.T @ weighted_gamma
    R[np.diag_indices_from(R)] += np.tile(r_diag, stages)
    S = weighted_gamma.T @ phi
    Q = phi.T @ (weight * phi)
    B_block = np.hstack(impulse[::-1])
    return CondensedBlock(powers[stages], B_block, R, S, Q, phi, gamma)
