"""The MPCs: LQR oracle, back-end agreement, fallbacks, and closed loops on the model."""

from __future__ import annotations

import dataclasses
import itertools
import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.model import PayloadModel
from controllers.mpc import (
    YAW_LEAD_FADE_RAD,
    CentralizedMpc,
    DecentralizedMpc,
    PlanStatus,
    agent_state,
    led_reference,
    yaws_ahead,
)
from controllers.params import RECOMMENDED_LEAD, MpcSettings, MpcWeights, ReferenceLead
from geometry.formation import FormationLayout
from geometry.state import P_B, PAYLOAD_YAW, V_B, W_B
from supervisor.app.config import load_config
from tests.conftest import CONFIGS, hover_reference
from tests.controllers.closed_loop import Run, fly
from tests.controllers.test_formation_equilibria import irregular_params, plate_params

CONFIG = load_config(CONFIGS / "kth_sml.toml")
LAYOUT = FormationLayout(2)  # the lab's
BACKENDS = ["osqp", "daqp", "hpipm"]


def settings(controller: str, **changes: object) -> MpcSettings:
    # The late-solve budget is a real-time concern; these tests check the control law.
    options: dict[str, object] = {"late_after_s": 10.0, **changes}
    return dataclasses.replace(CONFIG.mpc_settings(controller), **options)  # type: ignore[arg-type]


def actuator_range(n_uavs: int) -> np.ndarray:
    lim = CONFIG.mpc_settings("centralized").limits
    return np.tile([lim.thrust_max_n - lim.thrust_min_n] + [2 * lim.torque_max_nm] * 3, n_uavs)


def torques(layout: FormationLayout) -> list[int]:
    """Every τ_i's indices in u."""
    return [k for i in layout.vehicles for k in range(layout.n_inputs)[layout.torque_slice(i)]]


def thrusts(layout: FormationLayout) -> list[int]:
    return [layout.thrust_index(i) for i in layout.vehicles]


def riccati_first_gain(
    A: np.ndarray, B: np.ndarray, q: np.ndarray, r: np.ndarray, scale: float, N: int
) -> np.ndarray:
    """K_0 of the finite-horizon LQR with the MPC's cost: u_0 = −K_0 Δx_0."""
    Q, R = np.diag(q), np.diag(r)
    P = scale * Q
    K = np.zeros((B.shape[1], A.shape[0]))
    for _ in range(N):
        K = np.linalg.solve(R + B.T @ P @ B, B.T @ P @ A)
        P = Q + A.T @ P @ (A - B @ K)
    return K


@pytest.mark.parametrize("backend", BACKENDS)
def test_unconstrained_first_input_is_the_lqr_input(
    backend: str, lab_params: FormationParams
) -> None:
    mpc = CentralizedMpc(lab_params, settings("centralized"), backend, clock=time.perf_counter)
    reference = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5), math.radians(20))
    eq = formation_equilibrium(lab_params, reference)
    state = eq.x.copy()
    state[P_B] += (0.02, -0.01, 0.01)  # small enough that no bound is active
    state[PAYLOAD_YAW] += 0.02
    plan = mpc.step(state, reference, 0.0)
    assert plan.status is PlanStatus.OPTIMAL
    A, B = mpc.linearization(state, reference)
    w = mpc.settings.weights
    K = riccati_first_gain(
        A, B, np.array(w.q_diag), np.array(w.r_diag), w.terminal_scale, mpc.settings.horizon
    )
    expected = eq.u - K @ (state - eq.x)
    lim = mpc.settings.limits
    assert np.all(np.abs(expected[torques(LAYOUT)]) < lim.torque_max_nm)  # truly unconstrained
    np.testing.assert_array_less(np.abs(plan.u - expected), 1e-4 * actuator_range(2))
    assert np.abs(plan.u - eq.u).max() > 1e-3  # and the test is not comparing u_eq with u_eq


