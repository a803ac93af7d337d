"""HPIPM (the successor of the paper's HPMPC) driven directly through ctypes.

The libraries come from hpipm_library.py (an AVX2 build when installed, else the generic
one inside the casadi wheel); CasADi's own ``hpipm`` plugin costs ~6 ms per call here
(qp-solvers.md), the library itself a fraction of that. HPIPM
builds its objects in caller-provided memory sized by ``*_memsize``, so every buffer lives
in this object, allocated once; what never changes (bound indices, Q_N) is set once, and a
tick hands the library pointers to numpy arrays holding the condensed data and the boxes.

Formulation (base.py's ``OcpQp``), partially condensed (partial_condensing.py) into blocks
of stages: the initial state is eliminated — block 0 has no state (nx₀ = 0), its end state
is B̄ U₀ + b₀ with b₀ = Ā x₀, and its cost's cross term S̄ x₀ becomes a linear term — so it
carries only its input box. Later block starts carry the finite entries of the state box,
the last node those of the terminal box (±inf entries are left out: HPIPM's IPM stalls on
huge bounds). The interior-point solver runs in ``SPEED`` mode, warm-started.

Most ticks of a hovering or tracking flight have no active bound, and then the QP's
solution is that of the same QP without boxes. So each solve first solves the box-free QP
and keeps it when it satisfies every box (exactly the KKT conditions with zero
multipliers); otherwise HPIPM solves the boxed QP. While an input bound stays active
(saturation lasts a few ticks) the box-free attempt is skipped. The box-free solve comes
in two forms: HPIPM's own (one Riccati recursion in C, the fastest when the state is
already known), and a linear map of Δx₀ that depends on the model alone (riccati.py),
which ``prepare`` builds ahead of the solve — a real-time loop does it before the state
arrives, and the solve is then two matrix–vector products.
"""

from __future__ import annotations

import ctypes
import math
import time
from ctypes import POINTER, c_double, c_int, c_size_t, c_void_p
from typing import Any

import numpy as np

from controllers.qp.base import FloatArray, OcpQp, QpSolution, QpStatus
from controllers.qp.hpipm_library import library_folder
from controllers.qp.partial_condensing import CondensedBlock, block_lengths, condense
from controllers.qp.riccati import UnboxedSolutionMap, unboxed_solution_map

DEFAULT_BLOCK_STAGES = 5  # `uavbar-supervisor bench` compares block lengths
_SPEED = 1  # enum hpipm_mode: SPEED_ABS, SPEED, BALANCE, ROBUST
_STATUS = {
    0: QpStatus.SOLVED,
    1: QpStatus.MAX_ITERATIONS,
    2: QpStatus.NUMERICAL_ERROR,  # minimum step length reached
    3: QpStatus.NUMERICAL_ERROR,  # NaN in the computations
}
_library: ctypes.CDLL | None = None
_blasfeo: ctypes.CDLL | None = None


def _load() -> ctypes.CDLL:
    """libhpipm (after its libblasfeo, globally: one build in the process) from
    ``library_folder()``."""
    global _library, _blasfeo
    if _library is None:
        folder = library_folder()
        _blasfeo = ctypes.CDLL(str(folder / "libblasfeo.so"), mode=ctypes.RTLD_GLOBAL)
        lib = ctypes.CDLL(str(folder / "libhpipm.so"), mode=ctypes.RTLD_GLOBAL)
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


def library_build() -> str:
    """The SIMD features the loaded BLASFEO was built for ("AVX2 FMA"), or "generic"."""
    _load()
    assert _blasfeo is not None
    text = ctypes.create_string_buffer(256)
    _blasfeo.blasfeo_processor_library_string(text)
    return text.value.decode().strip() or "generic"


def _pointer(array: np.ndarray) -> Any:
    return array.ctypes.data_as(POINTER(c_double))


def _finite_indices(lower: FloatArray | None, upper: FloatArray | None) -> np.ndarray:
    """Indices of the box entries with a finite side (the only ones HPIPM is given)."""
    if lower is None or upper is None:
        return np.zeros(0, dtype=np.int32)
    return np.flatnonzero(np.isfinite(lower) | np.isfinite(upper)).astype(np.int32)


