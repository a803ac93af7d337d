"""HPIPM (the successor of the paper's HPMPC) driven directly through ctypes.

The libraries come from hpipm_library.py (an AVX2 build when installed, else the generic
one inside the casadi wheel); CasADi's own ``hpipm`` plugin costs ~6 ms per call here
(docs/reference/qp-solvers.md), the library itself a fraction of that. HPIPM builds its objects in
caller-provided memory sized by ``*_memsize``, so every buffer lives in this object,
allocated once; what changes rarely (weights, bound indices, boxes) is handed over only
when it changes, and a tick hands the library pointers to numpy arrays holding A, B and
b₀.

Formulation (base.py's ``OcpQp``) stage by stage, with the initial state eliminated:
stage 0 has no state (nx₀ = 0) and reaches x₁ = B u₀ + b₀, b₀ = A x₀, so it carries only
its input box. Stages 1 … N−1 carry the finite entries of the state box, stage N those of
the terminal box (±inf entries are left out: HPIPM's IPM stalls on huge bounds).

HPIPM's cost is Σ ½ xᵀQx + ½ uᵀRu + qᵀx + rᵀu; it is handed Q, R and Q_N as they are, so
it minimizes half of ``OcpQp``'s cost, and the targets x̄_k, ū_k become the linear terms
q_k = −Q x̄_k (stages 1 … N−1), q_N = −Q_N x̄_N and r_k = −R ū_k (stages 0 … N−1); stage 0
has no state, so x̄_0 (a constant of the cost) is never handed over. Without targets q and
r stay zero and are not touched.

Most ticks of a hovering or tracking flight have no active bound, and then the QP's
solution is that of the same QP without boxes. So each solve first solves the box-free QP
and keeps it when it satisfies every box (exactly the KKT conditions with zero
multipliers); otherwise HPIPM's interior-point solver (``SPEED`` mode, warm-started)
solves the boxed QP, partially condensed by HPIPM into blocks of stages. While an input
bound stays active (saturation lasts a few ticks) the box-free attempt is skipped. The
box-free solve comes in two forms: HPIPM's own (one Riccati recursion over the stages, in
C), and a linear map of Δx₀ that depends on the model alone (riccati.py), which
``prepare`` builds ahead of the solve — a real-time loop does it before the state arrives,
and the solve is then two matrix–vector products.
"""

from __future__ import annotations

import ctypes
from ctypes import POINTER, c_double, c_int, c_size_t, c_void_p
from typing import Any

import numpy as np

from controllers.qp.base import OcpQp, QpSolution, QpStatus
from controllers.qp.hpipm_library import library_folder
from controllers.qp.partial_condensing import block_lengths, condense
from controllers.qp.riccati import UnboxedSolutionMap, unboxed_solution_map
from geometry.arrays import FloatArray

DEFAULT_BLOCK_STAGES = 5  # fastest for the interior-point iterations in a sweep of 1–30
_SPEED = 1  # enum hpipm_mode: SPEED_ABS, SPEED, BALANCE, ROBUST
_STATUS = {
    0: QpStatus.SOLVED,
    1: QpStatus.MAX_ITERATIONS,
    2: QpStatus.NUMERICAL_ERROR,  # minimum step length reached
    3: QpStatus.NUMERICAL_ERROR,  # NaN in the computations
}
# HPIPM exports no *_strsize for these two structs (a pointer, an int and a size each).
_PART_COND_STRUCT_BYTES = 256
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
        lib.d_part_cond_qp_arg_memsize.restype = c_size_t
        lib.d_part_cond_qp_arg_memsize.argtypes = [c_int]
        lib.d_part_cond_qp_ws_memsize.restype = c_size_t
        lib.d_part_cond_qp_ws_memsize.argtypes = [c_void_p] * 4
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


def _finite_targets(qp: OcpQp) -> bool:
    """Whether every target ``qp`` has is finite."""
    return all(t is None or bool(np.isfinite(t).all()) for t in (qp.x_target, qp.u_target))


