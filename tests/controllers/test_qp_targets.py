"""Per-stage tracking targets (x̄_k, ū_k of base.py) in every QP back-end, against an
independent dense reference: the states eliminated, the QP is the weighted least-squares
problem min ‖C U − d‖² (numpy's lstsq without boxes, scipy's bounded BVLS with input
boxes)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from controllers.formation_params import FormationParams
from controllers.qp.base import OcpQp, QpBackend, QpSolution, QpStatus
from controllers.qp.condensed import CondensedDaqpBackend
from controllers.qp.hpipm import HpipmBackend
from controllers.qp.osqp_backend import OsqpBackend
from controllers.qp.partial_condensing import block_lengths, condense
from controllers.qp.riccati import unboxed_solution_map
from tests.controllers.test_hpipm import bounded, lab_qp


def random_qp(seed: int, nx: int = 6, nu: int = 2, horizon: int = 12) -> OcpQp:
    """A stable-ish random model, random diagonal weights, state and targets; input boxes
    far away (inactive)."""
    rng = np.random.default_rng(seed)
    A = np.eye(nx) + 0.15 * rng.normal(size=(nx, nx))
    A /= max(1.0, float(np.max(np.abs(np.linalg.eigvals(A))))) / 1.02
    return OcpQp(
        A=A, B=rng.normal(size=(nx, nu)), q_diag=rng.uniform(0.2, 3.0, nx),
        r_diag=rng.uniform(0.05, 1.0, nu), q_terminal_diag=rng.uniform(1.0, 10.0, nx),
        x0=rng.normal(size=nx), u_lb=np.full(nu, -1e3), u_ub=np.full(nu, 1e3), horizon=horizon,
        x_target=rng.normal(size=(horizon + 1, nx)), u_target=rng.normal(size=(horizon, nu)),
    )  # fmt: skip


def least_squares(qp: OcpQp) -> tuple[np.ndarray, np.ndarray]:
    """(C, d) with the QP's cost ‖C U − d‖² + constant, U the stacked inputs."""
    nx, nu, N = qp.nx, qp.nu, qp.horizon
    power = [np.eye(nx)]
    for _ in range(N):
        power.append(qp.A @ power[-1])
    gamma = np.zeros((N * nx, N * nu))  # rows: x_1 … x_N
    for k in range(1, N + 1):
        for j in range(k):
            gamma[(k - 1) * nx : k * nx, j * nu : (j + 1) * nu] = power[k - 1 - j] @ qp.B
    free = np.concatenate([power[k] @ qp.x0 for k in range(1, N + 1)])
    x_target = np.zeros((N + 1, nx)) if qp.x_target is None else qp.x_target
    u_target = np.zeros((N, nu)) if qp.u_target is None else qp.u_target
    sqrt_q = np.sqrt(np.concatenate([np.tile(qp.q_diag, N - 1), qp.q_terminal_diag]))
    sqrt_r = np.sqrt(np.tile(qp.r_diag, N))
    C = np.vstack([sqrt_q[:, None] * gamma, np.diag(sqrt_r)])
    d = np.concatenate([sqrt_q * (x_target[1:].ravel() - free), sqrt_r * u_target.ravel()])
    return C, d


def reference(qp: OcpQp) -> np.ndarray:
    """The optimal inputs (N, nu): lstsq, or BVLS (an exact active-set method) when an
    input bound is finite and close."""
    C, d = least_squares(qp)
    if np.all(qp.u_ub - qp.u_lb > 1e2):
        U = np.linalg.lstsq(C, d, rcond=None)[0]
    else:
        lower, upper = np.tile(qp.u_lb, qp.horizon), np.tile(qp.u_ub, qp.horizon)
        U = lsq_linear(C, d, bounds=(lower, upper), method="bvls", tol=1e-14).x
    return np.asarray(U).reshape(qp.horizon, qp.nu)


def trajectory(qp: OcpQp, u: np.ndarray) -> np.ndarray:
    x = [qp.x0]
    for k in range(qp.horizon):
        x.append(qp.A @ x[-1] + qp.B @ u[k])
    return np.array(x)