class _BlockBuffers:
    """Column-major copies of one block length's condensed data, handed to HPIPM by pointer."""

    def __init__(self, nx: int, nu: int) -> None:
        self.A = np.zeros((nx, nx), order="F")
        self.B = np.zeros((nx, nu), order="F")
        self.R = np.zeros((nu, nu), order="F")
        self.S = np.zeros((nu, nx), order="F")
        self.Q = np.zeros((nx, nx), order="F")
        self.pointers = tuple(_pointer(m) for m in (self.A, self.B, self.R, self.S, self.Q))
        self.block: CondensedBlock | None = None

    def load(self, block: CondensedBlock) -> None:
        self.block = block
        self.A[:] = block.A
        self.B[:] = block.B
        self.R[:] = block.R
        self.S[:] = block.S
        self.Q[:] = block.Q


class _HpipmProblem:
    """One HPIPM OCP-QP (dimensions, data, solution, solver) over the blocks of a horizon.

    ``boxed=False`` leaves every bound out: HPIPM then solves it with one Riccati recursion.
    """

    def __init__(
        self,
        lengths: tuple[int, ...],
        nx: int,
        nu: int,
        state_idx: np.ndarray,
        terminal_idx: np.ndarray,
        boxed: bool,
        tolerance: float,
        max_iterations: int,
    ) -> None:
        lib = _load()
        self._lib = lib
        nb = len(lengths)
        self._nb = nb
        self._keep: list[Any] = []  # memory the C side points into

        def block(size: int) -> Any:
            memory = ctypes.create_string_buffer(max(size, 1))
            self._keep.append(memory)
            return memory

        if not boxed:
            state_idx = terminal_idx = np.zeros(0, dtype=np.int32)
        self._has_state_boxes = bool(state_idx.size or terminal_idx.size)
        self._dim = block(lib.d_ocp_qp_dim_strsize())
        lib.d_ocp_qp_dim_create(c_int(nb), self._dim, block(lib.d_ocp_qp_dim_memsize(nb)))
        stage_nu = [m * nu for m in lengths] + [0]
        for setter, values in (
            (lib.d_ocp_qp_dim_set_nx, [0] + [nx] * nb),
            (lib.d_ocp_qp_dim_set_nu, stage_nu),
            (lib.d_ocp_qp_dim_set_nbx, [0] + [state_idx.size] * (nb - 1) + [terminal_idx.size]),
            (lib.d_ocp_qp_dim_set_nbu, stage_nu if boxed else [0] * (nb + 1)),
            (lib.d_ocp_qp_dim_set_ng, [0] * (nb + 1)),
            (lib.d_ocp_qp_dim_set_ns, [0] * (nb + 1)),
        ):
            for stage, count in enumerate(values):
                setter(c_int(stage), c_int(count), self._dim)
        self._qp = block(lib.d_ocp_qp_strsize())
        lib.d_ocp_qp_create(self._dim, self._qp, block(lib.d_ocp_qp_memsize(self._dim)))
        self.stages = [c_int(k) for k in range(nb + 1)]
        zeros = np.zeros(max(nx, max(lengths) * nu))
        idxbu = np.arange(max(lengths) * nu, dtype=np.int32)
        idxbx = [np.zeros(1, np.int32), *[state_idx] * (nb - 1), terminal_idx]
        self._keep += [zeros, idxbu, idxbx]
        int_pointer = POINTER(c_int)
        for k in range(nb + 1):
            lib.d_ocp_qp_set_q(self.stages[k], _pointer(zeros), self._qp)
            lib.d_ocp_qp_set_r(self.stages[k], _pointer(zeros), self._qp)
            if boxed:
                lib.d_ocp_qp_set_idxbu(self.stages[k], idxbu.ctypes.data_as(int_pointer), self._qp)
                lib.d_ocp_qp_set_idxbx(
                    self.stages[k], idxbx[k].ctypes.data_as(int_pointer), self._qp
                )
            if 0 < k < nb:
                lib.d_ocp_qp_set_b(self.stages[k], _pointer(zeros), self._qp)

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
        self._status = c_int(0)
        self._iterations = c_int(0)

    def set_dynamics_and_cost(
        self, block_pointers: list[tuple[Any, ...]], b0: Any, r0: Any, q_terminal: Any
    ) -> None:
        """Point every block at its condensed (A, B, R, S, Q); block 0 gets b₀ and r₀."""
        lib, stages, qp = self._lib, self.stages, self._qp
        lib.d_ocp_qp_set_b(stages[0], b0, qp)
        lib.d_ocp_qp_set_r(stages[0], r0, qp)
        for k, (ptr_A, ptr_B, ptr_R, ptr_S, ptr_Q) in enumerate(block_pointers):
            if k:
                lib.d_ocp_qp_set_A(stages[k], ptr_A, qp)
                lib.d_ocp_qp_set_Q(stages[k], ptr_Q, qp)
                lib.d_ocp_qp_set_S(stages[k], ptr_S, qp)
            lib.d_ocp_qp_set_B(stages[k], ptr_B, qp)
            lib.d_ocp_qp_set_R(stages[k], ptr_R, qp)
        lib.d_ocp_qp_set_Q(stages[self._nb], q_terminal, qp)

    def set_boxes(self, lbu: list[Any], ubu: list[Any], lbx: list[Any], ubx: list[Any]) -> None:
        """Input boxes of every block; state boxes of the block starts and the last node."""
        lib, stages, qp = self._lib, self.stages, self._qp
        for k in range(self._nb):
            lib.d_ocp_qp_set_lbu(stages[k], lbu[k], qp)
            lib.d_ocp_qp_set_ubu(stages[k], ubu[k], qp)
        if self._has_state_boxes:
            for k in range(1, self._nb + 1):
                lib.d_ocp_qp_set_lbx(stages[k], lbx[k], qp)
                lib.d_ocp_qp_set_ubx(stages[k], ubx[k], qp)

    def solve(self, inputs: list[Any], states: list[Any]) -> tuple[int, int]:
        """Run the solver; write block inputs and block-start states; (status, iterations)."""
        lib, stages = self._lib, self.stages
        lib.d_ocp_qp_ipm_solve(self._qp, self._sol, self._arg, self._ws)
        lib.d_ocp_qp_ipm_get_status(self._ws, ctypes.byref(self._status))
        lib.d_ocp_qp_ipm_get_iter(self._ws, ctypes.byref(self._iterations))
        for k in range(self._nb):
            lib.d_ocp_qp_sol_get_u(stages[k], self._sol, inputs[k])
            lib.d_ocp_qp_sol_get_x(stages[k + 1], self._sol, states[k + 1])
        return self._status.value, self._iterations.value


