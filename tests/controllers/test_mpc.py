"""The MPCs: LQR oracle, back-end agreement, fallbacks, and closed loops on the model."""

from __future__ import annotations

import dataclasses
import itertools
import math
import time

import numpy as np
import pytest

from controllers.equilibria import Reference, bar_equilibrium
from controllers.model import BarSystemModel
from controllers.mpc import (
    YAW_LEAD_FADE_RAD,
    CentralizedMpc,
    DecentralizedMpc,
    PlanStatus,
    agent_state,
    led_reference,
    yaws_ahead,
)
from controllers.params import RECOMMENDED_LEAD, BarSystemParams, MpcSettings, ReferenceLead
from supervisor.app.config import load_config
from tests.conftest import CONFIGS
from tests.controllers.closed_loop import Run, fly

CONFIG = load_config(CONFIGS / "kth_sml.toml")
BACKENDS = ["osqp", "daqp", "hpipm"]


def settings(controller: str, **changes: object) -> MpcSettings:
    # The late-solve budget is a real-time concern; these tests check the control law.
    options: dict[str, object] = {"late_after_s": 10.0, **changes}
    return dataclasses.replace(CONFIG.mpc.settings(controller), **options)  # type: ignore[arg-type]


def actuator_range(n_uavs: int) -> np.ndarray:
    lim = CONFIG.mpc.settings("centralized").limits
    return np.tile([lim.thrust_max_n - lim.thrust_min_n] + [2 * lim.torque_max_nm] * 3, n_uavs)


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
    backend: str, lab_params: BarSystemParams
) -> None:
    mpc = CentralizedMpc(lab_params, settings("centralized"), backend, clock=time.perf_counter)
    reference = Reference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5), math.radians(20))
    eq = bar_equilibrium(lab_params, reference)
    state = eq.x.copy()
    state[0:3] += (0.02, -0.01, 0.01)  # small enough that no bound is active
    state[8] += 0.02
    plan = mpc.step(state, reference, 0.0)
    assert plan.status is PlanStatus.OPTIMAL
    A, B = mpc.linearization(state, reference)
    w = mpc.settings.weights
    K = riccati_first_gain(
        A, B, np.array(w.q_diag), np.array(w.r_diag), w.terminal_scale, mpc.settings.horizon
    )
    expected = eq.u - K @ (state - eq.x)
    lim = mpc.settings.limits
    assert np.all(np.abs(expected[[1, 2, 3, 5, 6, 7]]) < lim.torque_max_nm)  # truly unconstrained
    np.testing.assert_array_less(np.abs(plan.u - expected), 1e-4 * actuator_range(2))
    assert np.abs(plan.u - eq.u).max() > 1e-3  # and the test is not comparing u_eq with u_eq


def saturating_sequence(params: BarSystemParams) -> list[tuple[np.ndarray, Reference]]:
    """States along a hard manoeuvre: large offsets saturate the torques."""
    rng = np.random.default_rng(11)
    out = []
    for k in range(12):
        ref = Reference((0.0, 0.0, 1.0), 0.1 * k, (0.1 * k, -0.1 * k), math.radians(5 * (k % 4)))
        x = bar_equilibrium(params, ref).x
        x = x + rng.normal(0.0, 0.1, 36) * (1 + (k % 3))
        out.append((x, ref))
    return out


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_backends_agree_on_the_same_qps(controller_cls: type, lab_params: BarSystemParams) -> None:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    controllers = {
        b: controller_cls(lab_params, settings(name), b, clock=time.perf_counter) for b in BACKENDS
    }
    saturated = 0
    lim = CONFIG.mpc.settings(name).limits
    for k, (x, ref) in enumerate(saturating_sequence(lab_params)):
        plans = {b: c.step(x, ref, 0.02 * k) for b, c in controllers.items()}
        assert all(p.status is PlanStatus.OPTIMAL for p in plans.values())
        reference = plans["daqp"].u
        for plan in plans.values():
            np.testing.assert_array_less(np.abs(plan.u - reference), 1e-4 * actuator_range(2))
        saturated += int(
            np.any(np.isclose(np.abs(reference[[1, 2, 3, 5, 6, 7]]), lim.torque_max_nm))
        )
    assert saturated >= 3  # the sequence really exercises the bounds


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_a_formation_moving_with_its_reference_needs_no_correction(
    controller_cls: type, lab_params: BarSystemParams
) -> None:
    """x_eq + v t solves the model with u_eq, so a system exactly on a reference that moves
    at constant velocity is left alone; the same state under a reference at rest is braked."""
    mpc = controller_cls(
        lab_params, settings(controller_cls.__name__.lower()[:-3]), clock=time.perf_counter
    )
    moving = Reference((0.2, 0.1, 1.0), 0.4, (0.4, 0.9), math.radians(15), (0.3, -0.1, 0.05))
    eq = bar_equilibrium(lab_params, moving)
    np.testing.assert_allclose(eq.x[3:6], moving.velocity_mps)
    np.testing.assert_allclose(eq.x[15:18], moving.velocity_mps)
    plan = mpc.step(eq.x, moving, 0.0)
    assert plan.status is PlanStatus.OPTIMAL
    np.testing.assert_allclose(plan.u, eq.u, atol=1e-6 * actuator_range(2).max())
    mpc.reset()
    braking = mpc.step(eq.x, moving.at_rest(), 0.0)
    assert np.max(np.abs(braking.u - eq.u)) > 1e-2