def hpipm_prepared(qp: OcpQp) -> HpipmBackend:
    """HPIPM with the box-free solution map of ``qp``'s model prepared (blocks of 5: the
    horizons here leave a shorter last block)."""
    backend = HpipmBackend(qp, block_stages=5)
    backend.prepare(dataclasses.replace(qp, x_target=None, u_target=None))
    return backend


BACKENDS: dict[str, Callable[[OcpQp], QpBackend]] = {
    "daqp": CondensedDaqpBackend,
    "osqp": OsqpBackend,
    "hpipm": lambda qp: HpipmBackend(qp, block_stages=5),
    "hpipm-stagewise": lambda qp: HpipmBackend(qp, block_stages=1),
    "hpipm-prepared": hpipm_prepared,
}
# OSQP (ADMM, eps 1e-6, polished) and HPIPM's interior point (tol 1e-6) are accurate to
# their tolerances; the rest are exact up to rounding.
EXACT, IPM, ADMM = 1e-9, 2e-5, 1e-5
TOLERANCE = {"daqp": EXACT, "osqp": ADMM, "hpipm": EXACT, "hpipm-stagewise": EXACT}
TOLERANCE["hpipm-prepared"] = EXACT


def solved(backend: QpBackend, qp: OcpQp) -> QpSolution:
    solution = backend.solve(qp)
    assert solution.status is QpStatus.SOLVED
    np.testing.assert_allclose(solution.x, trajectory(qp, solution.u), atol=1e-8)
    return solution


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("dims", [(6, 2, 12), (9, 3, 17), (4, 1, 5)])
def test_box_free_solutions_with_targets_match_the_dense_reference(
    name: str, dims: tuple[int, int, int]
) -> None:
    for seed in range(3):
        qp = random_qp(seed, *dims)
        backend = BACKENDS[name](qp)
        solution = solved(backend, qp)
        np.testing.assert_allclose(solution.u, reference(qp), atol=TOLERANCE[name], rtol=0)
        if name == "hpipm-prepared":
            assert isinstance(backend, HpipmBackend)
            assert backend.last_was_prepared and backend.last_was_box_free


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("which", ["x", "u"])
def test_state_or_input_targets_alone_match_the_dense_reference(name: str, which: str) -> None:
    qp = random_qp(7)
    qp = dataclasses.replace(
        qp,
        x_target=qp.x_target if which == "x" else None,
        u_target=qp.u_target if which == "u" else None,
    )
    solution = solved(BACKENDS[name](qp), qp)
    np.testing.assert_allclose(solution.u, reference(qp), atol=TOLERANCE[name], rtol=0)


def saturating(qp: OcpQp) -> OcpQp:
    """``qp`` with an input box that cuts its box-free optimum: some inputs saturate."""
    free = reference(dataclasses.replace(qp, u_lb=np.full(qp.nu, -1e3), u_ub=np.full(qp.nu, 1e3)))
    bound = 0.5 * np.max(np.abs(free), axis=0)
    return dataclasses.replace(qp, u_lb=-bound, u_ub=bound)


def assert_kkt(qp: OcpQp, u: np.ndarray, tolerance: float) -> None:
    """Stationarity with sign-correct bound multipliers: the cost's gradient in U is zero
    on free inputs, ≥ 0 at a lower bound and ≤ 0 at an upper one."""
    C, d = least_squares(qp)
    U = u.ravel()
    gradient = 2 * C.T @ (C @ U - d)
    lower, upper = np.tile(qp.u_lb, qp.horizon), np.tile(qp.u_ub, qp.horizon)
    slack = 1e-6 * (upper - lower)
    at_lower, at_upper = np.less_equal(U, lower + slack), np.greater_equal(U, upper - slack)
    inside = ~(at_lower | at_upper)
    assert np.all(np.greater_equal(U, lower - 1e-7)) and np.all(np.less_equal(U, upper + 1e-7))
    assert np.max(np.abs(gradient[inside]), initial=0.0) <= tolerance
    assert np.all(gradient[at_lower] >= -tolerance) and np.all(gradient[at_upper] <= tolerance)


