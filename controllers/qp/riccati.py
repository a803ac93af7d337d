"""The QP of base.py without its boxes, as a linear map of the initial state (and of the
targets).

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

Tracking targets (base.py: x̄_k, ū_k) leave every matrix above alone and add the linear
cost −2 Σ ((Q x̄_k)ᵀ x_k + (R ū_k)ᵀ u_k) − 2 (Q_N x̄_N)ᵀ x_N: the solution becomes affine,
U = K Δx₀ + U_t, with U_t linear in the targets. Condensed like the quadratic terms, a
block of stages s … s+M−1 (x_{s+j} = Φ_j x + Γ_j U) with the stacked targets
x̄_s = (x̄_s … x̄_{s+M−1}), ū_s = (ū_s … ū_{s+M−1}), W = blkdiag(Q) and R_s = blkdiag(R)
has the linear cost −2 (ρᵀU + σᵀx) with

    ρ = R_s ū_s + ΓᵀW x̄_s,    σ = ΦᵀW x̄_s

(the cross terms of Σ_j (Φ_j x + Γ_j U − x̄_{s+j})ᵀ Q (…) and of (U − ū_s)ᵀ R_s (U − ū_s)).
With the cost-to-go x_endᵀ P x_end − 2 πᵀ x_end after the block (π = Q_N x̄_N after the
last), setting the gradient in U of the block's cost plus cost-to-go to zero,
H U + G x − ρ − B̄ᵀπ = 0, gives U = K_k x + k_k; the minimum over U leaves the linear
term −2 (σ + Āᵀπ − Gᵀk_k)ᵀ x, and −Gᵀ = K_kᵀ H:

    k_k = H⁻¹ (ρ + B̄ᵀ π),
    π  ← σ + Āᵀπ − Gᵀk_k = σ + Āᵀπ + K_kᵀ (ρ + B̄ᵀπ) = σ + K_kᵀ ρ + (Ā + B̄ K_k)ᵀ π.

x̄_0 only enters the first block's σ, whose π is never needed (Δx₀ is fixed). U_t and
the block starts' part z_t then follow forward from z_t = 0:

    U_t = k_k + K_k z_t,    z_t ← (Ā + B̄ K_k) z_t + B̄ k_k.

Per tick this is two matrix products for the ρ and σ of all the blocks of one length
(WΓ and WΦ are the same for each), then per block one matrix–vector product with
[[H⁻¹, H⁻¹B̄ᵀ], [K_kᵀ, (Ā + B̄K_k)ᵀ]] on (ρ, π) backward (and the sum with σ) and one
with [[K_k, I], [Ā + B̄K_k, B̄]] on (z_t, k_k) forward. H⁻¹ comes from the Cholesky
factors of H that the map keeps (no new factorization). These matrices are built at the
first solve with targets (``TargetRecursion``), or ahead by reading
``UnboxedSolutionMap.target_recursion``, so building and applying a map that never sees
targets costs what it did before.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from scipy.linalg.lapack import dpotrf, dpotri, dpotrs

from controllers.qp.partial_condensing import CondensedBlock
from geometry.arrays import FloatArray


@dataclass(frozen=True)
class _Run:
    """Consecutive blocks with the same condensed data, ``count`` blocks of ``stages``
    stages from stage ``first_stage``: ``gamma_w`` (M·nx, M·nu) = WΓ and ``phi_w``
    (M·nx, nx) = WΦ turn a row of state targets into its ρ and σ, ``r_tile`` (M·nu,) is
    R_s's diagonal; ``rho`` (count, M·nu) and ``sigma`` (count, nx) are the work buffers'
    views they go to."""

    count: int
    first_stage: int
    stages: int
    gamma_w: FloatArray
    phi_w: FloatArray
    r_tile: FloatArray
    rho: FloatArray
    sigma: FloatArray


class TargetRecursion:
    """The targets' part of the box-free solution (see the module docstring). It keeps
    its work buffers, so one instance serves one solve at a time.

    Block k's row of ``_work`` holds (ρ_k, π_{k+1}); ``_trajectory`` holds (z_0, k_0, U_0,
    z_1, k_1, U_1, …, z_blocks), z_0 = 0 for good. Every step is one ``np.dot`` whose result
    lands where the next step reads it. Backward, from the last block:
    [[H⁻¹, H⁻¹B̄ᵀ], [K_kᵀ, (Ā + B̄K_k)ᵀ]] (ρ_k, π_{k+1}) = (k_k, π_k − σ_k) goes to k_k's
    place and on over U_k's (free until the forward pass), and π_k = (π_k − σ_k) + σ_k to
    the row before. Forward, [[K_k, I], [Ā + B̄K_k, B̄]] (z_k, k_k) = (U_k, z_{k+1}) goes
    right behind its input.
    """

    def __init__(
        self,
        blocks: Sequence[CondensedBlock],
        gains: Sequence[FloatArray],
        factors: Sequence[FloatArray],
        weights: tuple[FloatArray, FloatArray, FloatArray],
    ) -> None:
        q_diag, r_diag, self._terminal_weight = weights
        nx = q_diag.size
        sizes = [K.shape[0] for K in gains]  # M·nu of each block
        self.horizon = sum(block.phi.shape[0] for block in blocks) // nx
        self._work = np.zeros(sum(sizes) + len(sizes) * nx)
        self._trajectory = np.zeros(2 * sum(sizes) + (len(sizes) + 1) * nx)
        work_at = np.cumsum([0] + [size + nx for size in sizes])  # block k's row
        z_at = np.cumsum([0] + [nx + 2 * size for size in sizes])  # z_k
        rows = [self._work[w : w + size + nx] for w, size in zip(work_at, sizes, strict=False)]
        runs: list[_Run] = []
        b = first_stage = 0
        while b < len(blocks):
            block, size, count = blocks[b], sizes[b], 1
            while b + count < len(blocks) and blocks[b + count] is block:
                count += 1
            stages = block.phi.shape[0] // nx
            run_rows = self._work[work_at[b] : work_at[b + count]].reshape(count, size + nx)
            w = np.tile(q_diag, stages)[:, None]
            gamma_w, phi_w, r_tile = w * block.gamma, w * block.phi, np.tile(r_diag, stages)
            sigma = np.zeros((count, nx))
            runs.append(
                _Run(count, first_stage, stages, gamma_w, phi_w, r_tile, run_rows[:, :size], sigma)
            )
            b += count
            first_stage += count * stages
        self._runs = tuple(runs)
        self._terminal = rows[-1][-nx:]  # π after the last block
        sigmas = [row for run in runs for row in run.sigma]
        backward_steps, forward_steps = [], []
        for b, (block, K, factor) in enumerate(zip(blocks, gains, factors, strict=True)):
            size, z = sizes[b], z_at[b]
            closed_loop = block.A + block.B @ K
            inverse = _cholesky_inverse(factor)
            backward = np.empty((size + nx, size + nx))
            backward[:size, :size] = inverse
            backward[:size, size:] = inverse @ block.B.T
            backward[size:, :size] = K.T
            backward[size:, size:] = closed_loop.T
            result = self._trajectory[z + nx : z + 2 * nx + size]
            pi = (result[size:], sigmas[b], rows[b - 1][-nx:]) if b else None
            backward_steps.append((backward, rows[b], result, pi))
            forward = np.zeros((size + nx, nx + size))
            forward[:size, :nx] = K
            forward[np.arange(size), nx + np.arange(size)] = 1.0
            forward[size:, :nx] = closed_loop
            forward[size:, nx:] = block.B
            forward_steps.append(
                (
                    forward,
                    self._trajectory[z : z + nx + size],
                    self._trajectory[z + nx + size : z_at[b + 1] + nx],
                )
            )
        self._backward_steps = tuple(reversed(backward_steps))
        self._forward_steps = tuple(forward_steps)
        self._u_index = np.concatenate(
            [
                np.arange(z + nx + size, z + nx + 2 * size)
                for z, size in zip(z_at, sizes, strict=False)
            ]
        )
        self._z_index = np.concatenate([np.arange(z, z + nx) for z in z_at[1:]])

    def solve(
        self, x_target: FloatArray | None, u_target: FloatArray | None
    ) -> tuple[FloatArray, FloatArray]:
        """The targets' part of the stacked inputs (N·nu,) and of the block starts after
        the first (blocks·nx,)."""
        for run in self._runs:
            stages = slice(run.first_stage, run.first_stage + run.count * run.stages)
            if x_target is None:
                run.rho.fill(0.0)
                run.sigma.fill(0.0)
            else:
                state_rows = x_target[stages].reshape(run.count, -1)
                np.matmul(state_rows, run.gamma_w, out=run.rho)
                np.matmul(state_rows, run.phi_w, out=run.sigma)
            if u_target is not None:
                input_rows = u_target[stages].reshape(run.count, -1)
                np.add(run.rho, input_rows * run.r_tile, out=run.rho)
        if x_target is None:
            self._terminal.fill(0.0)
        else:
            np.multiply(x_target[self.horizon], self._terminal_weight, out=self._terminal)
        dot, add = np.dot, np.add
        for gain, row, result, pi in self._backward_steps:
            dot(gain, row, out=result)
            if pi is not None:
                add(*pi)
        for gain, start, result in self._forward_steps:
            dot(gain, start, out=result)
        return self._trajectory[self._u_index], self._trajectory[self._z_index]


@dataclass(frozen=True)
class UnboxedSolutionMap:
    """``inputs`` (N·nu, nx): the box-free QP's optimal inputs, stacked, as a linear map
    of Δx₀; ``starts`` ((blocks + 1)·nx, nx): each block's start state and the final one.
    ``gains`` (K_k), ``factors`` (H's upper Cholesky factors) and the weights give the
    targets' part; a map built without the stage weights solves without targets only."""

    inputs: FloatArray
    starts: FloatArray
    blocks: tuple[CondensedBlock, ...]
    horizon: int
    gains: tuple[FloatArray, ...] = ()
    factors: tuple[FloatArray, ...] = ()
    weights: tuple[FloatArray, FloatArray, FloatArray] | None = None
    """(Q, R, Q_N) diagonals."""

    def solve(
        self,
        x0: FloatArray,
        x_target: FloatArray | None = None,
        u_target: FloatArray | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """(u (N, nu), x (N + 1, nx)) of the box-free QP from ``x0``, tracking
        ``x_target`` (N + 1, nx) and ``u_target`` (N, nu) (None: zero)."""
        nx = x0.size
        inputs = self.inputs @ x0
        starts = (self.starts @ x0).reshape(-1, nx)
        if x_target is not None or u_target is not None:
            target_inputs, target_starts = self.target_recursion.solve(x_target, u_target)
            inputs += target_inputs
            starts[1:] += target_starts.reshape(-1, nx)
        states, first = [], 0
        for k, block in enumerate(self.blocks):
            size = block.gamma.shape[1]
            states.append(block.states(starts[k], inputs[first : first + size]))
            first += size
        states.append(starts[-1:])
        return inputs.reshape(self.horizon, -1), np.vstack(states)

    @cached_property
    def target_recursion(self) -> TargetRecursion:
        """The targets' part, built at its first use. Raises ``ValueError`` when the map
        was built without the stage weights."""
        if self.weights is None:
            raise ValueError("this solution map was built without the stage weights")
        return TargetRecursion(self.blocks, self.gains, self.factors, self.weights)


def _cholesky(H: FloatArray) -> FloatArray:
    """H's upper Cholesky factor, straight through LAPACK (scipy's checked wrappers cost
    more than the factorization at these sizes). Raises ``LinAlgError`` if H is not
    positive definite."""
    factor, info = dpotrf(H, lower=False, clean=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"Hessian block not positive definite (dpotrf info {info})")
    result: FloatArray = factor
    return result


def _cholesky_solve(factor: FloatArray, G: FloatArray) -> FloatArray:
    """H⁻¹ G from H's factor (``_cholesky``)."""
    solution, info = dpotrs(factor, G, lower=False)
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotrs info {info}")
    result: FloatArray = solution
    return result


def _cholesky_inverse(factor: FloatArray) -> FloatArray:
    """H⁻¹ from H's factor (``_cholesky``)."""
    upper, info = dpotri(factor, lower=False)  # H⁻¹'s upper triangle
    if info != 0:
        raise np.linalg.LinAlgError(f"dpotri info {info}")
    below = np.tri(upper.shape[0], k=-1, dtype=bool)
    result: FloatArray = np.where(below, upper.T, upper)
    return result


def unboxed_solution_map(
    blocks: Sequence[CondensedBlock],
    q_terminal_diag: FloatArray,
    q_diag: FloatArray | None = None,
    r_diag: FloatArray | None = None,
) -> UnboxedSolutionMap:
    """The map for the horizon made of ``blocks`` (in order) with terminal weight Q_N;
    given the stage weights the blocks were condensed with, it solves with targets too."""
    nx = q_terminal_diag.size
    P = np.diag(q_terminal_diag)
    gains: list[FloatArray] = []
    factors: list[FloatArray] = []
    for block in reversed(blocks):
        nu = block.B.shape[1]
        BA = np.hstack([block.B, block.A])
        BA_P_BA = BA.T @ (P @ BA)
        H = block.R + BA_P_BA[:nu, :nu]
        G = block.S + BA_P_BA[:nu, nu:]
        factor = _cholesky(H)
        K = -_cholesky_solve(factor, G)
        P = block.Q + BA_P_BA[nu:, nu:] + G.T @ K
        P = 0.5 * (P + P.T)  # rounding must not let the cost-to-go drift from symmetric
        gains.append(K)
        factors.append(factor)
    gains.reverse()
    factors.reverse()
    start = np.eye(nx)  # x_k as a map of x_0
    input_rows, start_rows = [], [start]
    for block, K in zip(blocks, gains, strict=True):
        U = K @ start
        input_rows.append(U)
        start = block.A @ start + block.B @ U
        start_rows.append(start)
    horizon = sum(block.phi.shape[0] for block in blocks) // nx
    weights = None
    if q_diag is not None and r_diag is not None:
        weights = (np.array(q_diag, float), np.array(r_diag, float), q_terminal_diag.astype(float))
    return UnboxedSolutionMap(
        np.vstack(input_rows),
        np.vstack(start_rows),
        tuple(blocks),
        horizon,
        tuple(gains),
        tuple(factors),
        weights,
    )