def saturating_sequence(params: FormationParams) -> list[tuple[np.ndarray, FormationReference]]:
    """States along a hard manoeuvre: large offsets saturate the torques."""
    rng = np.random.default_rng(11)
    out = []
    for k in range(12):
        ref = FormationReference(
            (0.0, 0.0, 1.0), 0.1 * k, (0.1 * k, -0.1 * k), math.radians(5 * (k % 4))
        )
        x = formation_equilibrium(params, ref).x
        x = x + rng.normal(0.0, 0.1, x.size) * (1 + (k % 3))
        out.append((x, ref))
    return out


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_backends_agree_on_the_same_qps(controller_cls: type, lab_params: FormationParams) -> None:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    controllers = {
        b: controller_cls(lab_params, settings(name), b, clock=time.perf_counter) for b in BACKENDS
    }
    saturated = 0
    lim = CONFIG.mpc_settings(name).limits
    for k, (x, ref) in enumerate(saturating_sequence(lab_params)):
        plans = {b: c.step(x, ref, 0.02 * k) for b, c in controllers.items()}
        assert all(p.status is PlanStatus.OPTIMAL for p in plans.values())
        reference = plans["daqp"].u
        for plan in plans.values():
            np.testing.assert_array_less(np.abs(plan.u - reference), 1e-4 * actuator_range(2))
        saturated += int(np.any(np.isclose(np.abs(reference[torques(LAYOUT)]), lim.torque_max_nm)))
    assert saturated >= 3  # the sequence really exercises the bounds


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_a_formation_moving_with_its_reference_needs_no_correction(
    controller_cls: type, lab_params: FormationParams
) -> None:
    """x_eq + v t solves the model with u_eq, so a system exactly on a reference that moves
    at constant velocity is left alone; the same state under a reference at rest is braked."""
    mpc = controller_cls(
        lab_params, settings(controller_cls.__name__.lower()[:-3]), clock=time.perf_counter
    )
    moving = FormationReference(
        (0.2, 0.1, 1.0), 0.4, (0.4, 0.9), math.radians(15), (0.3, -0.1, 0.05)
    )
    eq = formation_equilibrium(lab_params, moving)
    np.testing.assert_allclose(eq.x[V_B], moving.velocity_mps)
    np.testing.assert_allclose(LAYOUT.uav_velocity(eq.x, 1), moving.velocity_mps)
    plan = mpc.step(eq.x, moving, 0.0)
    assert plan.status is PlanStatus.OPTIMAL
    np.testing.assert_allclose(plan.u, eq.u, atol=1e-6 * actuator_range(2).max())
    mpc.reset()
    braking = mpc.step(eq.x, moving.at_rest(), 0.0)
    assert np.max(np.abs(braking.u - eq.u)) > 1e-2


def test_a_moving_equilibrium_is_a_steady_translation(lab_params: FormationParams) -> None:
    """f(x_eq, u_eq) = (v, 0, 0, 0, v, 0, …): positions move at v, nothing accelerates."""
    model = FormationModel(lab_params)
    moving = FormationReference(
        (0.0, 0.0, 1.0), 1.0, (0.2, -0.4), math.radians(30), (0.4, 0.2, -0.1)
    )
    eq = formation_equilibrium(lab_params, moving)
    x_dot = np.asarray(model.dynamics(eq.x, eq.u)).ravel()
    expected = np.zeros(LAYOUT.n_states)
    for position in (P_B, *(LAYOUT.uav_slices(i)[0] for i in LAYOUT.vehicles)):
        expected[position] = moving.velocity_mps
    np.testing.assert_allclose(x_dot, expected, atol=1e-9)


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_bad_input_falls_back_to_the_shifted_plan(
    controller_cls: type, lab_params: FormationParams
) -> None:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    mpc = controller_cls(lab_params, settings(name), "daqp", clock=time.perf_counter)
    reference = hover_reference(lab_params)
    state = formation_equilibrium(lab_params, reference).x
    state[0] += 0.2
    first = mpc.step(state, reference, 0.0)
    assert first.status is PlanStatus.OPTIMAL
    broken = state.copy()
    broken[5] = math.nan
    second = mpc.step(broken, reference, 0.02)
    assert second.status is PlanStatus.SHIFTED_BAD_STATE
    np.testing.assert_array_equal(second.u, first.u_pred[1])
    impossible = dataclasses.replace(reference, cone_angle_rad=2.0)
    third = mpc.step(state, impossible, 0.04)
    assert third.status is PlanStatus.SHIFTED_BAD_STATE and "cone angle" in (third.error or "")
    np.testing.assert_array_equal(third.u, first.u_pred[2])
    assert mpc.step(state, reference, 0.06).status is PlanStatus.OPTIMAL