@pytest.mark.parametrize("name", BACKENDS)
def test_active_input_boxes_with_targets_match_bounded_least_squares(name: str) -> None:
    for seed in range(3):
        qp = saturating(random_qp(seed, 6, 2, 12))
        backend = BACKENDS[name](qp)
        solution = solved(backend, qp)
        expected = reference(qp)
        active = np.isclose(expected, qp.u_lb) | np.isclose(expected, qp.u_ub)
        assert active.any() and not active.all()  # the boxes matter, and not everywhere
        tolerance = IPM if name.startswith("hpipm") else TOLERANCE[name]
        np.testing.assert_allclose(solution.u, expected, atol=tolerance, rtol=0)
        assert_kkt(qp, solution.u, tolerance=1e3 * tolerance)
        if isinstance(backend, HpipmBackend):
            assert not backend.last_was_box_free  # the interior-point solve, with targets


def model_trajectory(qp: OcpQp, seed: int) -> OcpQp:
    """``qp`` whose targets are a trajectory of its model from x0 = x̄_0, with its inputs
    inside the input box and every state inside a state and a terminal box."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.5 * qp.u_lb, 0.5 * qp.u_ub, size=(qp.horizon, qp.nu))
    x = trajectory(qp, u)
    margin = np.max(np.abs(x)) + 1.0
    box = np.full(qp.nx, margin)
    return dataclasses.replace(
        qp, x_target=x, u_target=u, x_lb=-box, x_ub=box, x_terminal_lb=-box, x_terminal_ub=box
    )


@pytest.mark.parametrize("name", BACKENDS)
def test_targets_that_are_a_model_trajectory_are_tracked_exactly(name: str) -> None:
    for seed in range(3):
        qp = model_trajectory(saturating(random_qp(seed)), seed)
        solution = solved(BACKENDS[name](qp), qp)
        assert qp.x_target is not None and qp.u_target is not None
        tolerance = 1e-4 if name == "osqp" else 1e-8
        np.testing.assert_allclose(solution.u, qp.u_target, atol=tolerance, rtol=0)
        np.testing.assert_allclose(solution.x, qp.x_target, atol=tolerance, rtol=0)


def test_a_model_trajectory_is_tracked_by_hpipms_interior_point_solve_too() -> None:
    """While an input bound was active in the last solve the box-free attempt is skipped:
    the boxed interior-point solve then has to give the targets as well."""
    qp = saturating(random_qp(3))
    backend = HpipmBackend(qp, block_stages=5)
    solved(backend, qp)
    tracking = model_trajectory(qp, 3)
    solution = solved(backend, tracking)
    assert not backend.last_was_box_free
    assert tracking.x_target is not None and tracking.u_target is not None
    np.testing.assert_allclose(solution.u, tracking.u_target, atol=1e-6, rtol=0)
    np.testing.assert_allclose(solution.x, tracking.x_target, atol=1e-6, rtol=0)


@pytest.mark.parametrize("name", BACKENDS)
def test_no_targets_are_zero_targets_and_targets_are_cleared_after_use(name: str) -> None:
    for saturated in (False, True):
        qp = saturating(random_qp(4)) if saturated else random_qp(4)
        plain = dataclasses.replace(qp, x_target=None, u_target=None)
        zero = dataclasses.replace(
            qp, x_target=np.zeros_like(qp.x_target), u_target=np.zeros_like(qp.u_target)
        )
        tolerance = IPM if saturated and name.startswith("hpipm") else TOLERANCE[name]
        fresh = solved(BACKENDS[name](plain), plain)
        np.testing.assert_allclose(fresh.u, reference(plain), atol=tolerance, rtol=0)
        backend = BACKENDS[name](plain)
        for problem in (zero, qp, plain, qp, zero):  # targets set, then cleared, then again
            solution = solved(backend, problem)
            expected = fresh.u if problem is not qp else reference(qp)
            np.testing.assert_allclose(solution.u, expected, atol=tolerance, rtol=0)


@pytest.mark.parametrize("name", BACKENDS)
def test_the_first_state_target_changes_nothing(name: str) -> None:
    """x̄_0 only adds a constant: Δx_0 is fixed."""
    qp = random_qp(5)
    assert qp.x_target is not None
    moved = qp.x_target.copy()
    moved[0] += 10.0
    a = solved(BACKENDS[name](qp), qp)
    b = solved(BACKENDS[name](qp), dataclasses.replace(qp, x_target=moved))
    np.testing.assert_allclose(a.u, b.u, atol=TOLERANCE[name], rtol=0)


@pytest.mark.parametrize("name", BACKENDS)
def test_non_finite_targets_are_a_failed_solve_not_an_exception(name: str) -> None:
    qp = random_qp(6)
    assert qp.u_target is not None
    bad = qp.u_target.copy()
    bad[3, 1] = np.nan
    backend = BACKENDS[name](qp)
    failed = backend.solve(dataclasses.replace(qp, u_target=bad))
    assert failed.status is QpStatus.NUMERICAL_ERROR
    np.testing.assert_allclose(solved(backend, qp).u, reference(qp), atol=TOLERANCE[name], rtol=0)


@pytest.mark.parametrize("block_stages", [1, 4, 5, 7, 12])
def test_the_solution_map_is_affine_in_the_initial_state_and_the_targets(
    block_stages: int,
) -> None:
    qp = random_qp(8, 5, 2, 12)
    lengths = block_lengths(qp.horizon, block_stages)
    blocks = {m: condense(qp.A, qp.B, qp.q_diag, qp.r_diag, m) for m in set(lengths)}
    ordered = [blocks[m] for m in lengths]
    solution_map = unboxed_solution_map(ordered, qp.q_terminal_diag, qp.q_diag, qp.r_diag)
    u, x = solution_map.solve(qp.x0, qp.x_target, qp.u_target)
    np.testing.assert_allclose(u, reference(qp), atol=EXACT, rtol=0)
    np.testing.assert_allclose(x, trajectory(qp, u), atol=1e-9, rtol=0)
    u_state, x_state = solution_map.solve(qp.x0)
    u_targets, x_targets = solution_map.solve(np.zeros(qp.nx), qp.x_target, qp.u_target)
    np.testing.assert_allclose(u, u_state + u_targets, atol=1e-10, rtol=0)
    np.testing.assert_allclose(x, x_state + x_targets, atol=1e-10, rtol=0)
    again, _ = solution_map.solve(qp.x0, qp.x_target, qp.u_target)  # work buffers reused
    np.testing.assert_array_equal(again, u)


def test_distinct_blocks_of_one_length_are_kept_apart() -> None:
    """The map takes any blocks in order; two equal-length blocks of different models (not
    one model's repeated block) must not share their condensed targets' data."""
    qp, other = random_qp(9, 4, 2, 6), random_qp(10, 4, 2, 6)
    first = condense(qp.A, qp.B, qp.q_diag, qp.r_diag, 3)
    second = condense(qp.A, qp.B, qp.q_diag, qp.r_diag, 3)  # equal data, another object
    mixed = condense(other.A, other.B, qp.q_diag, qp.r_diag, 3)
    same = unboxed_solution_map([first, first], qp.q_terminal_diag, qp.q_diag, qp.r_diag)
    copies = unboxed_solution_map([first, second], qp.q_terminal_diag, qp.q_diag, qp.r_diag)
    np.testing.assert_allclose(
        same.solve(qp.x0, qp.x_target, qp.u_target)[0],
        copies.solve(qp.x0, qp.x_target, qp.u_target)[0],
        atol=1e-12,
    )
    two_models = unboxed_solution_map([first, mixed], qp.q_terminal_diag, qp.q_diag, qp.r_diag)
    u, x = two_models.solve(qp.x0, qp.x_target, qp.u_target)
    # The reference: the same problem solved as one dense QP with stage-varying dynamics.
    As, Bs = [qp.A] * 3 + [other.A] * 3, [qp.B] * 3 + [other.B] * 3
    np.testing.assert_allclose(u, _time_varying_reference(qp, As, Bs), atol=EXACT, rtol=0)
    for k in range(qp.horizon):
        np.testing.assert_allclose(x[k + 1], As[k] @ x[k] + Bs[k] @ u[k], atol=1e-10)


def _time_varying_reference(qp: OcpQp, As: list[np.ndarray], Bs: list[np.ndarray]) -> np.ndarray:
    """The box-free optimum with x_{k+1} = A_k x_k + B_k u_k, by lstsq."""
    nx, nu, N = qp.nx, qp.nu, qp.horizon
    state_map = [np.zeros((nx, N * nu))]  # x_k = F_k x0 + G_k U
    free = [qp.x0]
    for k in range(N):
        G = As[k] @ state_map[-1]
        G[:, k * nu : (k + 1) * nu] += Bs[k]
        state_map.append(G)
        free.append(As[k] @ free[-1])
    assert qp.x_target is not None and qp.u_target is not None
    weights = [qp.q_diag] * (N - 1) + [qp.q_terminal_diag]
    rows = [np.sqrt(w)[:, None] * G for w, G in zip(weights, state_map[1:], strict=True)]
    rhs = [np.sqrt(w) * (t - f) for w, t, f in zip(weights, qp.x_target[1:], free[1:], strict=True)]
    sqrt_r = np.sqrt(np.tile(qp.r_diag, N))
    C = np.vstack([*rows, np.diag(sqrt_r)])
    d = np.concatenate([*rhs, sqrt_r * qp.u_target.ravel()])
    return np.asarray(np.linalg.lstsq(C, d, rcond=None)[0]).reshape(N, nu)


def test_a_map_built_without_the_stage_weights_refuses_targets() -> None:
    qp = random_qp(11)
    block = condense(qp.A, qp.B, qp.q_diag, qp.r_diag, 4)
    solution_map = unboxed_solution_map([block] * 3, qp.q_terminal_diag)
    solution_map.solve(qp.x0)  # without targets, as before
    with pytest.raises(ValueError, match="stage weights"):
        solution_map.solve(qp.x0, qp.x_target, qp.u_target)


def lab_targets(qp: OcpQp, scale: float, seed: int) -> OcpQp:
    """The lab QP with targets: a model trajectory from elsewhere, small enough that no
    input saturates."""
    rng = np.random.default_rng(seed)
    u = scale * rng.uniform(qp.u_lb, qp.u_ub, size=(qp.horizon, qp.nu))
    x = np.zeros((qp.horizon + 1, qp.nx))
    x[0] = scale * rng.normal(size=qp.nx)
    for k in range(qp.horizon):
        x[k + 1] = qp.A @ x[k] + qp.B @ u[k]
    return dataclasses.replace(qp, x_target=x, u_target=u)


@pytest.mark.parametrize("deviation, box_free", [(0.01, True), (1.0, False)])
def test_the_prepared_map_and_hpipm_agree_on_the_centralized_qp_with_targets(
    lab_params: FormationParams, deviation: float, box_free: bool
) -> None:
    """36 states, 8 inputs, N = 30: ``prepare`` then ``solve`` with targets (the map, or
    the interior-point solve when inputs saturate) against the unprepared solve and DAQP."""
    qp = lab_targets(lab_qp(lab_params, deviation, 4), 0.01, 4)
    prepared = HpipmBackend(qp)
    prepared.prepare(qp)  # with targets: the map's targets part is built ahead
    a = solved(prepared, qp)
    assert prepared.last_was_prepared and prepared.last_was_box_free is box_free
    unprepared = HpipmBackend(qp)
    b = solved(unprepared, qp)
    assert not unprepared.last_was_prepared and unprepared.last_was_box_free is box_free
    exact = solved(CondensedDaqpBackend(qp), qp)
    scale = qp.u_ub - qp.u_lb
    tolerance = 1e-8 if box_free else 1e-4  # relative to the actuator range
    assert np.max(np.abs(a.u - b.u) / scale) <= tolerance
    assert np.max(np.abs(a.u - exact.u) / scale) <= tolerance
    untracked = solved(HpipmBackend(qp), dataclasses.replace(qp, x_target=None, u_target=None))
    assert np.max(np.abs(a.u - untracked.u) / scale) > 1e-3  # ... and the targets mattered


def test_targets_with_state_and_terminal_boxes_agree_between_hpipm_and_daqp(
    lab_params: FormationParams,
) -> None:
    qp = lab_targets(bounded(lab_qp(lab_params, 0.1, 3), 0.4), 0.02, 5)
    a = solved(HpipmBackend(qp), qp)
    b = solved(CondensedDaqpBackend(qp), qp)
    np.testing.assert_allclose(a.u, b.u, atol=2e-4)
    assert np.all(np.abs(a.x[1:-1, 2]) <= 0.02 + 1e-6)
    assert np.max(np.abs(a.x[-1])) <= 0.4 + 1e-6
