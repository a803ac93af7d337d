"""The HPIPM back-end against the exact active-set solver (DAQP) on the lab's QPs."""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from controllers.mpc import CentralizedMpc
from controllers.qp.base import OcpQp, QpStatus
from controllers.qp.condensed import CondensedDaqpBackend
from controllers.qp.hpipm import HpipmBackend, _pointer
from supervisor.app.config import load_config
from tests.conftest import CONFIGS

CONFIG = load_config(CONFIGS / "kth_sml.toml")


def lab_qp(params: FormationParams, deviation: float, seed: int) -> OcpQp:
    """A centralized-MPC QP of the lab (Table I) at random yaws, from a perturbed state."""
    rng = np.random.default_rng(seed)
    settings = CONFIG.mpc_settings("centralized")
    reference = FormationReference(
        (0.0, 0.0, 1.0), rng.uniform(-3, 3), (rng.uniform(-3, 3), 0.2), 0.3
    )
    eq = formation_equilibrium(params, reference)
    A, B = CentralizedMpc(params, settings, "daqp", clock=time.perf_counter).linearization(
        eq.x, reference
    )
    w, lim = settings.weights, settings.limits
    n = params.n_vehicles
    u_lb = np.tile([lim.thrust_min_n, -1.0, -1.0, -1.0], n) - eq.u
    u_ub = np.tile([lim.thrust_max_n, 1.0, 1.0, 1.0], n) - eq.u
    q = np.asarray(w.q_diag, dtype=float)
    return OcpQp(
        A=A, B=B, q_diag=q, r_diag=np.asarray(w.r_diag, dtype=float),
        q_terminal_diag=w.terminal_scale * q, x0=deviation * rng.normal(size=eq.x.size),
        u_lb=u_lb, u_ub=u_ub, horizon=settings.horizon,
    )  # fmt: skip


@pytest.mark.parametrize("deviation", [0.01, 0.3, 1.0])
def test_hpipm_agrees_with_daqp_from_small_to_saturating_errors(
    lab_params: FormationParams, deviation: float
) -> None:
    template = lab_qp(lab_params, deviation, 0)
    hpipm, daqp = HpipmBackend(template), CondensedDaqpBackend(template)
    for seed in range(8):  # warm-started sequence of changing QPs
        qp = lab_qp(lab_params, deviation, seed)
        a, b = hpipm.solve(qp), daqp.solve(qp)
        assert a.status is QpStatus.SOLVED and b.status is QpStatus.SOLVED
        np.testing.assert_allclose(a.u, b.u, atol=1e-4 * 2.0)
        np.testing.assert_allclose(a.x[1], qp.A @ qp.x0 + qp.B @ a.u[0], atol=1e-8)
        assert np.all(a.u >= qp.u_lb - 1e-7) and np.all(a.u <= qp.u_ub + 1e-7)


def bounded(qp: OcpQp, terminal_m: float) -> OcpQp:
    """The bar height held within ±2 cm on every stage, every state within ±terminal at N."""
    nx = qp.x0.size
    x_lb, x_ub = np.full(nx, -np.inf), np.full(nx, np.inf)
    x_lb[2], x_ub[2] = -0.02, 0.02
    return dataclasses.replace(
        qp, x0=np.where(np.arange(nx) == 2, 0.0, qp.x0), x_lb=x_lb, x_ub=x_ub,
        x_terminal_lb=np.full(nx, -terminal_m), x_terminal_ub=np.full(nx, terminal_m),
    )  # fmt: skip


def test_state_and_terminal_boxes(lab_params: FormationParams) -> None:
    qp = bounded(lab_qp(lab_params, 0.1, 3), 0.4)
    a = HpipmBackend(qp).solve(qp)
    b = CondensedDaqpBackend(qp).solve(qp)
    assert a.status is QpStatus.SOLVED and b.status is QpStatus.SOLVED
    np.testing.assert_allclose(a.u, b.u, atol=2e-4)
    assert np.all(np.abs(a.x[1:-1, 2]) <= 0.02 + 1e-6)
    assert np.max(np.abs(a.x[-1])) == pytest.approx(0.4, abs=1e-6)  # the terminal box is active
    unbounded = HpipmBackend(lab_qp(lab_params, 0.1, 3)).solve(lab_qp(lab_params, 0.1, 3))
    assert np.max(np.abs(unbounded.x[-1])) > 0.4  # ... and it changed the solution


def test_an_unreachable_terminal_box_is_a_failed_solve_not_an_exception(
    lab_params: FormationParams,
) -> None:
    qp = bounded(lab_qp(lab_params, 0.1, 3), 0.05)
    backend = HpipmBackend(qp)
    assert backend.solve(qp).status is not QpStatus.SOLVED
    assert CondensedDaqpBackend(qp).solve(qp).status is QpStatus.INFEASIBLE  # the oracle agrees
    feasible = bounded(lab_qp(lab_params, 0.1, 3), 0.4)
    assert backend.solve(feasible).status is QpStatus.SOLVED