def test_a_moving_equilibrium_is_a_steady_translation(lab_params: BarSystemParams) -> None:
    """f(x_eq, u_eq) = (v, 0, 0, 0, v, 0, …): positions move at v, nothing accelerates."""
    model = BarSystemModel(lab_params)
    moving = Reference((0.0, 0.0, 1.0), 1.0, (0.2, -0.4), math.radians(30), (0.4, 0.2, -0.1))
    eq = bar_equilibrium(lab_params, moving)
    x_dot = np.asarray(model.dynamics(eq.x, eq.u)).ravel()
    expected = np.zeros(36)
    for offset in (0, 12, 24):
        expected[offset : offset + 3] = moving.velocity_mps
    np.testing.assert_allclose(x_dot, expected, atol=1e-9)


@pytest.mark.parametrize("controller_cls", [CentralizedMpc, DecentralizedMpc])
def test_bad_input_falls_back_to_the_shifted_plan(
    controller_cls: type, lab_params: BarSystemParams
) -> None:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    mpc = controller_cls(lab_params, settings(name), "daqp", clock=time.perf_counter)
    reference = Reference((0.0, 0.0, 1.0))
    state = bar_equilibrium(lab_params, reference).x
    state[0] += 0.2
    first = mpc.step(state, reference, 0.0)
    assert first.status is PlanStatus.OPTIMAL
    broken = state.copy()
    broken[5] = math.nan
    second = mpc.step(broken, reference, 0.02)
    assert second.status is PlanStatus.SHIFTED_BAD_STATE
    np.testing.assert_array_equal(second.u, first.u_pred[1])
    impossible = Reference((0.0, 0.0, 1.0), theta_l_rad=2.0)
    third = mpc.step(state, impossible, 0.04)
    assert third.status is PlanStatus.SHIFTED_BAD_STATE and "theta_l" in (third.error or "")
    np.testing.assert_array_equal(third.u, first.u_pred[2])
    assert mpc.step(state, reference, 0.06).status is PlanStatus.OPTIMAL


def test_a_late_solve_uses_the_shifted_plan(lab_params: BarSystemParams) -> None:
    one_second_per_reading = itertools.count(0.0, 1.0).__next__
    mpc = CentralizedMpc(
        lab_params, settings("centralized", late_after_s=0.5), "daqp", clock=one_second_per_reading
    )
    reference = Reference((0.0, 0.0, 1.0))
    state = bar_equilibrium(lab_params, reference).x
    first = mpc.step(state, reference, 0.0)
    assert first.status is PlanStatus.EQUILIBRIUM  # nothing to shift yet: hold u_eq
    np.testing.assert_allclose(first.u, bar_equilibrium(lab_params, reference).u)
    assert mpc.step(state, reference, 0.02).status is PlanStatus.SHIFTED_LATE


def test_decentralized_agent_sees_its_bar_end(lab_params: BarSystemParams) -> None:
    eq = bar_equilibrium(lab_params, Reference((0.5, 0.2, 1.0), 0.8, (0.1, 0.2), math.radians(30)))
    for i in (1, 2):
        np.testing.assert_allclose(
            agent_state(eq.x, lab_params, i), eq.payload_state(i), atol=1e-12
        )


def first_time_inside_for_good(
    run: Run, reference: Reference, tol_m: float, tol_deg: float
) -> float:
    """The earliest time from which the bar stays within the tolerances to the end."""
    error_m = np.linalg.norm(run.states[:, 0:3] - np.array(reference.bar_position_m), axis=1)
    error_deg = np.degrees(np.abs(run.states[:, 8] - reference.bar_yaw_rad))
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
    params: BarSystemParams,
    duration_s: float,
    lead: ReferenceLead | None = None,
) -> tuple[Run, Reference]:
    name = "centralized" if controller_cls is CentralizedMpc else "decentralized"
    options = settings(name, reference_lead=lead or ReferenceLead())
    mpc = controller_cls(params, options, "daqp", clock=time.perf_counter)
    reference = Reference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), 0.0)
    x0 = bar_equilibrium(params, Reference((0.3, 0.0, 1.0), math.radians(20), (0.0, 0.0))).x
    return fly(mpc, BarSystemModel(params), x0, reference, duration_s), reference