def test_a_late_solve_uses_the_shifted_plan(lab_params: FormationParams) -> None:
    one_second_per_reading = itertools.count(0.0, 1.0).__next__
    mpc = CentralizedMpc(
        lab_params, settings("centralized", late_after_s=0.5), "daqp", clock=one_second_per_reading
    )
    reference = hover_reference(lab_params)
    state = formation_equilibrium(lab_params, reference).x
    first = mpc.step(state, reference, 0.0)
    assert first.status is PlanStatus.EQUILIBRIUM  # nothing to shift yet: hold u_eq
    np.testing.assert_allclose(first.u, formation_equilibrium(lab_params, reference).u)
    assert mpc.step(state, reference, 0.02).status is PlanStatus.SHIFTED_LATE


@pytest.mark.parametrize(
    "params", [None, plate_params(3), irregular_params(5)], ids=["lab", "plate3", "irregular5"]
)
def test_decentralized_agent_sees_its_attachment(
    params: FormationParams | None, lab_params: FormationParams
) -> None:
    """Agent i's payload is the point e_i = p_b + R(Θ_b) a_i, moving with v_b + ω_b × q_i:
    at an equilibrium, and at a turning, tumbling state (against finite differences of the
    attachment's position along the state's motion)."""
    params = params or lab_params
    moving = FormationReference(
        (0.5, 0.2, 1.0),
        0.8,
        tuple(0.1 * i for i in params.layout.vehicles),
        math.radians(30),
        (0.1, -0.2, 0.05),
        0.3,
    )
    eq = formation_equilibrium(params, moving)
    for i in params.layout.vehicles:
        np.testing.assert_allclose(agent_state(eq.x, params, i), eq.agent_state(i), atol=1e-12)
    model = FormationModel(params)
    state = eq.x + 0.05 * np.random.default_rng(2).normal(size=eq.x.size)
    h = 1e-6
    later = state + h * np.asarray(model.dynamics(state, eq.u)).ravel()
    for i in params.layout.vehicles:
        x_i, x_later = agent_state(state, params, i), agent_state(later, params, i)
        np.testing.assert_allclose((x_later[12:15] - x_i[12:15]) / h, x_i[15:18], atol=1e-5)


