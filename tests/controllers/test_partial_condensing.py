"""Partial condensing: a block's condensed data reproduce its stages exactly."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.qp.partial_condensing import block_lengths, condense


def test_block_lengths_cover_the_horizon() -> None:
    assert block_lengths(30, 5) == (5,) * 6
    assert block_lengths(30, 7) == (7, 7, 7, 7, 2)
    assert sum(block_lengths(31, 4)) == 31
    with pytest.raises(ValueError):
        block_lengths(30, 0)


@pytest.mark.parametrize("stages", [1, 3, 5])
def test_condensed_block_matches_stage_by_stage_simulation_and_cost(stages: int) -> None:
    rng = np.random.default_rng(stages)
    nx, nu = 6, 2
    A = np.eye(nx) + 0.1 * rng.normal(size=(nx, nx))
    B = rng.normal(size=(nx, nu))
    q, r = rng.uniform(0.1, 2.0, nx), rng.uniform(0.1, 2.0, nu)
    block = condense(A, B, q, r, stages)
    x0, inputs = rng.normal(size=nx), rng.normal(size=(stages, nu))
    x, states, cost = x0, [], 0.0
    for u in inputs:
        states.append(x)
        cost += x @ (q * x) + u @ (r * u)
        x = A @ x + B @ u
    U = inputs.ravel()
    np.testing.assert_allclose(block.A @ x0 + block.B @ U, x, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(block.states(x0, U), np.array(states), rtol=1e-12, atol=1e-12)
    condensed_cost = U @ block.R @ U + 2 * U @ block.S @ x0 + x0 @ block.Q @ x0
    assert condensed_cost == pytest.approx(cost, rel=1e-12)