@pytest.mark.slow
@pytest.mark.parametrize("controller_cls, lead", CLOSED_LOOP_CASES)
def test_closed_loop_reaches_the_setpoint(
    controller_cls: type, lead: ReferenceLead, lab_params: BarSystemParams
) -> None:
    """From a 0.3 m bar offset and a 20° bar-yaw error: within 2 cm and 2° by 8 s, for good
    (checked over 10 s), never leaving the input set U."""
    run, reference = fly_offset_case(controller_cls, lab_params, 10.0, lead)
    assert first_time_inside_for_good(run, reference, 0.02, 2.0) <= 8.0
    inputs = np.array([p.u for p in run.plans])
    lim = CONFIG.mpc.settings("centralized").limits
    assert (
        inputs[:, [0, 4]].min() >= lim.thrust_min_n and inputs[:, [0, 4]].max() <= lim.thrust_max_n
    )
    assert np.abs(inputs[:, [1, 2, 3, 5, 6, 7]]).max() <= lim.torque_max_nm + 1e-9
    assert all(p.status is PlanStatus.OPTIMAL for p in run.plans)


@pytest.mark.slow
def test_decentralized_closed_loop_stays_bounded(lab_params: BarSystemParams) -> None:
    """What the decentralized controller does reach: the bar's error shrinks from 0.3 m and
    20° to a swing of a few centimetres and degrees."""
    run, reference = fly_offset_case(DecentralizedMpc, lab_params, 10.0)
    assert first_time_inside_for_good(run, reference, 0.06, 3.0) <= 8.0


def test_the_reference_lead_moves_the_setpoint_along_the_bars_motion_errors(
    lab_params: BarSystemParams,
) -> None:
    reference = Reference((0.1, 0.2, 1.0), 0.4, (0.4, 0.4), 0.0, (0.2, 0.0, 0.0), (0.1, 0.1, 0.1))
    state = bar_equilibrium(lab_params, reference).x
    assert led_reference(reference, state, LEAD) == reference  # moving as asked: no lead
    state[3:6] += (0.1, -0.2, 0.05)
    state[11] += 0.3
    led = led_reference(reference, state, LEAD)
    np.testing.assert_allclose(
        led.bar_position_m, np.add(reference.bar_position_m, 0.6 * np.array([0.1, -0.2, 0.05]))
    )
    assert led.bar_yaw_rad == pytest.approx(0.4 + 0.2 * 0.3)
    assert led.velocity_mps == reference.velocity_mps
    assert led.yaw_rates_radps == reference.yaw_rates_radps
    # The yaw lead fades out with θ_l; no lead, or a state with NaN, leaves the reference.
    half = dataclasses.replace(reference, theta_l_rad=YAW_LEAD_FADE_RAD / 2)
    assert led_reference(half, state, LEAD).bar_yaw_rad == pytest.approx(0.4 + 0.1 * 0.3)
    tilted = dataclasses.replace(reference, theta_l_rad=YAW_LEAD_FADE_RAD)
    assert led_reference(tilted, state, LEAD).bar_yaw_rad == pytest.approx(0.4)
    assert led_reference(reference, state, ReferenceLead()) is reference
    state[5] = math.nan
    assert led_reference(reference, state, LEAD) is reference


def test_a_turning_reference_is_kinematically_consistent(lab_params: BarSystemParams) -> None:
    """The rates a turning, moving reference carries are the time derivative of where its
    equilibrium goes: positions by the velocities, the bar's yaw by ω_b, the UAVs' yaws by
    their body rates."""
    rates = (0.3, -0.4, 0.5)
    velocity = (0.2, -0.1, 0.05)
    reference = Reference((0.1, 0.2, 1.0), 0.4, (0.7, -0.2), math.radians(25), velocity, rates)
    h = 1e-6
    later = Reference(
        tuple(p + v * h for p, v in zip(reference.bar_position_m, velocity, strict=True)),  # type: ignore[arg-type]
        reference.bar_yaw_rad + rates[0] * h,
        (reference.uav_yaw_rad[0] + rates[1] * h, reference.uav_yaw_rad[1] + rates[2] * h),
        reference.theta_l_rad,
    )
    x, x_later = bar_equilibrium(lab_params, reference).x, bar_equilibrium(lab_params, later).x
    derivative = (x_later - x) / h
    for offset in (0, 12, 24):
        np.testing.assert_allclose(
            derivative[offset : offset + 3], x[offset + 3 : offset + 6], atol=1e-5
        )
    assert derivative[8] == pytest.approx(x[11], abs=1e-5)  # bar: ψ̇ = ω_z
    for offset in (12, 24):
        phi, theta = x[offset + 6], x[offset + 7]
        q, r = x[offset + 10 : offset + 12]
        psi_dot = (q * math.sin(phi) + r * math.cos(phi)) / math.cos(theta)  # eq. (3)
        assert derivative[offset + 8] == pytest.approx(psi_dot, abs=1e-5)


