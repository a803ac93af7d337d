"""The optimal-control QP every back-end solves, and the small interface they share.

    min  Σ_{k=0}^{N-1} ((Δx_k − x̄_k)ᵀ Q (Δx_k − x̄_k) + (Δu_k − ū_k)ᵀ R (Δu_k − ū_k))
           + (Δx_N − x̄_N)ᵀ Q_N (Δx_N − x̄_N)
    s.t. Δx_{k+1} = A Δx_k + B Δu_k,   Δx_0 = x0,
         u_lb ≤ Δu_k ≤ u_ub            (k = 0 … N-1),
         x_lb ≤ Δx_k ≤ x_ub            (k = 1 … N-1, optional; ±inf entries are free),
         xN_lb ≤ Δx_N ≤ xN_ub          (optional)

This is (MPC) of Section IV in deviation coordinates (Δx = x − x_eq, Δu = u − u_eq):
A and B are the same on every stage but change every tick; Q, R, Q_N are diagonal.

x̄_k and ū_k are per-stage tracking targets (``x_target`` (N + 1, nx), ``u_target``
(N, nu)); either left at None is zero, and with both None the cost is the regulation
problem Σ Δx_kᵀ Q Δx_k + Δu_kᵀ R Δu_k + Δx_Nᵀ Q_N Δx_N. Expanded, the targets only add
linear terms −2 (Q x̄_k)ᵀ Δx_k and −2 (R ū_k)ᵀ Δu_k (−2 (Q_N x̄_N)ᵀ Δx_N at N) and a
constant: the Hessian and the constraints do not depend on them, and x̄_0 (Δx_0 is fixed)
changes only the constant.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from geometry.arrays import FloatArray


class QpStatus(Enum):
    """How a solve ended. Only ``SOLVED`` gives an input that may be applied."""

    SOLVED = "solved"
    MAX_ITERATIONS = "max_iterations"
    INFEASIBLE = "infeasible"
    NUMERICAL_ERROR = "numerical_error"


@dataclass(frozen=True)
class OcpQp:
    """One tick's QP data. Shapes: A (nx, nx), B (nx, nu), q/q_N (nx,), r (nu,);
    the optional targets x_target (N + 1, nx) and u_target (N, nu) (None: zero)."""

    A: FloatArray
    B: FloatArray
    q_diag: FloatArray
    r_diag: FloatArray
    q_terminal_diag: FloatArray
    x0: FloatArray
    u_lb: FloatArray
    u_ub: FloatArray
    horizon: int
    x_lb: FloatArray | None = None
    x_ub: FloatArray | None = None
    x_terminal_lb: FloatArray | None = None
    x_terminal_ub: FloatArray | None = None
    x_target: FloatArray | None = None
    u_target: FloatArray | None = None

    @property
    def nx(self) -> int:
        return int(self.A.shape[0])

    @property
    def nu(self) -> int:
        return int(self.B.shape[1])


@dataclass(frozen=True)
class QpSolution:
    """Optimal trajectories: ``u`` shape (N, nu), ``x`` shape (N + 1, nx) (deviations)."""

    u: FloatArray
    x: FloatArray
    status: QpStatus
    iterations: int

    @staticmethod
    def failed(qp: OcpQp, status: QpStatus, iterations: int = 0) -> QpSolution:
        """No applicable solution: NaN trajectories of ``qp``'s shape, and why."""
        N = qp.horizon
        return QpSolution(
            np.full((N, qp.nu), np.nan), np.full((N + 1, qp.nx), np.nan), status, iterations
        )


class QpBackend(Protocol):
    """A QP solver for ``OcpQp`` of fixed dimensions, warm-started from its last solve."""

    name: str

    def prepare(self, qp: OcpQp) -> None:
        """Precompute what depends on ``qp``'s model (A, B, weights) alone, before its state
        is known; a ``solve`` with the same model then does less. May do nothing."""
        ...

    def solve(self, qp: OcpQp) -> QpSolution:
        """Solve one tick's QP. Never raises for a bad QP: the status says what happened."""
        ...
