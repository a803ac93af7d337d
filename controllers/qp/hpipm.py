"""HPIPM (the successor of the paper's HPMPC) driven directly through ctypes.

The casadi wheel ships ``libhpipm.so`` and ``libblasfeo.so``; CasADi's own ``hpipm`` plugin
costs ~6 ms per call here (qp-solvers.md), the library itself a fraction of that. HPIPM
builds its objects in caller-provided memory sized by ``*_memsize``, so every buffer lives
in this object, allocated once; what never changes (weights, bound indices) is set once,
and a tick hands the library pointers to numpy arrays holding A, B, b₀ and the boxes.

Formulation (base.py's ``OcpQp``): the initial state is eliminated — stage 0 has no state
(nx₀ = 0) and x₁ = B Δu₀ + b₀ with b₀ = A x₀ — so stage 0 carries only its input box.
Stages 1…N−1 carry the finite entries of the state box, stage N those of the terminal box
(±inf entries are left out: HPIPM's IPM stalls on huge bounds). The interior-point solver
runs in ``SPEED`` mode, warm-started from the previous solution.
"""

from __future__ import annotations

import ctypes
import math
import os
import time
from ctypes import POINTER, c_double, c_int, c_size_t, c_void_p
from typing import Any

import casadi
import numpy as np

from controllers.qp.base import FloatArray, OcpQp, QpSolution, QpStatus

_SPEED = 1  # enum hpipm_mode: SPEED_ABS, SPEED, BALANCE, ROBUST
_STATUS = {
    0: QpStatus.SOLVED,
    1: QpStatus.MAX_ITERATIONS,
    2: QpStatus.NUMERICAL_ERROR,  # minimum step length reached
    3: QpStatus.NUMERICAL_ERROR,  # NaN in the computations
}
_library: ctypes.CDLL | None = None


def _load() -> ctypes.CDLL:
    """casadi's libhpipm (after its libblasfeo, globally: one build in the process)."""
    global _library
    if _library is None:
        folder = os.path.dirname(casadi.__file__)
        ctypes.CDLL(os.path.join(folder, "libblasfeo.so"), mode=ctypes.RTLD_GLOBAL)
        lib = ctypes.CDLL(os.path.join(folder, "libhpipm.so"), mode=ctypes.RTLD_GLOBAL)
        for name in (
            "d_ocp_qp_dim_strsize",
            "d_ocp_qp_strsize",
            "d_ocp_qp_sol_strsize",
            "d_ocp_qp_ipm_arg_strsize",
            "d_ocp_qp_ipm_ws_strsize",
        ):
            getattr(lib, name).restype = c_size_t
            getattr(lib, name).argtypes = []
        for name in ("d_ocp_qp_memsize", "d_ocp_qp_sol_memsize", "d_ocp_qp_ipm_arg_memsize"):
            getattr(lib, name).restype = c_size_t
            getattr(lib, name).argtypes = [c_void_p]
        lib.d_ocp_qp_dim_memsize.restype = c_size_t
        lib.d_ocp_qp_dim_memsize.argtypes = [c_int]
        lib.d_ocp_qp_ipm_ws_memsize.restype = c_size_t
        lib.d_ocp_qp_ipm_ws_memsize.argtypes = [c_void_p, c_void_p]
        _library = lib
    return _library


def _pointer(array: np.ndarray) -> Any:
    return array.ctypes.data_as(POINTER(c_double))


def _finite_indices(lower: FloatArray | None, upper: FloatArray | None) -> np.ndarray:
    """Indices of the box entries with a finite side (the only ones HPIPM is given)."""
    if lower is None or upper is None:
        return np.zeros(0, dtype=np.int32)
    return np.flatnonzero(np.isfinite(lower) | np.isfinite(upper)).astype(np.int32)


