"""The reference over the horizon (controllers/preview.py) and the MPCs given it."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from controllers.mpc import CentralizedMpc, DecentralizedMpc
from controllers.params import MpcSettings, ReferenceLead
from controllers.preview import Kinematics, carried_on, moved_like, sampled_stages, stage_targets
from geometry.state import P_B, P_I, PAYLOAD_YAW, V_B
from supervisor.app.config import load_config
from tests.conftest import CONFIGS

CONFIG = load_config(CONFIGS / "kth_sml.toml")
DT_S = 0.02
HORIZON = 30


def formation_kinematics(params: FormationParams) -> Kinematics:
    layout = params.layout
    return Kinematics(
        (
            (P_B, V_B),
            *((layout.uav_slices(i)[0], layout.uav_slices(i)[1]) for i in layout.vehicles),
        ),
        ((PAYLOAD_YAW, 0), *((layout.uav_yaw_index(i), i) for i in layout.vehicles)),
    )


def moving(reference: FormationReference, t_s: float) -> FormationReference:
    """``reference`` ``t_s`` later on its own steady acceleration."""
    p, v, a = (
        np.asarray(f)
        for f in (reference.payload_position_m, reference.velocity_mps, reference.acceleration_mps2)
    )
    position = p + v * t_s + 0.5 * a * t_s**2
    velocity = v + a * t_s
    return dataclasses.replace(
        reference,
        payload_position_m=tuple(float(c) for c in position),  # type: ignore[arg-type]
        velocity_mps=tuple(float(c) for c in velocity),  # type: ignore[arg-type]
    )


ACCELERATING = FormationReference(
    (0.2, -0.1, 1.2), 0.3, (0.3, 0.3), 0.0, (0.5, -0.2, 0.1), acceleration_mps2=(0.8, 0.4, -0.3)
)


def test_the_reference_carried_on_is_its_equilibrium_later(lab_params: FormationParams) -> None:
    """x_eq(t) of an accelerating formation is the equilibrium of the reference moved on
    at its acceleration: every position and velocity of every body."""
    eq = formation_equilibrium(lab_params, ACCELERATING)
    times = np.array([0.0, 0.1, 0.6])
    carried = carried_on(eq.x, ACCELERATING, formation_kinematics(lab_params), times)
    for row, t_s in zip(carried, times, strict=True):
        later = formation_equilibrium(lab_params, moving(ACCELERATING, float(t_s))).x
        np.testing.assert_allclose(row, later, atol=1e-12)


def stages_of(
    params: FormationParams, preview: Sequence[FormationReference], every: int = 5
) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    picked = {*range(every, len(preview) + 1, every), len(preview)}
    return {
        k: (lambda e: (e.x, e.u))(formation_equilibrium(params, preview[k - 1])) for k in picked
    }


def test_a_preview_that_carries_the_reference_on_asks_for_nothing_more(
    lab_params: FormationParams,
) -> None:
    eq = formation_equilibrium(lab_params, ACCELERATING)
    preview = [moving(ACCELERATING, k * DT_S) for k in range(1, HORIZON + 1)]
    x_target, u_target = stage_targets(
        eq.x,
        eq.u,
        ACCELERATING,
        stages_of(lab_params, preview),
        HORIZON,
        formation_kinematics(lab_params),
        DT_S,
    )
    assert np.abs(x_target).max() < 1e-9
    assert np.abs(u_target).max() < 1e-9


def test_a_stop_ahead_becomes_targets_whose_velocities_agree_with_their_positions(
    lab_params: FormationParams,
) -> None:
    """A steady 1 m/s cruise that stops 0.2 s ahead (decelerating at 2 m/s² from stage 10
    on): the targets hold the bar back from the cruise carried on, and each body's target
    velocity is the rate of its target positions."""
    cruise = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), 0.0, (1.0, 0.0, 0.0))
    preview = []
    for k in range(1, HORIZON + 1):
        t_s = k * DT_S
        if t_s <= 0.2:
            preview.append(moving(cruise, t_s))
        else:
            at_brake = moving(cruise, 0.2)
            preview.append(
                moving(dataclasses.replace(at_brake, acceleration_mps2=(-2.0, 0.0, 0.0)), t_s - 0.2)
            )
    eq = formation_equilibrium(lab_params, cruise)
    kinematics = formation_kinematics(lab_params)
    x_target, u_target = stage_targets(
        eq.x, eq.u, cruise, stages_of(lab_params, preview, every=1), HORIZON, kinematics, DT_S
    )
    bar_x = x_target[:, P_B][:, 0]
    assert abs(bar_x[10]) < 1e-9  # still cruising at stage 10
    assert bar_x[-1] == pytest.approx(-0.5 * 2.0 * (0.4) ** 2, abs=1e-9)  # braked 0.4 s
    carried = carried_on(eq.x, cruise, kinematics, np.arange(HORIZON + 1, dtype=np.float64) * DT_S)
    absolute = carried + x_target
    for position, velocity in kinematics.moving:
        rate = np.gradient(absolute[:, position], DT_S, axis=0)
        np.testing.assert_allclose(absolute[11:-1, velocity], rate[11:-1], atol=1e-9)
    # Braking tilts the UAVs back: their thrusts change from the cruise's.
    assert np.abs(u_target[-1]).max() > 0.1


def test_a_preview_moves_with_the_reference() -> None:
    before = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    after = dataclasses.replace(before, payload_position_m=(0.1, -0.2, 1.0), payload_yaw_rad=0.05)
    preview = {30: dataclasses.replace(before, payload_position_m=(0.5, 0.0, 1.0))}
    moved = moved_like(preview, before, after)[30]
    assert moved.payload_position_m == pytest.approx((0.6, -0.2, 1.0))
    assert moved.payload_yaw_rad == pytest.approx(0.05)
    assert moved_like(preview, before, before) == preview


def mpc_settings(controller: str) -> MpcSettings:
    options: dict[str, object] = {"late_after_s": 10.0, "reference_lead": ReferenceLead(0.0, 0.0)}
    return dataclasses.replace(CONFIG.mpc_settings(controller), **options)  # type: ignore[arg-type]


@pytest.mark.parametrize("controller", ["centralized", "decentralized"])
def test_a_preview_of_the_reference_carried_on_changes_no_input(
    controller: str, lab_params: FormationParams
) -> None:
    make = CentralizedMpc if controller == "centralized" else DecentralizedMpc
    with_preview = make(lab_params, mpc_settings(controller), clock=time.perf_counter)
    without = make(lab_params, mpc_settings(controller), clock=time.perf_counter)
    state = formation_equilibrium(lab_params, ACCELERATING).x
    state[P_B] += (0.05, -0.03, 0.02)  # something to correct
    preview = {k: moving(ACCELERATING, k * DT_S) for k in sampled_stages(HORIZON)}
    planned = with_preview.step(state, ACCELERATING, 0.0, preview)
    plain = without.step(state, ACCELERATING, 0.0)
    np.testing.assert_allclose(planned.u, plain.u, atol=1e-7)


@pytest.mark.parametrize("controller", ["centralized", "decentralized"])
def test_with_a_preview_the_plan_moves_before_the_reference_does(
    controller: str, lab_params: FormationParams
) -> None:
    """At rest now, 0.3 m along x from stage 10 on: the plan sets off towards it (UAV 1
    leads, the bar follows); without the preview it holds still."""
    make = CentralizedMpc if controller == "centralized" else DecentralizedMpc
    here = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    there = dataclasses.replace(here, payload_position_m=(0.3, 0.0, 1.0))
    preview = {k: here if k < 10 else there for k in sampled_stages(HORIZON)}
    state = formation_equilibrium(lab_params, here).x
    mpc = make(lab_params, mpc_settings(controller), clock=time.perf_counter)
    ahead = mpc.step(state, here, 0.0, preview)
    still = make(lab_params, mpc_settings(controller), clock=time.perf_counter).step(
        state, here, 0.0
    )
    # UAV 1's x: the centralized state's UAV block, the first agent's own (P_I) alike.
    uav_x = lab_params.layout.uav_slices(1)[0].start if controller == "centralized" else P_I.start
    start_x = float(state[lab_params.layout.uav_slices(1)[0]][0])
    assert ahead.x_pred[-1][uav_x] - start_x > 0.01
    assert abs(still.x_pred[-1][uav_x] - start_x) < 1e-9