class _HpipmProblem:
    """One HPIPM problem: the stage-wise OCP-QP, its partial condensing into blocks of
    stages (in C), and the interior-point solver on the blocks.

    The initial state is eliminated: stage 0 has no state (nx₀ = 0) and its dynamics is
    x₁ = B u₀ + b₀ with b₀ = A x₀. ``boxed=False`` leaves every bound out: HPIPM then
    solves with one Riccati recursion. Q, R and Q_N are set once (``set_weights``); a
    tick sets A, B and b₀ (``set_model``) and, for the boxed problem, the boxes; the
    targets' linear terms q and r are set (``set_gradient``) only while there are targets
    and once more to clear them.
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
        N, nb = sum(lengths), len(lengths)
        self._N = N
        self._keep: list[Any] = []  # memory the C side points into

        def block(size: int) -> Any:
            memory = ctypes.create_string_buffer(max(size, 1))
            self._keep.append(memory)
            return memory

        if not boxed:
            state_idx = terminal_idx = np.zeros(0, dtype=np.int32)
        self._has_state_boxes = bool(state_idx.size or terminal_idx.size)
        self._dim = block(lib.d_ocp_qp_dim_strsize())
        lib.d_ocp_qp_dim_create(c_int(N), self._dim, block(lib.d_ocp_qp_dim_memsize(N)))
        stage_nu = [nu] * N + [0]
        for setter, values in (
            (lib.d_ocp_qp_dim_set_nx, [0] + [nx] * N),
            (lib.d_ocp_qp_dim_set_nu, stage_nu),
            (lib.d_ocp_qp_dim_set_nbx, [0] + [state_idx.size] * (N - 1) + [terminal_idx.size]),
            (lib.d_ocp_qp_dim_set_nbu, stage_nu if boxed else [0] * (N + 1)),
            (lib.d_ocp_qp_dim_set_ng, [0] * (N + 1)),
            (lib.d_ocp_qp_dim_set_ns, [0] * (N + 1)),
        ):
            for stage, count in enumerate(values):
                setter(c_int(stage), c_int(count), self._dim)
        self._qp = block(lib.d_ocp_qp_strsize())
        lib.d_ocp_qp_create(self._dim, self._qp, block(lib.d_ocp_qp_memsize(self._dim)))
        self.stages = [c_int(k) for k in range(N + 1)]
        zeros = np.zeros(max(nx, nu))
        idxbu = np.arange(nu, dtype=np.int32)
        idxbx = [np.zeros(1, np.int32), *[state_idx] * (N - 1), terminal_idx]
        self._keep += [zeros, idxbu, idxbx]
        int_pointer = POINTER(c_int)
        for k in range(N + 1):
            lib.d_ocp_qp_set_q(self.stages[k], _pointer(zeros), self._qp)
            lib.d_ocp_qp_set_r(self.stages[k], _pointer(zeros), self._qp)
            if boxed:
                lib.d_ocp_qp_set_idxbu(self.stages[k], idxbu.ctypes.data_as(int_pointer), self._qp)
                lib.d_ocp_qp_set_idxbx(
                    self.stages[k], idxbx[k].ctypes.data_as(int_pointer), self._qp
                )
            if 0 < k < N:
                lib.d_ocp_qp_set_b(self.stages[k], _pointer(zeros), self._qp)

        self._sol = block(lib.d_ocp_qp_sol_strsize())
        lib.d_ocp_qp_sol_create(self._dim, self._sol, block(lib.d_ocp_qp_sol_memsize(self._dim)))
        # Partial condensing into the blocks (state boxes inside a block become general
        # constraints of the block); blocks of one stage solve the stage-wise QP itself.
        self._condensed = nb < N
        self._lengths = lengths
        self.solved_stages = [c_int(k) for k in range(nb + 1)]
        # A seed is handed over block by block: a block's state is its first stage's (block
        # 0 has none), and its inputs are its stages' in reverse order (HPIPM's order).
        firsts = np.cumsum((0, *lengths))
        self._seed_rows = np.concatenate(
            [np.arange(firsts[k + 1] - 1, firsts[k] - 1, -1) for k in range(nb)]
        )
        self._seed_u = np.zeros((N, nu))
        self._seed_x = np.zeros((N + 1, nx))
        self._seed_u_pointers = [_pointer(self._seed_u[first]) for first in firsts[:-1]]
        self._seed_x_pointers = [_pointer(self._seed_x[first]) for first in firsts[1:]]
        solved_dim, self._solved_qp, self._solved_sol = self._dim, self._qp, self._sol
        if self._condensed:
            block_size = (c_int * (nb + 1))(*lengths, 0)
            part_dim = block(lib.d_ocp_qp_dim_strsize())
            lib.d_ocp_qp_dim_create(c_int(nb), part_dim, block(lib.d_ocp_qp_dim_memsize(nb)))
            lib.d_part_cond_qp_compute_dim(self._dim, block_size, part_dim)
            self._cond_arg = block(_PART_COND_STRUCT_BYTES)
            lib.d_part_cond_qp_arg_create(
                c_int(nb), self._cond_arg, block(lib.d_part_cond_qp_arg_memsize(c_int(nb)))
            )
            lib.d_part_cond_qp_arg_set_default(self._cond_arg)
            self._cond_ws = block(_PART_COND_STRUCT_BYTES)
            cond_memory = lib.d_part_cond_qp_ws_memsize(
                self._dim, block_size, part_dim, self._cond_arg
            )
            lib.d_part_cond_qp_ws_create(
                self._dim, block_size, part_dim, self._cond_arg, self._cond_ws, block(cond_memory)
            )
            part_qp = block(lib.d_ocp_qp_strsize())
            lib.d_ocp_qp_create(part_dim, part_qp, block(lib.d_ocp_qp_memsize(part_dim)))
            part_sol = block(lib.d_ocp_qp_sol_strsize())
            lib.d_ocp_qp_sol_create(part_dim, part_sol, block(lib.d_ocp_qp_sol_memsize(part_dim)))
            self._keep.append(block_size)
            solved_dim, self._solved_qp, self._solved_sol = part_dim, part_qp, part_sol
            # HPIPM changed this function's arguments (casadi 3.8's build dropped the
            # condensed QP); the newer builds are the ones that also export cond_sol.
            if hasattr(lib, "d_part_cond_qp_cond_sol"):
                self._expand_args: tuple[Any, ...] = (self._qp, part_sol)
            else:
                self._expand_args = (self._qp, part_qp, part_sol)
            self._expand_args += (self._sol, self._cond_arg, self._cond_ws)

        self._arg = block(lib.d_ocp_qp_ipm_arg_strsize())
        lib.d_ocp_qp_ipm_arg_create(
            solved_dim, self._arg, block(lib.d_ocp_qp_ipm_arg_memsize(solved_dim))
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
        workspace = block(lib.d_ocp_qp_ipm_ws_memsize(solved_dim, self._arg))
        lib.d_ocp_qp_ipm_ws_create(solved_dim, self._arg, self._ws, workspace)
        self._status = c_int(0)
        self._iterations = c_int(0)
        self.has_gradient = False
        """Whether q and r hold a (targets') gradient rather than zeros."""
        # Solution buffers for d_ocp_qp_sol_get_all (it writes π and the bound multipliers
        # too); stage 0 has no state and stage N no input.
        self.u = np.zeros((N + 1, nu))
        self.x = np.zeros((N + 1, nx))
        pi = np.zeros((N, nx))
        lam = np.zeros((2, N + 1, max(nx, nu)))
        self._keep += [pi, lam]

        def rows(matrix: np.ndarray) -> Any:
            return (POINTER(c_double) * len(matrix))(*(_pointer(row) for row in matrix))

        nothing = (POINTER(c_double) * (N + 1))()
        self._get_all_args = (
            self._sol, rows(self.u), rows(self.x), nothing, nothing, rows(pi),
            rows(lam[0]), rows(lam[1]), nothing, nothing, nothing, nothing,
        )  # fmt: skip
        self._keep.append(self._get_all_args)

    def set_weights(self, Q: Any, R: Any, Q_terminal: Any) -> None:
        """Q on stages 1 … N−1, R on stages 0 … N−1, Q_N on stage N (column-major)."""
        lib, stages, qp, N = self._lib, self.stages, self._qp, self._N
        for k in range(N):
            lib.d_ocp_qp_set_R(stages[k], R, qp)
            if k:
                lib.d_ocp_qp_set_Q(stages[k], Q, qp)
        lib.d_ocp_qp_set_Q(stages[N], Q_terminal, qp)

    def set_model(self, A: Any, B: Any, b0: Any) -> None:
        """A and B (column-major) on every stage; stage 0's b₀ = A x₀."""
        lib, stages, qp = self._lib, self.stages, self._qp
        set_A, set_B = lib.d_ocp_qp_set_A, lib.d_ocp_qp_set_B
        set_B(stages[0], B, qp)
        for stage in stages[1 : self._N]:
            set_A(stage, A, qp)
            set_B(stage, B, qp)
        lib.d_ocp_qp_set_b(stages[0], b0, qp)

    def set_gradient(self, q_rows: Any, r_rows: Any) -> None:
        """q_k on stages 1 … N and r_k on stages 0 … N−1 from ``q_rows[k]``, ``r_rows[k]``
        (pointers to nx and nu values; q_rows[0] is not read: stage 0 has no state)."""
        lib, stages, qp, N = self._lib, self.stages, self._qp, self._N
        set_q, set_r = lib.d_ocp_qp_set_q, lib.d_ocp_qp_set_r
        for k in range(N):
            set_r(stages[k], r_rows[k], qp)
        for k in range(1, N + 1):
            set_q(stages[k], q_rows[k], qp)

    def set_boxes(self, lbu: Any, ubu: Any, lbx: Any, ubx: Any, lbx_N: Any, ubx_N: Any) -> None:
        """The input box on every stage, the state box on stages 1 … N−1, the terminal
        box on stage N (the finite entries, as given at construction)."""
        lib, stages, qp, N = self._lib, self.stages, self._qp, self._N
        for k in range(N):
            lib.d_ocp_qp_set_lbu(stages[k], lbu, qp)
            lib.d_ocp_qp_set_ubu(stages[k], ubu, qp)
        if self._has_state_boxes:
            for k in range(1, N):
                lib.d_ocp_qp_set_lbx(stages[k], lbx, qp)
                lib.d_ocp_qp_set_ubx(stages[k], ubx, qp)
            lib.d_ocp_qp_set_lbx(stages[N], lbx_N, qp)
            lib.d_ocp_qp_set_ubx(stages[N], ubx_N, qp)

    def seed(self, u: FloatArray, x: FloatArray) -> None:
        """Start the next solve's iterations from inputs ``u`` (N, nu) and states ``x``
        (N + 1, nx) instead of the last solution."""
        lib, sol, stages = self._lib, self._solved_sol, self.solved_stages
        np.take(u, self._seed_rows, axis=0, out=self._seed_u)
        self._seed_x[:] = x
        for stage, pointer in zip(stages[:-1], self._seed_u_pointers, strict=True):
            lib.d_ocp_qp_sol_set_u(stage, pointer, sol)
        for stage, pointer in zip(stages[1:], self._seed_x_pointers, strict=True):
            lib.d_ocp_qp_sol_set_x(stage, pointer, sol)

    def solve(self) -> tuple[int, int]:
        """Condense, solve, expand into ``u`` and ``x`` (row k: stage k; x's row 0 is left
        to the caller); (status, iterations)."""
        lib = self._lib
        if self._condensed:
            lib.d_part_cond_qp_cond(self._qp, self._solved_qp, self._cond_arg, self._cond_ws)
        lib.d_ocp_qp_ipm_solve(self._solved_qp, self._solved_sol, self._arg, self._ws)
        lib.d_ocp_qp_ipm_get_status(self._ws, ctypes.byref(self._status))
        lib.d_ocp_qp_ipm_get_iter(self._ws, ctypes.byref(self._iterations))
        if self._condensed:
            lib.d_part_cond_qp_expand_sol(*self._expand_args)
        lib.d_ocp_qp_sol_get_all(*self._get_all_args)
        return self._status.value, self._iterations.value


class HpipmBackend:
    """``QpBackend`` on HPIPM's OCP-QP interior-point solver, partially condensed.

    For the interior-point iterations HPIPM condenses the N stages into blocks of
    ``block_stages`` (in C) and runs its Riccati recursions over the blocks; the box-free
    solve is one recursion over the stages. ``prepare`` builds the box-free solution map
    over the blocks, condensed in numpy (partial_condensing.py).
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
        self._lengths = block_lengths(N, block_stages)
        boxes = (self._state_idx, self._terminal_idx)
        # One Riccati recursion (box-free) is fastest stage by stage; the interior-point
        # iterations on blocks (bench sweep: 1 vs 5 stages, 0.31 vs 0.37 ms box-free and
        # 1.8 vs 1.0 ms boxed on the centralized problem).
        self._free = _HpipmProblem(
            block_lengths(N, 1), nx, nu, *boxes, False, tolerance, max_iterations
        )
        self._boxed = _HpipmProblem(self._lengths, nx, nu, *boxes, True, tolerance, max_iterations)
        self._weights: tuple[FloatArray, ...] = ()
        self._prepared_model: tuple[FloatArray, ...] = ()
        self._solution_map: UnboxedSolutionMap | None = None  # built by ``prepare`` only

        self._A = np.zeros((nx, nx), order="F")
        self._B = np.zeros((nx, nu), order="F")
        self._b0 = np.zeros(nx)
        self._Q = np.zeros((nx, nx), order="F")
        self._R = np.zeros((nu, nu), order="F")
        self._QN = np.zeros((nx, nx), order="F")
        self._lbu, self._ubu = np.zeros(nu), np.zeros(nu)
        self._lbx, self._ubx = np.zeros(max(nx, 1)), np.zeros(max(nx, 1))
        self._lbx_N, self._ubx_N = np.zeros(max(nx, 1)), np.zeros(max(nx, 1))
        self._model_pointers = tuple(_pointer(a) for a in (self._A, self._B, self._b0))
        self._weight_pointers = tuple(_pointer(a) for a in (self._Q, self._R, self._QN))
        box_buffers = (self._lbu, self._ubu, self._lbx, self._ubx, self._lbx_N, self._ubx_N)
        self._box_pointers = tuple(_pointer(a) for a in box_buffers)
        # The targets' linear terms, stage by stage (row k: stage k).
        self._q_lin = np.zeros((N + 1, nx))
        self._r_lin = np.zeros((N, nu))
        self._gradient_pointers = (
            [_pointer(row) for row in self._q_lin],
            [_pointer(row) for row in self._r_lin],
        )
        self._boxes_set = False
        self.last_was_box_free = False
        """Whether the last solve's box-free solution met every box (no IPM run)."""
        self.last_was_prepared = False
        """Whether the last solve found its model already prepared."""
        self._try_box_free = True

    def prepare(self, qp: OcpQp) -> None:
        """Build the box-free solution map of ``qp``'s model now; a later ``solve`` of a
        QP with the same A, B and weights uses it, with any targets. The map's part for
        targets is built now when ``qp`` has targets, else at the first solve with them.
        Raises ``LinAlgError`` when a condensed Hessian block is not positive definite."""
        self._prepared_model = ()
        self._solution_map = None
        blocks = {m: condense(qp.A, qp.B, qp.q_diag, qp.r_diag, m) for m in set(self._lengths)}
        ordered = [blocks[m] for m in self._lengths]
        solution_map = unboxed_solution_map(ordered, qp.q_terminal_diag, qp.q_diag, qp.r_diag)
        if qp.x_target is not None or qp.u_target is not None:
            _ = solution_map.target_recursion  # built ahead of the state, as the map is
        self._solution_map = solution_map
        self._prepared_model = tuple(np.array(a) for a in self._model(qp))

    def solve(self, qp: OcpQp) -> QpSolution:
        """Solve box-free (by the prepared map, else by HPIPM; not while an input bound
        was active in the last boxed solve), and if a box is violated solve boxed with
        HPIPM; never raises."""
        data = (qp.A, qp.B, qp.x0, qp.u_lb, qp.u_ub)
        if not all(np.isfinite(a).all() for a in data):
            return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
        targeted = qp.x_target is not None or qp.u_target is not None
        if targeted and not _finite_targets(qp):
            return QpSolution.failed(qp, QpStatus.NUMERICAL_ERROR)
        if self._boxes_empty(qp):
            return QpSolution.failed(qp, QpStatus.INFEASIBLE)
        self.last_was_prepared = len(self._prepared_model) == 5 and all(
            np.array_equal(a, b) for a, b in zip(self._model(qp), self._prepared_model, strict=True)
        )
        status, iterations = 0, 0
        self.last_was_box_free = False
        loaded = False  # this QP's data in the buffers HPIPM reads (the map needs none)
        if self._try_box_free:
            if self.last_was_prepared and self._solution_map is not None:
                u, x = self._solution_map.solve(qp.x0, qp.x_target, qp.u_target)
            else:
                self._load_data(qp)
                loaded = True
                status, iterations, u, x = self._run(self._free, qp.x0, targeted)
            self.last_was_box_free = status == 0 and self._within_boxes(qp, u, x)
        if not self.last_was_box_free:
            if self._try_box_free:
                # Saturation begins: the box-free solution, clipped into the input box, is
                # a better start than the boxed solve of the last saturation, long ago.
                self._boxed.seed(np.clip(u, qp.u_lb, qp.u_ub), x)
            if not loaded:
                self._load_data(qp)
            if self._load_boxes(qp):
                self._boxed.set_boxes(*self._box_pointers)
            status, boxed_iterations, u, x = self._run(self._boxed, qp.x0, targeted)
            iterations += boxed_iterations
            # Saturation lasts a few ticks: while an input bound is active, skip the attempt.
            self._try_box_free = not self._input_bound_active(qp, u)
        result = _STATUS.get(status, QpStatus.NUMERICAL_ERROR)
        if result is QpStatus.SOLVED and not (np.all(np.isfinite(u)) and np.all(np.isfinite(x))):
            result = QpStatus.NUMERICAL_ERROR
        return QpSolution(u, x, result, iterations)

    def _run(
        self, problem: _HpipmProblem, x0: FloatArray, targeted: bool
    ) -> tuple[int, int, FloatArray, FloatArray]:
        """``problem`` on this tick's model (and targets, loaded by ``_load_data``):
        (status, iterations, u (N, nu), x (N+1, nx))."""
        problem.set_model(*self._model_pointers)
        if targeted or problem.has_gradient:  # without targets, once to clear the last ones
            if not targeted:
                self._q_lin.fill(0.0)
                self._r_lin.fill(0.0)
            problem.set_gradient(*self._gradient_pointers)
            problem.has_gradient = targeted
        status, iterations = problem.solve()
        trajectory = problem.x.copy()
        trajectory[0] = x0
        return status, iterations, problem.u[:-1].copy(), trajectory

    @staticmethod
    def _model(qp: OcpQp) -> tuple[FloatArray, ...]:
        """What fixes the box-free map."""
        return (qp.A, qp.B, qp.q_diag, qp.r_diag, qp.q_terminal_diag)

    def _load_data(self, qp: OcpQp) -> None:
        """The weights (when changed), A, B, b₀ = A x₀ and the targets' linear terms (when
        there are targets) into the buffers HPIPM reads."""
        self._load_weights(qp)
        self._A[:] = qp.A
        self._B[:] = qp.B
        np.dot(qp.A, qp.x0, out=self._b0)
        if qp.x_target is not None or qp.u_target is not None:
            self._load_targets(qp)

    def _load_targets(self, qp: OcpQp) -> None:
        """HPIPM's linear terms of ``qp``'s targets into their buffers (see the module
        docstring)."""
        N = self._dims[2]
        if qp.x_target is None:
            self._q_lin.fill(0.0)
        else:
            np.multiply(qp.x_target, -qp.q_diag, out=self._q_lin)
            np.multiply(qp.x_target[N], -qp.q_terminal_diag, out=self._q_lin[N])
        if qp.u_target is None:
            self._r_lin.fill(0.0)
        else:
            np.multiply(qp.u_target, -qp.r_diag, out=self._r_lin)

    def _load_weights(self, qp: OcpQp) -> None:
        """Q, R and Q_N into both problems, when they differ from the last ones set."""
        weights = (qp.q_diag, qp.r_diag, qp.q_terminal_diag)
        if len(self._weights) == 3 and all(
            np.array_equal(a, b) for a, b in zip(weights, self._weights, strict=True)
        ):
            return
        for target, diagonal in zip((self._Q, self._R, self._QN), weights, strict=True):
            target[:] = np.diag(diagonal)
        for problem in (self._free, self._boxed):
            problem.set_weights(*self._weight_pointers)
        self._weights = tuple(np.array(w) for w in weights)

    def _load_boxes(self, qp: OcpQp) -> bool:
        """``qp``'s boxes into the buffers; whether they differ from the ones HPIPM holds
        (the boxes move only with u_eq and x_eq, and setting them takes 2N calls)."""
        pairs = [(self._lbu, qp.u_lb), (self._ubu, qp.u_ub)]
        for idx, lower, upper, lbx, ubx in (
            (self._state_idx, qp.x_lb, qp.x_ub, self._lbx, self._ubx),
            (self._terminal_idx, qp.x_terminal_lb, qp.x_terminal_ub, self._lbx_N, self._ubx_N),
        ):
            if idx.size:
                assert lower is not None and upper is not None
                pairs += [(lbx[: idx.size], lower[idx]), (ubx[: idx.size], upper[idx])]
        changed = not self._boxes_set
        for held, given in pairs:
            if not np.array_equal(held, given):
                held[:] = given
                changed = True
        self._boxes_set = True
        return changed

    @staticmethod
    def _input_bound_active(qp: OcpQp, u: FloatArray) -> bool:
        tolerance = 1e-5 * (qp.u_ub - qp.u_lb)
        return bool(np.any(u <= qp.u_lb + tolerance) or np.any(u >= qp.u_ub - tolerance))

    @staticmethod
    def _within_boxes(qp: OcpQp, u: FloatArray, trajectory: FloatArray) -> bool:
        if np.any(u < qp.u_lb) or np.any(u > qp.u_ub):
            return False
        inner, last = trajectory[1:-1], trajectory[-1]
        for states, lower, upper in (
            (inner, qp.x_lb, qp.x_ub),
            (last, qp.x_terminal_lb, qp.x_terminal_ub),
        ):
            if lower is None or upper is None:
                continue
            if np.any(states < lower) or np.any(states > upper):
                return False
        return True

    @staticmethod
    def _boxes_empty(qp: OcpQp) -> bool:
        """A box with lower > upper: no input sequence can meet it."""
        boxes = [(qp.u_lb, qp.u_ub), (qp.x_lb, qp.x_ub), (qp.x_terminal_lb, qp.x_terminal_ub)]
        return any(lo is not None and hi is not None and bool(np.any(lo > hi)) for lo, hi in boxes)
