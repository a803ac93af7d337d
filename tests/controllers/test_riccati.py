"""The box-free solution map against the exact solver, and HPIPM's use of a prepared model."""

from __future__ import annotations

import dataclasses

import numpy as np

from controllers.formation_params import FormationParams
from controllers.qp.base import QpStatus
from controllers.qp.condensed import CondensedDaqpBackend
from controllers.qp.hpipm import HpipmBackend
from controllers.qp.partial_condensing import block_lengths, condense
from controllers.qp.riccati import unboxed_solution_map
from tests.controllers.test_hpipm import lab_qp


def test_the_map_gives_the_unconstrained_optimum_for_any_block_split(
    lab_params: FormationParams,
) -> None:
    qp = lab_qp(lab_params, 0.01, 3)  # small: no bound is active
    exact = CondensedDaqpBackend(qp).solve(qp)
    assert exact.status is QpStatus.SOLVED
    for block_stages in (1, 5, 7):
        lengths = block_lengths(qp.horizon, block_stages)
        blocks = {m: condense(qp.A, qp.B, qp.q_diag, qp.r_diag, m) for m in set(lengths)}
        solution_map = unboxed_solution_map([blocks[m] for m in lengths], qp.q_terminal_diag)
        u, x = solution_map.solve(qp.x0)
        np.testing.assert_allclose(u, exact.u, atol=1e-8)
        np.testing.assert_allclose(x[0], qp.x0, atol=1e-12)
        for k in range(qp.horizon):  # the states are the inputs' trajectory
            np.testing.assert_allclose(x[k + 1], qp.A @ x[k] + qp.B @ u[k], atol=1e-9)


def test_the_map_is_linear_in_the_initial_state(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 0.3, 4)
    lengths = block_lengths(qp.horizon, 5)
    block = condense(qp.A, qp.B, qp.q_diag, qp.r_diag, 5)
    solution_map = unboxed_solution_map([block] * len(lengths), qp.q_terminal_diag)
    other = np.random.default_rng(0).normal(size=qp.nx)
    u_sum, x_sum = solution_map.solve(qp.x0 + 2.0 * other)
    u_a, x_a = solution_map.solve(qp.x0)
    u_b, x_b = solution_map.solve(other)
    np.testing.assert_allclose(u_sum, u_a + 2.0 * u_b, atol=1e-9)
    np.testing.assert_allclose(x_sum, x_a + 2.0 * x_b, atol=1e-9)


def test_a_prepared_model_is_used_only_for_the_same_model(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 0.01, 6)
    backend = HpipmBackend(qp)
    backend.prepare(qp)
    moved = dataclasses.replace(qp, x0=-qp.x0)  # another state, the same model (copied)
    moved = dataclasses.replace(moved, A=qp.A.copy(), B=qp.B.copy())
    solution = backend.solve(moved)
    assert backend.last_was_prepared and backend.last_was_box_free
    np.testing.assert_allclose(solution.u, CondensedDaqpBackend(qp).solve(moved).u, atol=1e-8)
    other_model = lab_qp(lab_params, 0.01, 7)  # other yaws: other A and B
    solution = backend.solve(other_model)
    assert not backend.last_was_prepared
    expected = CondensedDaqpBackend(other_model).solve(other_model).u
    np.testing.assert_allclose(solution.u, expected, atol=1e-8)


def test_a_prepared_model_that_saturates_is_solved_boxed(lab_params: FormationParams) -> None:
    qp = lab_qp(lab_params, 1.0, 5)  # far enough from equilibrium that inputs saturate
    backend = HpipmBackend(qp)
    backend.prepare(qp)
    solution = backend.solve(qp)
    assert backend.last_was_prepared and not backend.last_was_box_free
    oracle = CondensedDaqpBackend(qp).solve(qp)
    assert np.max(np.abs(solution.u - oracle.u) / (qp.u_ub - qp.u_lb)) <= 1e-4
