"""The body-rate filter: exact on the model's own trajectory, and quieter on noisy rates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.delay import DelayPredictor
from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from controllers.rate_filter import RateCrossover, RateFilter
from geometry.formation import FormationLayout
from geometry.frames import euler_zyx_from_rotation, rotation_from_euler_zyx

TICK_S = 0.02
LAYOUT = FormationLayout(2)  # the lab's
RATES = LAYOUT.uav_rate_indices


def _flown(
    params: FormationParams, ticks: int, weight: float, noise_std: float = 0.0
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The model flown under varying torques, each tick's state (UAV rates with white
    noise of ``noise_std``) filtered before that tick's input is sent, as the flight core
    does; (true states, filtered estimates)."""
    eq = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)))
    predictor = DelayPredictor(params, 0.0)
    rates = RateFilter(predictor, weight)
    rng = np.random.default_rng(3)
    x, states, filtered = eq.x.copy(), [], []
    for k in range(ticks):
        noisy = x.copy()
        noisy[RATES] += noise_std * rng.standard_normal(len(RATES))
        states.append(x)
        filtered.append(rates.filtered(noisy, k * TICK_S))
        u = eq.u.copy()
        roll_pitch = [LAYOUT.torque_slice(i).start + k for i in LAYOUT.vehicles for k in (0, 1)]
        u[roll_pitch] += 0.05 * math.sin(2 * math.pi * 1.5 * k * TICK_S)
        predictor.sent(k * TICK_S, u)
        x = predictor.advance(x, k * TICK_S, (k + 1) * TICK_S)
    return states, filtered


def test_the_models_own_trajectory_passes_unchanged(lab_params: FormationParams) -> None:
    states, filtered = _flown(lab_params, 40, 0.8)
    assert np.abs(np.array(filtered) - np.array(states)).max() < 1e-9
    assert np.abs(states[-1][RATES]).max() > 0.01  # the rates did move


def test_noisy_rates_come_out_quieter(lab_params: FormationParams) -> None:
    """White rate noise through w = 0.7: the filtered error's spread is about
    √((1 − w)/(1 + w)) ≈ 0.42 of the noise's (a first-order recursion on white noise)."""
    noise_std = 0.05
    states, filtered = _flown(lab_params, 300, 0.7, noise_std)
    errors = [f[RATES] - x[RATES] for x, f in zip(states, filtered, strict=True)]
    ratio = float(np.std(errors[20:])) / noise_std
    assert 0.3 < ratio < 0.55


def test_no_weight_passes_the_estimate_and_a_gap_restarts(lab_params: FormationParams) -> None:
    x = formation_equilibrium(lab_params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    predictor = DelayPredictor(lab_params, 0.0)
    predictor.sent(0.0, np.zeros(LAYOUT.n_inputs))
    noisy = x + 0.01
    assert np.array_equal(RateFilter(predictor, 0.0).filtered(noisy, TICK_S), noisy)
    on = RateFilter(predictor, 0.5)
    on.filtered(x, 0.0)
    assert np.array_equal(on.filtered(noisy, 5.0), noisy)  # 5 s later: nothing to blend with


@pytest.mark.parametrize("weight", [-0.1, 1.0, math.nan])
def test_a_weight_outside_zero_to_one_is_refused(
    weight: float, lab_params: FormationParams
) -> None:
    with pytest.raises(ValueError, match="model weight"):
        RateFilter(DelayPredictor(lab_params, 0.0), weight)


def _turning(k: int) -> np.ndarray:
    """A state whose UAVs turn at steady body rates (1: about x, 2: about y and z)."""
    x = np.zeros(LAYOUT.n_states)
    for i, rates in ((1, np.array([0.3, 0.0, 0.0])), (2, np.array([0.0, -0.2, 0.5]))):
        angle = np.linalg.norm(rates) * k * TICK_S
        axis = rates / np.linalg.norm(rates)
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        R = rotation_from_euler_zyx(0.1, -0.05, 3.0) @ (
            np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
        )
        x[LAYOUT.uav_slices(i)[2]] = euler_zyx_from_rotation(R)
        x[LAYOUT.uav_slices(i)[3]] = rates
    return x


def test_the_crossover_passes_steady_rates_and_removes_a_slow_rate_error() -> None:
    """Steady body rates (yaw crossing ±π included) pass unchanged; a constant error on
    the fused rates, which the attitudes do not show, decays with the time constant."""
    crossover = RateCrossover(LAYOUT, 0.05)
    for k in range(10):
        x = _turning(k)
        assert np.allclose(crossover.corrected(x, k * TICK_S), x, atol=1e-9)
    crossover.reset()
    bias = 0.02
    for k in range(30):
        x = _turning(k)
        biased = x.copy()
        biased[RATES] += bias
        out = crossover.corrected(biased, k * TICK_S)
    assert np.abs(out[RATES] - x[RATES]).max() < 1e-3 * bias  # (1 - 0.02/0.07)^29 ≈ 6e-5
    others = [j for j in range(LAYOUT.n_states) if j not in RATES]
    assert np.array_equal(out[others], biased[others])


def test_the_crossover_off_passes_and_a_gap_restarts() -> None:
    x = _turning(0)
    assert np.array_equal(RateCrossover(LAYOUT, 0.0).corrected(x + 0.01, 0.0), x + 0.01)
    crossover = RateCrossover(LAYOUT, 0.05)
    crossover.corrected(_turning(0), 0.0)
    later = _turning(1) + 0.01
    assert np.array_equal(crossover.corrected(later, 5.0), later)  # nothing to difference


@pytest.mark.parametrize("time_constant", [-0.1, math.nan])
def test_a_negative_crossover_is_refused(time_constant: float) -> None:
    with pytest.raises(ValueError, match="time constant"):
        RateCrossover(LAYOUT, time_constant)