class HpipmBackend:
    """``QpBackend`` on HPIPM's OCP-QP interior-point solver (Riccati recursion)."""

    name = "hpipm"

    def __init__(self, template: OcpQp, tolerance: float = 1e-8, max_iterations: int = 50) -> None:
        lib = _load()
        self._lib = lib
        nx, nu, N = template.nx, template.nu, template.horizon
        self._dims = (nx, nu, N)
        self._state_idx = _finite_indices(template.x_lb, template.x_ub)
        self._terminal_idx = _finite_indices(template.x_terminal_lb, template.x_terminal_ub)
        self._keep: list[Any] = []  # memory the C side points into

        def block(size: int) -> Any:
            memory = ctypes.create_string_buffer(max(size, 1))
            self._keep.append(memory)
            return memory

        self._dim = block(lib.d_ocp_qp_dim_strsize())
        lib.d_ocp_qp_dim_create(c_int(N), self._dim, block(lib.d_ocp_qp_dim_memsize(N)))
        stage_nx = [0] + [nx] * N
        stage_nu = [nu] * N + [0]
        stage_nbx = [0] + [self._state_idx.size] * (N - 1) + [self._terminal_idx.size]
        for setter, values in (
            (lib.d_ocp_qp_dim_set_nx, stage_nx),
            (lib.d_ocp_qp_dim_set_nu, stage_nu),
            (lib.d_ocp_qp_dim_set_nbx, stage_nbx),
            (lib.d_ocp_qp_dim_set_nbu, stage_nu),
            (lib.d_ocp_qp_dim_set_ng, [0] * (N + 1)),
            (lib.d_ocp_qp_dim_set_ns, [0] * (N + 1)),
        ):
            for stage, count in enumerate(values):
                setter(c_int(stage), c_int(count), self._dim)
        self._qp = block(lib.d_ocp_qp_strsize())
        lib.d_ocp_qp_create(self._dim, self._qp, block(lib.d_ocp_qp_memsize(self._dim)))

        # Buffers (column-major matrices); every stage shares A, B, Q, R.
        self._A = np.zeros((nx, nx), order="F")
        self._B = np.zeros((nx, nu), order="F")
        self._b0 = np.zeros(nx)
        self._lbu = np.zeros((N, nu))
        self._ubu = np.zeros((N, nu))
        self._lbx = np.zeros((N + 1, max(nx, 1)))
        self._ubx = np.zeros((N + 1, max(nx, 1)))
        Q = np.asfortranarray(np.diag(template.q_diag))
        QN = np.asfortranarray(np.diag(template.q_terminal_diag))
        R = np.asfortranarray(np.diag(template.r_diag))
        S = np.zeros((nu, nx), order="F")
        zeros = np.zeros(max(nx, nu))
        idxbu = np.arange(nu, dtype=np.int32)
        idxbx = [np.zeros(1, np.int32), *[self._state_idx] * (N - 1), self._terminal_idx]
        self._keep += [Q, QN, R, S, zeros, idxbu, idxbx]
        self._stage = [c_int(k) for k in range(N + 1)]
        for k in range(N + 1):
            lib.d_ocp_qp_set_Q(self._stage[k], _pointer(QN if k == N else Q), self._qp)
            lib.d_ocp_qp_set_R(self._stage[k], _pointer(R), self._qp)
            lib.d_ocp_qp_set_S(self._stage[k], _pointer(S), self._qp)
            lib.d_ocp_qp_set_q(self._stage[k], _pointer(zeros), self._qp)
            lib.d_ocp_qp_set_r(self._stage[k], _pointer(zeros), self._qp)
            int_pointer = POINTER(c_int)
            lib.d_ocp_qp_set_idxbu(self._stage[k], idxbu.ctypes.data_as(int_pointer), self._qp)
            lib.d_ocp_qp_set_idxbx(self._stage[k], idxbx[k].ctypes.data_as(int_pointer), self._qp)
            if 0 < k < N:
                lib.d_ocp_qp_set_b(self._stage[k], _pointer(zeros), self._qp)
        self._ptr_A, self._ptr_B, self._ptr_b0 = (
            _pointer(self._A),
            _pointer(self._B),
            _pointer(self._b0),
        )
        self._ptr_lbu = [_pointer(row) for row in self._lbu]
        self._ptr_ubu = [_pointer(row) for row in self._ubu]
        self._ptr_lbx = [_pointer(row) for row in self._lbx]
        self._ptr_ubx = [_pointer(row) for row in self._ubx]

        self._sol = block(lib.d_ocp_qp_sol_strsize())
        lib.d_ocp_qp_sol_create(self._dim, self._sol, block(lib.d_ocp_qp_sol_memsize(self._dim)))
        self._arg = block(lib.d_ocp_qp_ipm_arg_strsize())
        lib.d_ocp_qp_ipm_arg_create(
            self._dim, self._arg, block(lib.d_ocp_qp_ipm_arg_memsize(self._dim))
        )
        lib.d_ocp_qp_ipm_arg_set_default(c_int(_SPEED), self._arg)
        settings: tuple[tuple[Any, c_int | c_double], ...] = (
            (lib.d_ocp_qp_ipm_arg_set_iter_max, c_int(max_iterations)),
            (lib.d_ocp_qp_ipm_arg_set_tol_stat, c_double(tolerance)),
            (lib.d_ocp_qp_ipm_arg_set_tol_eq, c_double(tolerance)),
            (lib.d_ocp_qp_ipm_arg_set_tol_ineq, c_double(tolerance)),
            (lib.d_ocp_qp_ipm_arg_set_tol_comp, c_double(tolerance)),
            (lib.d_ocp_qp_ipm_arg_set_warm_start, c_int(1)),
        )
        for setter, value in settings:
            setter(ctypes.byref(value), self._arg)
        self._ws = block(lib.d_ocp_qp_ipm_ws_strsize())
        workspace = block(lib.d_ocp_qp_ipm_ws_memsize(self._dim, self._arg))
        lib.d_ocp_qp_ipm_ws_create(self._dim, self._arg, self._ws, workspace)

        self._u = np.zeros((N, nu))
        self._x = np.zeros((N + 1, nx))
        self._ptr_u = [_pointer(row) for row in self._u]
        self._ptr_x = [_pointer(row) for row in self._x]
        self._status = c_int(0)
        self._iterations = c_int(0)
        self.last_solve_s = 0.0
        """Time spent in ``d_ocp_qp_ipm_solve`` by the last ``solve`` [s]."""

    def solve(self, qp: OcpQp) -> QpSolution:
        """Write the tick's data, solve, read u and x; never raises for a bad QP."""
        N = self._dims[2]
        start = time.perf_counter()
        data = (qp.A, qp.B, qp.x0, qp.u_lb, qp.u_ub)
        if not all(np.all(np.isfinite(a)) for a in data):
            return self._failure(QpStatus.NUMERICAL_ERROR, start)
        if self._boxes_empty(qp):
            return self._failure(QpStatus.INFEASIBLE, start)
        self._A[:] = qp.A
        self._B[:] = qp.B
        self._b0[:] = qp.A @ qp.x0
        self._lbu[:] = qp.u_lb
        self._ubu[:] = qp.u_ub
        if self._state_idx.size:
            assert qp.x_lb is not None and qp.x_ub is not None
            n = self._state_idx.size
            self._lbx[1:N, :n] = qp.x_lb[self._state_idx]
            self._ubx[1:N, :n] = qp.x_ub[self._state_idx]
        if self._terminal_idx.size:
            assert qp.x_terminal_lb is not None and qp.x_terminal_ub is not None
            n = self._terminal_idx.size
            self._lbx[N, :n] = qp.x_terminal_lb[self._terminal_idx]
            self._ubx[N, :n] = qp.x_terminal_ub[self._terminal_idx]
        lib, stages, qp_struct = self._lib, self._stage, self._qp
        lib.d_ocp_qp_set_b(stages[0], self._ptr_b0, qp_struct)
        for k in range(N):
            if k:
                lib.d_ocp_qp_set_A(stages[k], self._ptr_A, qp_struct)
            lib.d_ocp_qp_set_B(stages[k], self._ptr_B, qp_struct)
            lib.d_ocp_qp_set_lbu(stages[k], self._ptr_lbu[k], qp_struct)
            lib.d_ocp_qp_set_ubu(stages[k], self._ptr_ubu[k], qp_struct)
        if self._state_idx.size or self._terminal_idx.size:
            for k in range(1, N + 1):
                lib.d_ocp_qp_set_lbx(stages[k], self._ptr_lbx[k], qp_struct)
                lib.d_ocp_qp_set_ubx(stages[k], self._ptr_ubx[k], qp_struct)
        solve_started = time.perf_counter()
        lib.d_ocp_qp_ipm_solve(qp_struct, self._sol, self._arg, self._ws)
        self.last_solve_s = time.perf_counter() - solve_started
        lib.d_ocp_qp_ipm_get_status(self._ws, ctypes.byref(self._status))
        lib.d_ocp_qp_ipm_get_iter(self._ws, ctypes.byref(self._iterations))
        for k in range(N):
            lib.d_ocp_qp_sol_get_u(stages[k], self._sol, self._ptr_u[k])
            lib.d_ocp_qp_sol_get_x(stages[k + 1], self._sol, self._ptr_x[k + 1])
        u = self._u.copy()
        x = self._x.copy()
        x[0] = qp.x0
        status = _STATUS.get(self._status.value, QpStatus.NUMERICAL_ERROR)
        if status is QpStatus.SOLVED and not (np.all(np.isfinite(u)) and np.all(np.isfinite(x))):
            status = QpStatus.NUMERICAL_ERROR
        return QpSolution(u, x, status, self._iterations.value, time.perf_counter() - start)

    @staticmethod
    def _boxes_empty(qp: OcpQp) -> bool:
        """A box with lower > upper: no input sequence can meet it."""
        boxes = [(qp.u_lb, qp.u_ub), (qp.x_lb, qp.x_ub), (qp.x_terminal_lb, qp.x_terminal_ub)]
        return any(lo is not None and hi is not None and bool(np.any(lo > hi)) for lo, hi in boxes)

    def _failure(self, status: QpStatus, start: float) -> QpSolution:
        nx, nu, N = self._dims
        return QpSolution(
            np.full((N, nu), math.nan),
            np.full((N + 1, nx), math.nan),
            status,
            0,
            time.perf_counter() - start,
        )
