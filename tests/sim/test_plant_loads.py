"""External loads on the plant (a steady push, a gust): checked by Newton's laws and the
work–energy theorem, not by snapshots."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sim.loads import ExternalLoad
from sim.plant import BODY_NAMES, Plant
from sim.plant_params import CableParams, PayloadBodyParams, PlantParams, UavBodyParams

UNDAMPED = PlantParams(cables=(CableParams(damping_n_s_per_m=0.0),) * 2)
# Zero gravity, no ground, cables too long to tighten: three free bodies at rest.
FREE = dataclasses.replace(UNDAMPED, gravity_mps2=0.0, cables=(CableParams(length_m=5.0),) * 2)


def masses(params: PlantParams) -> dict[str, float]:
    return {
        "uav1": params.uavs[0].mass_kg,
        "uav2": params.uavs[1].mass_kg,
        "bar": params.bar.mass_kg,
    }


def momentum(plant: Plant) -> np.ndarray:
    m = masses(plant.params)
    total: np.ndarray = sum(m[n] * plant.body(n).velocity_mps for n in BODY_NAMES)  # type: ignore[assignment]
    return total


def test_a_steady_push_changes_momentum_by_its_impulse_and_nothing_else() -> None:
    """F on the bar from 0.1005 s (between two steps) for 0.5 s: m Δv = F T exactly, the
    bar moves ½ a T² then coasts at a T; the other bodies never move."""
    plant = Plant(FREE, ground=False)
    start = {n: plant.body(n).position_m for n in BODY_NAMES}
    force = np.array([1.5, -0.4, 0.8])
    plant.add_load(ExternalLoad("bar", (1.5, -0.4, 0.8), start_s=0.1005, duration_s=0.5))
    plant.advance(0.05)
    assert np.array_equal(plant.body("bar").velocity_mps, np.zeros(3))  # not yet
    plant.advance(1.0)
    m = FREE.bar.mass_kg
    bar = plant.body("bar")
    assert all(plant.cables().slack)
    # The load is applied on whole steps: 0.1005 → the step from 0.101 s, 500 steps.
    np.testing.assert_allclose(m * bar.velocity_mps, force * 0.5, rtol=1e-12)
    a = force / m
    coast = plant.time_s - (0.101 + 0.5)
    expected = start["bar"] + 0.5 * a * 0.5**2 + a * 0.5 * coast
    np.testing.assert_allclose(bar.position_m, expected, rtol=1e-9, atol=1e-12)
    for other in ("uav1", "uav2"):
        np.testing.assert_array_equal(plant.body(other).position_m, start[other])
    assert plant.energy().kinetic_j == pytest.approx(float(force @ force) * 0.25 / (2 * m), 1e-12)


def test_a_world_torque_changes_angular_momentum_by_its_impulse() -> None:
    """τ (world frame) on UAV 1 for 0.3 s: its world angular momentum R J ω grows by τ T,
    whatever the body turned meanwhile (Euler's law in the world frame)."""
    plant = Plant(FREE, ground=False)
    torque = np.array([0.02, -0.05, 0.03])
    plant.add_load(ExternalLoad("uav1", (0.0, 0.0, 0.0), (0.02, -0.05, 0.03), 0.0, 0.3))
    plant.advance(0.6)
    truth = plant.body("uav1")
    J = np.array(FREE.uavs[0].inertia_kgm2, dtype=float)
    np.testing.assert_allclose(truth.rotation @ J @ truth.body_rates_radps, torque * 0.3, rtol=1e-7)
    assert np.linalg.norm(truth.body_rates_radps) > 0.1  # it did turn
    np.testing.assert_array_equal(truth.velocity_mps, np.zeros(3))


def test_a_gust_s_impulse_is_half_the_steady_one() -> None:
    plant = Plant(FREE, ground=False)
    plant.add_load(
        ExternalLoad("uav2", (0.0, 2.0, 0.0), start_s=0.0, duration_s=0.4, profile="gust")
    )
    force, _ = plant.external_load("uav2", 0.2)
    np.testing.assert_allclose(force, [0.0, 2.0, 0.0])  # the peak, mid-gust
    assert plant.external_load("uav2", 0.0)[0][1] == 0.0
    plant.advance(0.5)
    np.testing.assert_allclose(momentum(plant), [0.0, 2.0 * 0.4 / 2, 0.0], rtol=1e-5)


def test_a_push_on_a_uav_pulls_the_bar_and_the_work_is_the_energy_gained() -> None:
    """Zero gravity, undamped elastic cables taut from the start: a steady push
    on UAV 1 away from the bar stretches cable 1 and drags the bar and UAV 2 along. The
    cables are internal: the system's momentum grows by F T alone; the energy (kinetic +
    cable springs) by the work F · Δp₁ of the push."""
    params = dataclasses.replace(UNDAMPED, gravity_mps2=0.0)
    plant = Plant(params, ground=False)
    hanging = Plant(UNDAMPED)  # a taut pose to start from: hanging under gravity
    hanging.place_hanging(
        (np.array([-params.bar.d1_m, 0.0, 2.0]), np.array([params.bar.d2_m, 0.0, 2.0]))
    )
    x = hanging.get_state()
    x[39:47] = 0.0  # no rotor thrust in this test: the push alone
    plant.set_state(x)
    before_p1 = plant.body("uav1").position_m
    before = plant.energy()
    force = np.array([0.0, 0.0, 6.0])
    plant.add_load(ExternalLoad("uav1", (0.0, 0.0, 6.0), start_s=0.0, duration_s=0.8))
    plant.advance(0.8)
    assert not plant.cables().slack[0]
    after = plant.energy()
    work = float(force @ (plant.body("uav1").position_m - before_p1))
    gained = (after.kinetic_j + after.cable_spring_j) - (before.kinetic_j + before.cable_spring_j)
    assert work > 0.1 and gained == pytest.approx(work, rel=1e-4)
    np.testing.assert_allclose(momentum(plant), force * 0.8, rtol=1e-9, atol=1e-9)
    assert np.linalg.norm(plant.body("bar").velocity_mps) > 0.1  # the bar was pulled


def test_a_push_on_a_plate_moves_it_and_nothing_else() -> None:
    """Three UAVs and a plate in zero gravity, cables too long to tighten: a push on the
    payload for 0.2 s gives it the momentum F T and leaves the UAVs still; a world torque
    on it gives it the angular momentum τ T."""
    corners = tuple((0.5 * math.cos(t), 0.5 * math.sin(t), 0.0) for t in (0.0, 2.1, 4.2))
    J = ((0.015, 0.001, 0.0), (0.001, 0.016, 0.0), (0.0, 0.0, 0.03))
    plate = PayloadBodyParams(0.6, J, corners, corners)
    params = PlantParams(
        uavs=(UavBodyParams(),) * 3,
        cables=(CableParams(length_m=5.0),) * 3,
        gravity_mps2=0.0,
        payload=plate,
    )
    plant = Plant(params, ground=False)
    start = {n: plant.body(n).position_m for n in plant.layout.body_names}
    plant.add_load(ExternalLoad("payload", (0.3, -0.6, 0.9), (0.01, 0.0, -0.02), 0.0, 0.2))
    plant.advance(0.5)
    payload = plant.body("payload")
    assert all(plant.cables().slack)
    np.testing.assert_allclose(0.6 * payload.velocity_mps, [0.06, -0.12, 0.18], rtol=1e-12)
    np.testing.assert_allclose(
        payload.rotation @ np.array(J) @ payload.body_rates_radps,
        [0.002, 0.0, -0.004],
        rtol=1e-7,
        atol=1e-12,
    )
    for name in plant.layout.uav_names:
        np.testing.assert_array_equal(plant.body(name).position_m, start[name])


def test_bad_loads_are_refused() -> None:
    with pytest.raises(ValueError, match="body"):
        ExternalLoad("uav9", (1.0, 0.0, 0.0))
    for absent in ("uav3", "payload"):
        with pytest.raises(ValueError, match="unknown body"):
            Plant().add_load(ExternalLoad(absent, (1.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="gust needs a duration_s"):
        ExternalLoad("bar", (1.0, 0.0, 0.0), profile="gust")
    with pytest.raises(ValueError, match="finite"):
        ExternalLoad("bar", (float("nan"), 0.0, 0.0))
    with pytest.raises(ValueError, match="positive"):
        ExternalLoad("bar", (1.0, 0.0, 0.0), duration_s=0.0)
