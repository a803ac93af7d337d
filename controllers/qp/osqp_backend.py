"""OSQP on the sparse (multiple-shooting) formulation: the baseline and the fallback.

Variables z = (Δx_0, …, Δx_N, Δu_0, …, Δu_{N-1}); equality rows for Δx_0 = x0 and the
dynamics, box rows for inputs and finite state bounds. The sparsity pattern is fixed at
construction (from ``a_pattern``/``b_pattern``, the model's structural nonzeros) so each
tick only updates values.

OSQP minimizes ½ zᵀPz + qᵀz, so P holds twice the weights (``_cost``) and the targets
(base.py) become q = −2 (Q x̄_k, Q_N x̄_N, R ū_k) on their variables; x̄_0's entry is
left zero (Δx_0 is fixed: it would only shift that equality's multiplier). Without
targets q stays zero and is not updated.
"""

from __future__ import annotations

import numpy as np
import osqp
import scipy.sparse as sp

from controllers.qp.base import OcpQp, QpSolution, QpStatus
from geometry.arrays import FloatArray

_SOLVED = {"solved", "solved inaccurate"}
_INFEASIBLE = {
    "primal infeasible",
    "dual infeasible",
    "primal infeasible inaccurate",
    "dual infeasible inaccurate",
}


class OsqpBackend:
    """``QpBackend`` on OSQP (ADMM), warm-started with the previous primal–dual pair."""

    name = "osqp"

    def __init__(
        self,
        template: OcpQp,
        a_pattern: np.ndarray | None = None,
        b_pattern: np.ndarray | None = None,
        eps: float = 1e-6,
        max_iter: int = 20000,
    ) -> None:
        nx, nu, N = template.nx, template.nu, template.horizon
        self._dims = (nx, nu, N)
        self._a_mask = (
            np.ones((nx, nx), bool) if a_pattern is None else (a_pattern | np.eye(nx, dtype=bool))
        )
        self._b_mask = np.ones((nx, nu), bool) if b_pattern is None else b_pattern.astype(bool)
        self._state_rows = self._finite_rows(template.x_lb, template.x_ub, nx)
        self._terminal_rows = self._finite_rows(template.x_terminal_lb, template.x_terminal_ub, nx)
        constraint, self._value_slots = self._constraint_matrix(template)
        self._n_eq = nx * (N + 1)
        self._solver = osqp.OSQP()
        self._solver.setup(
            P=self._cost(template),
            q=np.zeros((N + 1) * nx + N * nu),
            A=constraint,
            l=self._lower(template),
            u=self._upper(template),
            eps_abs=eps,
            eps_rel=eps,
            max_iter=max_iter,
            polishing=True,
            verbose=False,
            warm_starting=True,
        )
        self._cost_key = self._weights_key(template)
        self._linear_cost_set = False  # whether q holds targets' terms rather than zeros

    @staticmethod
    def _finite_rows(lb: FloatArray | None, ub: FloatArray | None, nx: int) -> np.ndarray:
        if lb is None and ub is None:
            return np.zeros(0, dtype=int)
        lower = np.full(nx, -np.inf) if lb is None else lb
        upper = np.full(nx, np.inf) if ub is None else ub
        return np.flatnonzero(np.isfinite(lower) | np.isfinite(upper))

    @staticmethod
    def _weights_key(qp: OcpQp) -> bytes:
        return qp.q_diag.tobytes() + qp.r_diag.tobytes() + qp.q_terminal_diag.tobytes()

    def _cost(self, qp: OcpQp) -> sp.csc_matrix:
        N = self._dims[2]
        diag = np.concatenate([np.tile(qp.q_diag, N), qp.q_terminal_diag, np.tile(qp.r_diag, N)])
        return sp.diags(2.0 * diag, format="csc")

    def _linear_cost(self, qp: OcpQp) -> FloatArray:
        """OSQP's q for ``qp``'s targets (see the module docstring)."""
        nx, nu, N = self._dims
        q = np.zeros((N + 1) * nx + N * nu)
        if qp.x_target is not None:
            states = q[: (N + 1) * nx].reshape(N + 1, nx)
            np.multiply(qp.x_target[1:N], -2.0 * qp.q_diag, out=states[1:N])
            np.multiply(qp.x_target[N], -2.0 * qp.q_terminal_diag, out=states[N])
        if qp.u_target is not None:
            q[(N + 1) * nx :] = (-2.0 * qp.r_diag * qp.u_target).reshape(-1)
        return q

    def _constraint_matrix(self, qp: OcpQp) -> tuple[sp.csc_matrix, np.ndarray]:
        """Rows: [Δx_0 = x0; Δx_{k+1} − AΔx_k − BΔu_k = 0; Δu_k box; Δx_k box; Δx_N box].

        Returns the matrix and, for the per-tick update, the positions in its ``data``
        array of every A and B entry (ordered as ``_dynamics_values`` produces them).
        """
        nx, nu, N = self._dims

        def x_col(k: int) -> int:
            return k * nx

        def u_col(k: int) -> int:
            return (N + 1) * nx + k * nu

        rows: list[int] = []
        cols: list[int] = []
        tags: list[int] = []
        a_r, a_c = np.nonzero(self._a_mask)
        b_r, b_c = np.nonzero(self._b_mask)
        rows += list(range(nx))
        cols += list(range(nx))
        tags += [-1] * nx
        tag = 0
        for k in range(N):
            r0 = (k + 1) * nx
            rows += list(r0 + np.arange(nx))
            cols += list(x_col(k + 1) + np.arange(nx))
            tags += [-1] * nx
            rows += list(r0 + a_r)
            cols += list(x_col(k) + a_c)
            tags += list(range(tag, tag + a_r.size))
            tag += a_r.size
            rows += list(r0 + b_r)
            cols += list(u_col(k) + b_c)
            tags += list(range(tag, tag + b_r.size))
            tag += b_r.size
        r0 = (N + 1) * nx
        for k in range(N):
            rows += list(r0 + np.arange(nu))
            cols += list(u_col(k) + np.arange(nu))
            tags += [-1] * nu
            r0 += nu
        for k in range(1, N):
            m = self._state_rows.size
            rows += list(r0 + np.arange(m))
            cols += list(x_col(k) + self._state_rows)
            tags += [-1] * m
            r0 += m
        m = self._terminal_rows.size
        rows += list(r0 + np.arange(m))
        cols += list(x_col(N) + self._terminal_rows)
        tags += [-1] * m
        r0 += m
        n_var = (N + 1) * nx + N * nu
        # Every fixed entry is 1; each A/B entry carries its index ("tag") through the COO →
        # CSC conversion, which tells where its value lives in the CSC data array.
        tagged = sp.csc_matrix((np.asarray(tags, float) + 2.0, (rows, cols)), shape=(r0, n_var))
        tagged.sort_indices()
        order = tagged.data.astype(int) - 2
        dynamic = order >= 0
        slots = np.empty(tag, dtype=int)
        slots[order[dynamic]] = np.flatnonzero(dynamic)
        matrix = tagged.copy()
        matrix.data = np.ones_like(tagged.data)
        matrix.data[slots] = self._dynamics_values(qp)
        self._matrix_data = matrix.data.copy()
        return matrix, slots

    def _dynamics_values(self, qp: OcpQp) -> FloatArray:
        per_stage = np.concatenate([-qp.A[self._a_mask], -qp.B[self._b_mask]])
        return np.tile(per_stage, self._dims[2])

    def _bounds(self, qp: OcpQp, lower: bool) -> FloatArray:
        nx, _, N = self._dims
        inf = -np.inf if lower else np.inf
        u_bound = qp.u_lb if lower else qp.u_ub
        x_bound = qp.x_lb if lower else qp.x_ub
        xn_bound = qp.x_terminal_lb if lower else qp.x_terminal_ub
        parts = [qp.x0, np.zeros(N * nx), np.tile(u_bound, N)]
        if self._state_rows.size:
            x_b = np.full(nx, inf) if x_bound is None else x_bound
            parts.append(np.tile(x_b[self._state_rows], N - 1))
        if self._terminal_rows.size:
            xn_b = np.full(nx, inf) if xn_bound is None else xn_bound
            parts.append(xn_b[self._terminal_rows])
        return np.concatenate(parts)

    def _lower(self, qp: OcpQp) -> FloatArray:
        return self._bounds(qp, lower=True)

    def _upper(self, qp: OcpQp) -> FloatArray:
        return self._bounds(qp, lower=False)

    def prepare(self, qp: OcpQp) -> None:
        """Nothing to precompute: this back-end builds its data from the whole QP."""

    def solve(self, qp: OcpQp) -> QpSolution:
        """Update A, B, x0 and bounds (and weights if changed), solve warm-started."""
        nx, nu, N = self._dims
        if not (
            np.all(np.isfinite(qp.A)) and np.all(np.isfinite(qp.B)) and np.all(np.isfinite(qp.x0))
        ):
            return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
        self._matrix_data[self._value_slots] = self._dynamics_values(qp)
        key = self._weights_key(qp)
        if key != self._cost_key:
            self._solver.update(Px=self._cost(qp).data)
            self._cost_key = key
        if qp.x_target is not None or qp.u_target is not None:
            q = self._linear_cost(qp)
            if not np.all(np.isfinite(q)):
                return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
            self._solver.update(q=q)
            self._linear_cost_set = True
        elif self._linear_cost_set:  # the last targets' terms, cleared once
            self._solver.update(q=np.zeros((N + 1) * nx + N * nu))
            self._linear_cost_set = False
        self._solver.update(Ax=self._matrix_data, l=self._lower(qp), u=self._upper(qp))
        result = self._solver.solve(raise_error=False)
        status_text = result.info.status
        if status_text not in _SOLVED:
            status = QpStatus.INFEASIBLE if status_text in _INFEASIBLE else QpStatus.MAX_ITERATIONS
            return QpSolution.failed(qp, status, int(result.info.iter))
        z = result.x
        return QpSolution(
            u=z[(N + 1) * nx :].reshape(N, nu).copy(),
            x=z[: (N + 1) * nx].reshape(N + 1, nx).copy(),
            status=QpStatus.SOLVED,
            iterations=int(result.info.iter),
        )