class HpipmBackend:
    """``QpBackend`` on HPIPM's OCP-QP interior-point solver, partially condensed.

    The N stages are condensed into blocks of ``block_stages`` (partial_condensing.py);
    HPIPM's Riccati recursion then runs over the blocks. State boxes inside a block would
    become general constraints, so a QP with a state set is solved stage by stage
    (blocks of one stage, no condensing).
    """

    name = "hpipm"

    def __init__(
        self,
        template: OcpQp,
        tolerance: float = 1e-6,
        max_iterations: int = 50,
        block_stages: int = DEFAULT_BLOCK_STAGES,
    ) -> None:
        nx, nu, N = template.nx, template.nu, template.horizon
        self._dims = (nx, nu, N)
        self._state_idx = _finite_indices(template.x_lb, template.x_ub)
        self._terminal_idx = _finite_indices(template.x_terminal_lb, template.x_terminal_ub)
        if self._state_idx.size:
            block_stages = 1
        self._lengths = block_lengths(N, block_stages)
        nb = len(self._lengths)
        shape = (self._lengths, nx, nu, self._state_idx, self._terminal_idx)
        self._free = _HpipmProblem(*shape, False, tolerance, max_iterations)
        self._boxed = _HpipmProblem(*shape, True, tolerance, max_iterations)
        self._prepared_model: tuple[FloatArray, ...] = ()
        self._blocks: dict[int, CondensedBlock] = {}
        self._solution_map: UnboxedSolutionMap | None = None  # built by ``prepare`` only

        self._buffers = {m: _BlockBuffers(nx, m * nu) for m in set(self._lengths)}
        self._block_pointers = [self._buffers[m].pointers for m in self._lengths]
        self._b0 = np.zeros(nx)
        self._r0 = np.zeros(self._lengths[0] * nu)
        self._QN = np.asfortranarray(np.diag(template.q_terminal_diag))
        self._lbu = [np.zeros(m * nu) for m in self._lengths]
        self._ubu = [np.zeros(m * nu) for m in self._lengths]
        self._lbx = np.zeros((nb + 1, max(nx, 1)))
        self._ubx = np.zeros((nb + 1, max(nx, 1)))
        self._ptr_b0, self._ptr_r0, self._ptr_QN = (
            _pointer(self._b0),
            _pointer(self._r0),
            _pointer(self._QN),
        )
        self._ptr_lbu = [_pointer(row) for row in self._lbu]
        self._ptr_ubu = [_pointer(row) for row in self._ubu]
        self._ptr_lbx = [_pointer(row) for row in self._lbx]
        self._ptr_ubx = [_pointer(row) for row in self._ubx]
        self._U = [np.zeros(m * nu) for m in self._lengths]
        self._X = np.zeros((nb + 1, nx))
        self._ptr_U = [_pointer(row) for row in self._U]
        self._ptr_X = [_pointer(row) for row in self._X]
        self.last_solve_s = 0.0
        """Time spent solving by the last ``solve``, after its data was prepared [s]."""
        self.last_was_box_free = False
        """Whether the last solve's box-free solution met every box (no IPM run)."""
        self.last_was_prepared = False
        """Whether the last solve found its model already prepared."""
        self._try_box_free = True

    @property
    def block_lengths(self) -> tuple[int, ...]:
        """Stages per block of the QP HPIPM solves."""
        return self._lengths

    def prepare(self, qp: OcpQp) -> None:
        """Condense ``qp``'s model and build its box-free solution map now; a later
        ``solve`` of a QP with the same A, B and weights reuses them. Raises
        ``LinAlgError`` when a condensed Hessian block is not positive definite."""
        self._condense(qp)
        blocks = [self._blocks[m] for m in self._lengths]
        self._solution_map = unboxed_solution_map(blocks, qp.q_terminal_diag)

    def _condense(self, qp: OcpQp) -> None:
        self._prepared_model = ()
        self._blocks = {
            m: condense(qp.A, qp.B, qp.q_diag, qp.r_diag, m) for m in set(self._lengths)
        }
        self._solution_map = None
        self._prepared_model = tuple(np.array(a) for a in self._model(qp))

    def solve(self, qp: OcpQp) -> QpSolution:
        """Solve box-free (by the prepared map, else by HPIPM; not while an input bound
        was active in the last boxed solve), and if a box is violated solve boxed with
        HPIPM; never raises."""
        start = time.perf_counter()
        data = (qp.A, qp.B, qp.x0, qp.u_lb, qp.u_ub)
        if not all(np.all(np.isfinite(a)) for a in data):
            return self._failure(QpStatus.NUMERICAL_ERROR, start)
        if self._boxes_empty(qp):
            return self._failure(QpStatus.INFEASIBLE, start)
        self.last_was_prepared = len(self._prepared_model) == 5 and all(
            np.array_equal(a, b) for a, b in zip(self._model(qp), self._prepared_model, strict=True)
        )
        if not self.last_was_prepared:
            self._condense(qp)
        solve_started = time.perf_counter()
        status, iterations = 0, 0
        self.last_was_box_free = False
        loaded = False
        if self._try_box_free:
            if self._solution_map is not None:
                u, x = self._solution_map.solve(qp.x0)
            else:
                self._load_data(qp.x0)
                loaded = True
                self._free.set_dynamics_and_cost(
                    self._block_pointers, self._ptr_b0, self._ptr_r0, self._ptr_QN
                )
                status, iterations = self._free.solve(self._ptr_U, self._ptr_X)
                u, x = self._expand(qp.x0)
            self.last_was_box_free = status == 0 and self._within_boxes(qp, u, x)
        if not self.last_was_box_free:
            if not loaded:
                self._load_data(qp.x0)
            self._load_boxes(qp)
            self._boxed.set_dynamics_and_cost(
                self._block_pointers, self._ptr_b0, self._ptr_r0, self._ptr_QN
            )
            self._boxed.set_boxes(self._ptr_lbu, self._ptr_ubu, self._ptr_lbx, self._ptr_ubx)
            status, boxed_iterations = self._boxed.solve(self._ptr_U, self._ptr_X)
            iterations += boxed_iterations
            u, x = self._expand(qp.x0)
            # Saturation lasts a few ticks: while an input bound is active, skip the attempt.
            self._try_box_free = not self._input_bound_active(qp, u)
        self.last_solve_s = time.perf_counter() - solve_started
        result = _STATUS.get(status, QpStatus.NUMERICAL_ERROR)
        if result is QpStatus.SOLVED and not (np.all(np.isfinite(u)) and np.all(np.isfinite(x))):
            result = QpStatus.NUMERICAL_ERROR
        return QpSolution(u, x, result, iterations, time.perf_counter() - start)

    @staticmethod
    def _model(qp: OcpQp) -> tuple[FloatArray, ...]:
        """What fixes the condensed data and the box-free map."""
        return (qp.A, qp.B, qp.q_diag, qp.r_diag, qp.q_terminal_diag)

    def _load_data(self, x0: FloatArray) -> None:
        """The condensed blocks into HPIPM's buffers, and block 0's b₀ and r₀ for ``x0``."""
        for m, buffers in self._buffers.items():
            buffers.load(self._blocks[m])
        first = self._buffers[self._lengths[0]]
        self._b0[:] = first.A @ x0
        self._r0[:] = first.S @ x0

    def _load_boxes(self, qp: OcpQp) -> None:
        nb = len(self._lengths)
        for k, m in enumerate(self._lengths):
            self._lbu[k].reshape(m, -1)[:] = qp.u_lb
            self._ubu[k].reshape(m, -1)[:] = qp.u_ub
        if self._state_idx.size:
            assert qp.x_lb is not None and qp.x_ub is not None
            n = self._state_idx.size
            self._lbx[1:nb, :n] = qp.x_lb[self._state_idx]
            self._ubx[1:nb, :n] = qp.x_ub[self._state_idx]
        if self._terminal_idx.size:
            assert qp.x_terminal_lb is not None and qp.x_terminal_ub is not None
            n = self._terminal_idx.size
            self._lbx[nb, :n] = qp.x_terminal_lb[self._terminal_idx]
            self._ubx[nb, :n] = qp.x_terminal_ub[self._terminal_idx]

    @staticmethod
    def _input_bound_active(qp: OcpQp, u: FloatArray) -> bool:
        tolerance = 1e-5 * (qp.u_ub - qp.u_lb)
        return bool(np.any(u <= qp.u_lb + tolerance) or np.any(u >= qp.u_ub - tolerance))

    @staticmethod
    def _within_boxes(qp: OcpQp, u: FloatArray, x: FloatArray) -> bool:
        if np.any(u < qp.u_lb) or np.any(u > qp.u_ub):
            return False
        inner, last = x[1:-1], x[-1]
        for states, lower, upper in (
            (inner, qp.x_lb, qp.x_ub),
            (last, qp.x_terminal_lb, qp.x_terminal_ub),
        ):
            if lower is None or upper is None:
                continue
            if np.any(states < lower) or np.any(states > upper):
                return False
        return True

    def _expand(self, x0: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The block solution as the N inputs and N + 1 states of the original QP."""
        nu = self._dims[1]
        self._X[0] = x0
        u = np.concatenate(self._U).reshape(-1, nu)
        states = []
        for k, m in enumerate(self._lengths):
            block = self._buffers[m].block
            assert block is not None
            states.append(block.states(self._X[k], self._U[k]))
        states.append(self._X[-1:])
        return u, np.vstack(states)

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
