"""Condensed dense QP: states eliminated, solved by DAQP (an exact dual active-set solver).

With X = Φ x0 + Γ U the cost becomes UᵀH U + 2 gᵀU. H and g are built with backward
recursions instead of forming Γ (O(N² nx nu²) rather than O(N² nx² nu²)):

    P_{N-1} = Q_N,  P_j = Q + Aᵀ P_{j+1} A               (the weight seen by x_{j+1} onwards)
    H_{ij}  = (A^{j-i} B)ᵀ P_j B  (i ≤ j),  H_ii += R
    λ_N = Q_N A^N x0,  λ_k = Q A^k x0 + Aᵀ λ_{k+1},  g_i = Bᵀ λ_{i+1}.

Targets (base.py) change only g: the cost's deviations from them are A^k x0 − x̄_k on the
free response and U − Ū on the inputs, so

    λ_N = Q_N (A^N x0 − x̄_N),  λ_k = Q (A^k x0 − x̄_k) + Aᵀ λ_{k+1},  g_i = Bᵀ λ_{i+1} − R ū_i.

Input bounds are simple bounds; finite state bounds become general rows of Γ.
DAQP is warm-started with the previous active set.
"""

from __future__ import annotations

import daqp
import numpy as np

from controllers.qp.base import OcpQp, QpSolution, QpStatus
from geometry.arrays import FloatArray

_DAQP_OPTIMAL = (1, 2)  # optimal, soft-optimal
_DAQP_INFEASIBLE = (-1,)


class CondensedDaqpBackend:
    """``QpBackend``: condense in numpy, solve with DAQP."""

    name = "daqp"

    def __init__(self, template: OcpQp) -> None:
        self._dims = (template.nx, template.nu, template.horizon)
        self._active: np.ndarray | None = None

    def _powers_times_b(self, A: FloatArray, B: FloatArray) -> FloatArray:
        """AB[m] = A^m B for m = 0 … N-1, shape (N, nx, nu)."""
        N = self._dims[2]
        out = np.empty((N, *B.shape))
        out[0] = B
        for m in range(1, N):
            out[m] = A @ out[m - 1]
        return out

    def _free_response(self, A: FloatArray, x0: FloatArray) -> FloatArray:
        """A^k x0 for k = 0 … N, shape (N + 1, nx)."""
        N = self._dims[2]
        out = np.empty((N + 1, x0.size))
        out[0] = x0
        for k in range(1, N + 1):
            out[k] = A @ out[k - 1]
        return out

    def condense(self, qp: OcpQp) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(H, g, AB, free) of the condensed problem min UᵀHU + 2gᵀU."""
        nx, nu, N = self._dims
        A, B = qp.A, qp.B
        Q, Q_N, R = np.diag(qp.q_diag), np.diag(qp.q_terminal_diag), qp.r_diag
        P = np.empty((N, nx, nx))
        P[N - 1] = Q_N
        for j in range(N - 2, -1, -1):
            P[j] = Q + A.T @ P[j + 1] @ A
        PB = P @ B  # (N, nx, nu)
        AB = self._powers_times_b(A, B)
        H = np.zeros((N * nu, N * nu))
        blocks = H.reshape(N, nu, N, nu)
        for d in range(N):
            # H_{i, i+d} = AB[d]ᵀ PB[i+d] for i = 0 … N-1-d
            upper = np.einsum("xa,ixb->iab", AB[d], PB[d:])
            idx = np.arange(N - d)
            blocks[idx, :, idx + d, :] = upper
            if d:
                blocks[idx + d, :, idx, :] = upper.transpose(0, 2, 1)
        H[np.diag_indices_from(H)] += np.tile(R, N)
        free = self._free_response(A, qp.x0)
        deviation = free if qp.x_target is None else free - qp.x_target
        lam = np.empty((N + 1, nx))
        lam[N] = Q_N @ deviation[N]
        for k in range(N - 1, 0, -1):
            lam[k] = Q @ deviation[k] + A.T @ lam[k + 1]
        g = (lam[1:] @ B).reshape(-1)
        if qp.u_target is not None:
            g -= (qp.u_target * R).reshape(-1)
        return H, g, AB, free

    def _state_rows(
        self, qp: OcpQp, AB: FloatArray, free: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """General rows G U ∈ [lo, hi] for the finite state bounds (k = 1 … N)."""
        nx, nu, N = self._dims
        rows, lower, upper = [], [], []
        for k in range(1, N + 1):
            lb = qp.x_terminal_lb if k == N else qp.x_lb
            ub = qp.x_terminal_ub if k == N else qp.x_ub
            if lb is None and ub is None:
                continue
            lo = np.full(nx, -np.inf) if lb is None else lb
            hi = np.full(nx, np.inf) if ub is None else ub
            finite = np.flatnonzero(np.isfinite(lo) | np.isfinite(hi))
            if finite.size == 0:
                continue
            gamma = np.zeros((nx, N * nu))
            for j in range(k):
                gamma[:, j * nu : (j + 1) * nu] = AB[k - 1 - j]
            rows.append(gamma[finite])
            lower.append(lo[finite] - free[k][finite])
            upper.append(hi[finite] - free[k][finite])
        if not rows:
            return np.zeros((0, N * nu)), np.zeros(0), np.zeros(0)
        return np.vstack(rows), np.concatenate(lower), np.concatenate(upper)

    def prepare(self, qp: OcpQp) -> None:
        """Nothing to precompute: this back-end builds its data from the whole QP."""

    def solve(self, qp: OcpQp) -> QpSolution:
        """Condense, solve warm-started from the last active set, expand the states."""
        nx, nu, N = self._dims
        if not all(np.all(np.isfinite(a)) for a in (qp.A, qp.B, qp.x0)):
            return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
        if qp.x_target is not None or qp.u_target is not None:
            targets = (qp.x_target, qp.u_target)
            if not all(t is None or np.all(np.isfinite(t)) for t in targets):
                return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
        H, g, AB, free = self.condense(qp)
        G, g_lo, g_hi = self._state_rows(qp, AB, free)
        upper = np.concatenate([np.tile(qp.u_ub, N), g_hi])
        lower = np.concatenate([np.tile(qp.u_lb, N), g_lo])
        sense = np.zeros(upper.size, dtype=np.int32)
        if self._active is not None and self._active.size == sense.size:
            sense[:] = self._active
        U, _, exitflag, info = daqp.solve(H, g, G, upper, lower, sense)
        if exitflag not in _DAQP_OPTIMAL:
            self._active = None
            status = (
                QpStatus.INFEASIBLE if exitflag in _DAQP_INFEASIBLE else QpStatus.NUMERICAL_ERROR
            )
            return QpSolution.failed(qp, status, int(info.get("iterations", 0)))
        self._active = np.where(np.abs(info["lam"]) > 0.0, 1, 0).astype(np.int32)
        u = np.asarray(U).reshape(N, nu)
        trajectory = np.empty((N + 1, nx))
        trajectory[0] = qp.x0
        for k in range(N):
            trajectory[k + 1] = qp.A @ trajectory[k] + qp.B @ u[k]
        return QpSolution(
            u=u, x=trajectory, status=QpStatus.SOLVED, iterations=int(info.get("iterations", 0))
        )
