"""An agent's own process solves its vehicle's problem alone: the same inputs the whole
decentralized MPC gives that vehicle, and its peers' rows as they planned them."""

from __future__ import annotations

import time

import numpy as np

from controllers.formation_equilibria import formation_equilibrium
from controllers.formation_params import FormationParams
from controllers.mpc import DecentralizedMpc, PlanStatus
from tests.conftest import hover_reference
from tests.controllers.test_mpc import settings


def test_an_agent_alone_plans_what_the_whole_decentralized_mpc_plans_for_it(
    lab_params: FormationParams,
) -> None:
    reference = hover_reference(lab_params)
    state = formation_equilibrium(lab_params, reference).x
    state[0] += 0.15  # the bar off to one side: both agents must act
    whole = DecentralizedMpc(lab_params, settings("decentralized"), "daqp", clock=time.perf_counter)
    full = whole.step(state, reference, 0.0)
    planned_by_2 = full.u_pred[:, 4:8] + 0.01  # what agent 2 told its peers, say
    asked: list[tuple[int, float]] = []

    def peer_inputs(i: int, now_s: float) -> np.ndarray:
        asked.append((i, now_s))
        return planned_by_2

    alone = DecentralizedMpc(
        lab_params,
        settings("decentralized"),
        "daqp",
        clock=time.perf_counter,
        own=(1,),
        peer_inputs=peer_inputs,
    )
    assert [agent.i for agent in alone.agents] == [1]
    plan = alone.step(state, reference, 0.0)
    assert plan.status is PlanStatus.OPTIMAL
    np.testing.assert_allclose(plan.u_pred[:, 0:4], full.u_pred[:, 0:4], atol=1e-6)
    np.testing.assert_array_equal(plan.u_pred[:, 4:8], planned_by_2)
    assert asked == [(2, 0.0)]


def test_a_peer_not_heard_is_planned_at_its_equilibrium(lab_params: FormationParams) -> None:
    reference = hover_reference(lab_params)
    eq = formation_equilibrium(lab_params, reference)
    alone = DecentralizedMpc(
        lab_params,
        settings("decentralized"),
        "daqp",
        clock=time.perf_counter,
        own=(2,),
        peer_inputs=lambda i, now_s: None,
    )
    plan = alone.step(eq.x, reference, 0.0)
    np.testing.assert_allclose(
        plan.u_pred[:, 0:4], np.tile(eq.agent_input(1), (len(plan.u_pred), 1))
    )