def formation_settings(controller: str, n: int) -> MpcSettings:
    """The lab's settings for a formation of ``n``: the payload weighted as the bar, every
    UAV as the lab's UAVs (Table I; an agent's 18-state weights need no change)."""
    lab = settings(controller, prepared_yaw_tolerance_rad=0.0)
    if controller == "decentralized":
        return lab
    w = lab.weights
    q = (*w.q_diag[:12], *w.q_diag[12:24] * n)
    return dataclasses.replace(lab, weights=MpcWeights(q, w.r_diag[:4] * n, w.terminal_scale))


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
@pytest.mark.parametrize("params", [plate_params(3), irregular_params(4)], ids=["plate3", "irr4"])
def test_a_formation_of_more_than_two_is_brought_back_to_its_reference(
    params: FormationParams, controller_cls: type
) -> None:
    """N UAVs, any payload: from 0.24 m and 10° off, each MPC (on the 12 + 12N-state, or N
    agents) brings the payload back on the formation's own model, every plan optimal."""
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    n = params.n_vehicles
    mpc = controller_cls(params, formation_settings(name, n), clock=time.perf_counter)
    start = FormationReference((0.2, -0.1, 1.1), math.radians(10), (0.0,) * n)
    run = fly(
        mpc,
        FormationModel(params),
        formation_equilibrium(params, start).x,
        hover_reference(params),
        4.0,
    )
    assert all(p.status is PlanStatus.OPTIMAL for p in run.plans)
    assert run.plans[0].u.size == 4 * n
    error_m = np.linalg.norm(run.states[:, P_B] - (0.0, 0.0, 1.0), axis=1)
    assert error_m[-1] < 0.2 * error_m[0]
    assert abs(math.degrees(run.states[-1, PAYLOAD_YAW])) < 2.5


def test_each_agent_linearizes_at_a_fixed_point_of_its_own_model() -> None:
    """Attachments at different heights: at a cone angle the vertical loads are not the
    agents' hanging masses, and ``external_force`` adds the difference to f_ext."""
    params = irregular_params(4)
    mpc = DecentralizedMpc(params, formation_settings("decentralized", 4), clock=time.perf_counter)
    eq = formation_equilibrium(
        params, FormationReference((0.2, 0.1, 1.0), 0.5, (0.0, 0.3, -0.2, 0.1), math.radians(35))
    )
    for agent in mpc.agents:
        i = agent.i
        model = PayloadModel(
            params.uavs[i - 1], agent.payload_mass_kg, params.cable_lengths_m[i - 1]
        )
        force = agent.external_force(eq.agent(i))
        assert abs(force[2]) > 1e-3  # the correction is not trivially zero here
        xdot = model.dynamics(eq.agent_state(i), eq.agent_input(i), force)
        assert float(np.abs(np.asarray(xdot)).max()) < 1e-9


def first_time_inside_for_good(
    run: Run, reference: FormationReference, tol_m: float, tol_deg: float
) -> float:
    """The earliest time from which the bar stays within the tolerances to the end."""
    error_m = np.linalg.norm(run.states[:, P_B] - np.array(reference.payload_position_m), axis=1)
    error_deg = np.degrees(np.abs(run.states[:, PAYLOAD_YAW] - reference.payload_yaw_rad))
    outside = np.flatnonzero((error_m >= tol_m) | (error_deg >= tol_deg))
    if outside.size == 0:
        return 0.0
    last = int(outside[-1])
    return math.inf if last == len(run.times_s) - 1 else float(run.times_s[last + 1])


LEAD = RECOMMENDED_LEAD
CLOSED_LOOP_CASES = [
    pytest.param(CentralizedMpc, ReferenceLead(), id="centralized"),
    pytest.param(DecentralizedMpc, LEAD, id="decentralized-with-reference-lead"),
    pytest.param(
        DecentralizedMpc,
        ReferenceLead(),
        id="decentralized",
        marks=pytest.mark.xfail(
            strict=True,
            reason="each agent models its bar end as an independent pendulum (Section V); the "
            "bar's yaw swing (0.86 Hz) and its swing along the bar (0.52 Hz) grow by 4.9 and 0.9 "
            "%/s in the linear closed loop (test_closed_loop_modes.py), so ±4 cm and ±2° remain "
            "after 8 s (the oscillation the paper reports in Fig. 8c and Table III); the "
            "reference lead (the case above, beyond the paper) damps both",
        ),
    ),
]