@pytest.mark.parametrize("controller", ["centralized", "decentralized"])
def test_a_prepared_model_is_used_when_the_yaws_stay_within_the_tolerance(
    controller: str, lab_params: BarSystemParams
) -> None:
    options = settings(controller, prepared_yaw_tolerance_rad=0.01)
    mpc_class = CentralizedMpc if controller == "centralized" else DecentralizedMpc
    prepared = mpc_class(lab_params, options, clock=time.perf_counter)
    fresh = mpc_class(lab_params, options, clock=time.perf_counter)
    reference = Reference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5), math.radians(20))
    state = bar_equilibrium(lab_params, reference).x.copy()
    state[0:3] += (0.05, -0.03, 0.02)
    elsewhere = dataclasses.replace(reference, bar_position_m=(0.4, 0.1, 1.2))
    prepared.prepare(state, elsewhere)  # A and B do not depend on where the bar is
    state[[8, 20, 32]] += 0.005  # the next tick's yaws moved, within the tolerance
    plan = prepared.step(state, reference, 0.02)
    assert prepared.last_step_was_prepared
    exact = fresh.step(state, reference, 0.02)
    assert not fresh.last_step_was_prepared
    # Linearized 0.3° away: the same input to well within a thousandth of the range.
    assert np.max(np.abs(plan.u - exact.u) / actuator_range(2)) < 1e-3
    prepared.prepare(state, reference)
    state[20] += 0.02  # beyond it: linearized anew, exactly as without preparation
    again, exact = prepared.step(state, reference, 0.04), fresh.step(state, reference, 0.04)
    assert not prepared.last_step_was_prepared
    np.testing.assert_allclose(again.u, exact.u, atol=1e-9)


def test_a_zero_tolerance_prepares_nothing(lab_params: BarSystemParams) -> None:
    mpc = CentralizedMpc(
        lab_params, settings("centralized", prepared_yaw_tolerance_rad=0.0), clock=time.perf_counter
    )
    reference = Reference((0.0, 0.0, 1.0), 0.3, (0.3, 0.5))
    state = bar_equilibrium(lab_params, reference).x
    mpc.prepare(state, reference)
    mpc.step(state, reference, 0.0)
    assert not mpc.last_step_was_prepared


def test_the_linearization_does_not_depend_on_where_the_formation_is(
    lab_params: BarSystemParams,
) -> None:
    mpc = CentralizedMpc(lab_params, settings("centralized"), clock=time.perf_counter)
    here = Reference((0.0, 0.0, 1.0), 0.7, (0.2, -0.4), math.radians(15))
    there = dataclasses.replace(here, bar_position_m=(1.3, -0.8, 2.1))
    for a, b in zip(
        mpc.linearization(bar_equilibrium(lab_params, here).x, here),
        mpc.linearization(bar_equilibrium(lab_params, there).x, there),
        strict=True,
    ):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_the_yaws_ahead_follow_the_models_euler_rates(lab_params: BarSystemParams) -> None:
    rng = np.random.default_rng(3)
    reference = Reference((0.0, 0.0, 1.0), 0.4, (0.4, -0.6), math.radians(20))
    eq = bar_equilibrium(lab_params, reference)
    state = eq.x + 0.1 * rng.normal(size=36)  # tilted and turning, every body
    rates = np.asarray(BarSystemModel(lab_params).dynamics(state, eq.u)).ravel()[[8, 20, 32]]
    dt = 0.02
    bar, (uav_1, uav_2) = yaws_ahead(state, dt)
    ahead = np.array([bar, uav_1, uav_2])
    np.testing.assert_allclose((ahead - state[[8, 20, 32]]) / dt, rates, atol=1e-9)
    assert np.all(np.abs(rates) > 1e-3)  # the rates are not trivially zero