def test_bad_qps_report_a_status_instead_of_raising(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 0.3, 1)
    backend = HpipmBackend(qp)
    x0 = qp.x0.copy()
    x0[4] = math.nan
    assert backend.solve(dataclasses.replace(qp, x0=x0)).status is QpStatus.NUMERICAL_ERROR
    empty = dataclasses.replace(qp, u_lb=qp.u_ub + 1.0)
    assert backend.solve(empty).status is QpStatus.INFEASIBLE
    assert backend.solve(qp).status is QpStatus.SOLVED  # and it recovers


@pytest.mark.parametrize("deviation, box_free", [(0.01, True), (1.0, False)])
def test_the_box_free_solution_is_kept_only_when_it_meets_every_box(
    lab_params: FormationParams, deviation: float, box_free: bool
) -> None:
    qp = lab_qp(lab_params, deviation, 5)
    backend = HpipmBackend(qp)
    solution = backend.solve(qp)
    assert backend.last_was_box_free is box_free
    assert solution.status is QpStatus.SOLVED
    np.testing.assert_allclose(solution.u, CondensedDaqpBackend(qp).solve(qp).u, atol=2e-4)


@pytest.mark.parametrize("block_stages", [1, 4, 7, 30])
def test_every_block_length_gives_the_same_solution_and_trajectory(
    lab_params: FormationParams, block_stages: int
) -> None:
    qp = lab_qp(lab_params, 0.3, 2)
    solution = HpipmBackend(qp, block_stages=block_stages).solve(qp)
    assert solution.status is QpStatus.SOLVED
    np.testing.assert_allclose(solution.u, CondensedDaqpBackend(qp).solve(qp).u, atol=2e-4)
    for k in range(qp.horizon):  # x is the trajectory of u, stage by stage
        np.testing.assert_allclose(
            solution.x[k + 1], qp.A @ solution.x[k] + qp.B @ solution.u[k], atol=1e-9
        )


def test_while_a_bound_is_active_the_box_free_attempt_waits_for_an_unsaturated_tick(
    lab_params: FormationParams,
) -> None:
    saturated, calm = lab_qp(lab_params, 1.0, 5), lab_qp(lab_params, 0.01, 5)
    backend = HpipmBackend(saturated)
    box_free = []
    for qp in (saturated, calm, calm):
        solution = backend.solve(qp)
        box_free.append(backend.last_was_box_free)
        np.testing.assert_allclose(solution.u, CondensedDaqpBackend(qp).solve(qp).u, atol=2e-4)
    assert box_free == [False, False, True]


def test_changed_weights_are_taken_up_by_the_next_solve(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 0.3, 4)
    backend = HpipmBackend(qp)
    backend.solve(qp)
    heavier = dataclasses.replace(qp, r_diag=10.0 * qp.r_diag, q_terminal_diag=0.5 * qp.q_diag)
    solution = backend.solve(heavier)
    oracle = CondensedDaqpBackend(heavier).solve(heavier)
    np.testing.assert_allclose(solution.u, oracle.u, atol=2e-4)
    assert np.max(np.abs(solution.u - backend.solve(qp).u)) > 1e-2  # ... and they mattered


def test_changed_boxes_are_taken_up_by_the_next_boxed_solve(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 1.0, 5)
    backend = HpipmBackend(qp)
    backend.solve(qp)
    tighter = dataclasses.replace(qp, u_lb=0.5 * qp.u_lb, u_ub=0.5 * qp.u_ub)
    for problem in (tighter, qp):
        solution = backend.solve(problem)
        assert not backend.last_was_box_free
        oracle = CondensedDaqpBackend(problem).solve(problem)
        assert np.max(np.abs(solution.u - oracle.u) / (qp.u_ub - qp.u_lb)) <= 1e-4


@pytest.mark.parametrize("block_stages", [1, 5, 7])
def test_a_seed_reaches_the_condensed_blocks_in_hpipms_input_order(
    lab_params: FormationParams, block_stages: int
) -> None:
    """HPIPM's partial condensing orders a block's inputs last stage first: seeding the
    boxed problem with its own solution (stage by stage) must leave its blocks as solved
    (7 stages a block leaves a shorter last block)."""
    qp = lab_qp(lab_params, 1.0, 5)
    backend = HpipmBackend(qp, block_stages=block_stages)
    backend.solve(qp)
    assert not backend.last_was_box_free
    boxed = backend._boxed  # white-box: the seed's layout is internal to HPIPM

    def block_inputs() -> list[np.ndarray]:
        blocks = []
        for stage, m in zip(boxed.solved_stages, boxed._lengths, strict=False):
            values = np.zeros(m * qp.u_lb.size)
            boxed._lib.d_ocp_qp_sol_get_u(stage, boxed._solved_sol, _pointer(values))
            blocks.append(values)
        return blocks

    solved = block_inputs()
    boxed.seed(boxed.u[:-1].copy(), boxed.x.copy())
    for seeded, expected in zip(block_inputs(), solved, strict=True):
        np.testing.assert_allclose(seeded, expected, atol=1e-12)