def fly_offset_case(
    controller_cls: type,
    params: FormationParams,
    duration_s: float,
    lead: ReferenceLead | None = None,
) -> tuple[Run, FormationReference]:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    options = settings(name, reference_lead=lead or ReferenceLead())
    mpc = controller_cls(params, options, "daqp", clock=time.perf_counter)
    reference = hover_reference(params)
    x0 = formation_equilibrium(
        params, FormationReference((0.3, 0.0, 1.0), math.radians(20), (0.0, 0.0))
    ).x
    return fly(mpc, FormationModel(params), x0, reference, duration_s), reference


@pytest.mark.slow
@pytest.mark.parametrize("controller_cls, lead", CLOSED_LOOP_CASES)
def test_closed_loop_reaches_the_setpoint(
    controller_cls: type, lead: ReferenceLead, lab_params: FormationParams
) -> None:
    """From a 0.3 m bar offset and a 20° bar-yaw error: within 2 cm and 2° by 8 s, for good
    (checked over 10 s), never leaving the input set U."""
    run, reference = fly_offset_case(controller_cls, lab_params, 10.0, lead)
    assert first_time_inside_for_good(run, reference, 0.02, 2.0) <= 8.0
    inputs = np.array([p.u for p in run.plans])
    lim = CONFIG.mpc_settings("centralized").limits
    thrust = inputs[:, thrusts(LAYOUT)]
    assert thrust.min() >= lim.thrust_min_n and thrust.max() <= lim.thrust_max_n
    assert np.abs(inputs[:, torques(LAYOUT)]).max() <= lim.torque_max_nm + 1e-9
    assert all(p.status is PlanStatus.OPTIMAL for p in run.plans)


@pytest.mark.slow
def test_decentralized_closed_loop_stays_bounded(lab_params: FormationParams) -> None:
    """What the decentralized controller does reach: the bar's error shrinks from 0.3 m and
    20° to a swing of a few centimetres and degrees."""
    run, reference = fly_offset_case(DecentralizedMpc, lab_params, 10.0)
    assert first_time_inside_for_good(run, reference, 0.06, 3.0) <= 8.0


def test_the_reference_lead_moves_the_setpoint_along_the_bars_motion_errors(
    lab_params: FormationParams,
) -> None:
    reference = FormationReference(
        (0.1, 0.2, 1.0), 0.4, (0.4, 0.4), 0.0, (0.2, 0.0, 0.0), 0.1, (0.1, 0.1)
    )
    state = formation_equilibrium(lab_params, reference).x
    assert led_reference(reference, state, LEAD) == reference  # moving as asked: no lead
    state[V_B] += (0.1, -0.2, 0.05)
    state[W_B.stop - 1] += 0.3
    led = led_reference(reference, state, LEAD)
    np.testing.assert_allclose(
        led.payload_position_m,
        np.add(reference.payload_position_m, 0.6 * np.array([0.1, -0.2, 0.05])),
    )
    assert led.payload_yaw_rad == pytest.approx(0.4 + 0.2 * 0.3)
    assert led.velocity_mps == reference.velocity_mps
    assert led.payload_yaw_rate_radps == reference.payload_yaw_rate_radps
    assert led.uav_yaw_rates_radps == reference.uav_yaw_rates_radps
    # The yaw lead fades out with θ_l; no lead, or a state with NaN, leaves the reference.
    half = dataclasses.replace(reference, cone_angle_rad=YAW_LEAD_FADE_RAD / 2)
    assert led_reference(half, state, LEAD).payload_yaw_rad == pytest.approx(0.4 + 0.1 * 0.3)
    tilted = dataclasses.replace(reference, cone_angle_rad=YAW_LEAD_FADE_RAD)
    assert led_reference(tilted, state, LEAD).payload_yaw_rad == pytest.approx(0.4)
    assert led_reference(reference, state, ReferenceLead()) is reference
    state[5] = math.nan
    assert led_reference(reference, state, LEAD) is reference


def test_a_turning_reference_is_kinematically_consistent(lab_params: FormationParams) -> None:
    """The rates a turning, moving reference carries are the time derivative of where its
    equilibrium goes: positions by the velocities, the bar's yaw by ω_b, the UAVs' yaws by
    their body rates."""
    payload_rate, uav_rates = 0.3, (-0.4, 0.5)
    velocity = (0.2, -0.1, 0.05)
    reference = FormationReference(
        (0.1, 0.2, 1.0), 0.4, (0.7, -0.2), math.radians(25), velocity, payload_rate, uav_rates
    )
    h = 1e-6
    later = FormationReference(
        tuple(p + v * h for p, v in zip(reference.payload_position_m, velocity, strict=True)),  # type: ignore[arg-type]
        reference.payload_yaw_rad + payload_rate * h,
        tuple(y + r * h for y, r in zip(reference.uav_yaw_rad, uav_rates, strict=True)),
        reference.cone_angle_rad,
    )
    x = formation_equilibrium(lab_params, reference).x
    derivative = (formation_equilibrium(lab_params, later).x - x) / h
    for position, velocity_slice in ((P_B, V_B), *(LAYOUT.uav_slices(i)[:2] for i in (1, 2))):
        np.testing.assert_allclose(derivative[position], x[velocity_slice], atol=1e-5)
    assert derivative[PAYLOAD_YAW] == pytest.approx(x[W_B][2], abs=1e-5)  # bar: ψ̇ = ω_z
    for i in LAYOUT.vehicles:
        _, _, euler, body_rates = LAYOUT.uav_slices(i)
        phi, theta, _ = x[euler]
        _, q, r = x[body_rates]
        psi_dot = (q * math.sin(phi) + r * math.cos(phi)) / math.cos(theta)  # eq. (3)
        assert derivative[LAYOUT.uav_yaw_index(i)] == pytest.approx(psi_dot, abs=1e-5)


@pytest.mark.parametrize("controller", ["centralized", "decentralized"])
def test_a_prepared_model_is_used_when_the_yaws_stay_within_the_tolerance(
    controller: str, lab_params: FormationParams
) -> None:
    options = settings(controller, prepared_yaw_tolerance_rad=0.01)
    mpc_class = CentralizedMpc if controller == "centralized" else DecentralizedMpc
    prepared = mpc_class(lab_params, options, clock=time.perf_counter)
    fresh = mpc_class(lab_params, options, clock=time.perf_counter)
    reference = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5), math.radians(20))
    state = formation_equilibrium(lab_params, reference).x.copy()
    state[P_B] += (0.05, -0.03, 0.02)
    elsewhere = dataclasses.replace(reference, payload_position_m=(0.4, 0.1, 1.2))
    prepared.prepare(state, elsewhere)  # A and B do not depend on where the bar is
    yaws = list(LAYOUT.yaw_indices)
    state[yaws] += 0.005  # the next tick's yaws moved, within the tolerance
    plan = prepared.step(state, reference, 0.02)
    assert prepared.last_step_was_prepared
    exact = fresh.step(state, reference, 0.02)
    assert not fresh.last_step_was_prepared
    # Linearized 0.3° away: the same input to well within a thousandth of the range.
    assert np.max(np.abs(plan.u - exact.u) / actuator_range(2)) < 1e-3
    prepared.prepare(state, reference)
    state[LAYOUT.uav_yaw_index(1)] += 0.02  # beyond it: linearized anew, as unprepared
    again, exact = prepared.step(state, reference, 0.04), fresh.step(state, reference, 0.04)
    assert not prepared.last_step_was_prepared
    np.testing.assert_allclose(again.u, exact.u, atol=1e-9)


@pytest.mark.parametrize("controller", ["centralized", "decentralized"])
def test_a_prepared_model_serves_while_the_yaws_stay_within_the_tolerance(
    controller: str, lab_params: FormationParams
) -> None:
    options = settings(controller, prepared_yaw_tolerance_rad=0.01)
    mpc_class = CentralizedMpc if controller == "centralized" else DecentralizedMpc
    mpc = mpc_class(lab_params, options, clock=time.perf_counter)
    fresh = mpc_class(lab_params, options, clock=time.perf_counter)
    reference = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5), math.radians(20))
    state = formation_equilibrium(lab_params, reference).x.copy()
    mpc.prepare(state, reference)
    assert not mpc.last_prepare_kept_models  # nothing to keep yet
    yaws = list(LAYOUT.yaw_indices)
    for tick in range(1, 4):  # a hover: the yaws wander 2 mrad a tick, 6 in all
        state[yaws] += 0.002
        plan = mpc.step(state, reference, 0.02 * tick)
        assert mpc.last_step_was_prepared
        exact = fresh.step(state, reference, 0.02 * tick)
        assert np.max(np.abs(plan.u - exact.u) / actuator_range(2)) < 1e-3
        mpc.prepare(state, reference)
        assert mpc.last_prepare_kept_models
    state[yaws] += 0.01  # beyond the tolerance of the kept model: linearized anew
    mpc.prepare(state, reference)
    assert not mpc.last_prepare_kept_models
    mpc.step(state, reference, 0.1)
    assert mpc.last_step_was_prepared
    state[LAYOUT.uav_yaw_index(1)] += 0.03  # the step's yaws left it: a step of its own
    again, exact = mpc.step(state, reference, 0.12), fresh.step(state, reference, 0.12)
    assert not mpc.last_step_was_prepared
    np.testing.assert_allclose(again.u, exact.u, atol=1e-9)
    mpc.prepare(state, reference)  # and the dropped model is never kept
    assert not mpc.last_prepare_kept_models


def test_a_zero_tolerance_prepares_nothing(lab_params: FormationParams) -> None:
    mpc = CentralizedMpc(
        lab_params, settings("centralized", prepared_yaw_tolerance_rad=0.0), clock=time.perf_counter
    )
    reference = FormationReference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5))
    state = formation_equilibrium(lab_params, reference).x
    mpc.prepare(state, reference)
    mpc.step(state, reference, 0.0)
    assert not mpc.last_step_was_prepared


def test_the_linearization_does_not_depend_on_where_the_formation_is(
    lab_params: FormationParams,
) -> None:
    mpc = CentralizedMpc(lab_params, settings("centralized"), clock=time.perf_counter)
    here = FormationReference((0.0, 0.0, 1.0), 0.7, (0.2, -0.4), math.radians(15))
    there = dataclasses.replace(here, payload_position_m=(1.3, -0.8, 2.1))
    for a, b in zip(
        mpc.linearization(formation_equilibrium(lab_params, here).x, here),
        mpc.linearization(formation_equilibrium(lab_params, there).x, there),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, atol=1e-12)


@pytest.mark.parametrize("params", [None, irregular_params(4)], ids=["lab", "irregular4"])
def test_the_yaws_ahead_follow_the_models_euler_rates(
    params: FormationParams | None, lab_params: FormationParams
) -> None:
    params = params or lab_params
    layout = params.layout
    rng = np.random.default_rng(3)
    reference = FormationReference(
        (0.0, 0.0, 1.0), 0.4, tuple(0.4 - 0.5 * k for k in range(layout.n_vehicles)), 0.35
    )
    eq = formation_equilibrium(params, reference)
    state = eq.x + 0.1 * rng.normal(size=layout.n_states)  # tilted and turning, every body
    yaws = list(layout.yaw_indices)
    rates = np.asarray(FormationModel(params).dynamics(state, eq.u)).ravel()[yaws]
    dt = 0.02
    payload_yaw, uav_yaws = yaws_ahead(state, layout, dt)
    ahead = np.array([payload_yaw, *uav_yaws])
    np.testing.assert_allclose((ahead - state[yaws]) / dt, rates, atol=1e-9)
    assert np.all(np.abs(rates) > 1e-3)  # the rates are not trivially zero
