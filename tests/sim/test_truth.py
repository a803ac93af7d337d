"""The simulator's own view of a flight (sim/truth.py), as the real-time world logs it and
``benchmarks.tick`` reads it back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.tick import flight_truths, world_truth
from sim.plant import Plant
from sim.plant_params import CableParams, PayloadBodyParams, PlantParams, UavBodyParams, diagonal
from sim.truth import FlightTruths, TruthStats


def hanging_plant() -> tuple[Plant, tuple[float, ...]]:
    plant = Plant()
    trim = plant.place_hanging((np.array([-0.72, 0.0, 2.0]), np.array([0.76, 0.0, 2.0])), (0, 0))
    return plant, trim.tension_n


def test_a_hanging_bar_counts_its_time_and_its_tension() -> None:
    plant, tensions = hanging_plant()
    truth = TruthStats(bar_rest_z_m=0.02)
    for _ in range(50):
        plant.advance(0.02)
        truth.update(plant, airborne=True)
    assert truth.hanging_s == pytest.approx(0.98, abs=1e-6)  # from the first update on
    assert truth.min_tension_airborne_n == pytest.approx(min(tensions), rel=1e-6)
    assert truth.slack_events == 0
    assert truth.max_tilt_deg < 0.1


def test_nothing_counts_while_the_bar_rests_or_the_mode_is_not_airborne() -> None:
    plant = Plant()
    truth = TruthStats(bar_rest_z_m=float(plant.body("bar").position_m[2]))
    plant.advance(0.5)
    truth.update(plant, airborne=True)
    hanging, _ = hanging_plant()
    truth.update(hanging, airborne=False)
    assert truth.hanging_s == 0.0 and truth.min_tension_airborne_n == float("inf")
    assert truth.describe() == "truth: the bar has not hung yet"
    assert world_truth([truth.describe()]) == {}


def test_the_benchmark_reads_back_what_the_world_logs() -> None:
    plant, tensions = hanging_plant()
    truth = TruthStats(bar_rest_z_m=0.02)
    for _ in range(3):
        plant.advance(0.1)
        truth.update(plant, airborne=True)
    line = f"03:12:00 uavbar-world sim.world INFO: {truth.describe()}"
    figures = world_truth(["unrelated", line])
    assert figures["bar_hanging_s"] == pytest.approx(0.2, abs=0.05)
    assert figures["min_tension_hanging_n"] == pytest.approx(min(tensions), abs=0.005)
    assert figures["slack_events"] == 0
    for name, descent in truth.descent_by_body_mps.items():
        assert figures[f"max_descent_{name}_mps"] == pytest.approx(descent, abs=0.005)
    assert figures["max_descent_mps"] == pytest.approx(
        max(truth.descent_by_body_mps.values()), abs=0.005
    )


def test_three_uavs_and_a_plate_are_counted_like_the_bar() -> None:
    """The payload named "payload" hangs from three UAVs: its hanging time, every cable's
    tension, every UAV's tilt and every body's descent are counted."""
    r = 1.0 / math.sqrt(3.0)
    corners = tuple((r * math.cos(t), r * math.sin(t), 0.0) for t in (0.0, 2.1, 4.2))
    plate = PayloadBodyParams(0.6, diagonal((0.025, 0.025, 0.05)), corners, corners)
    params = PlantParams(uavs=(UavBodyParams(),) * 3, cables=(CableParams(),) * 3, payload=plate)
    plant = Plant(params)
    positions = [np.array(c) + np.array([0.0, 0.0, 2.5]) for c in corners]
    trim = plant.place_hanging(positions)
    truth = TruthStats(0.01, bodies=("payload", *plant.layout.uav_names))
    for _ in range(20):
        plant.advance(0.02)
        truth.update(plant, airborne=True)
    assert truth.hanging_s == pytest.approx(0.38, abs=1e-6)
    assert truth.min_tension_airborne_n == pytest.approx(min(trim.tension_n), rel=1e-6)
    assert truth.slack_events == 0 and truth.max_tilt_deg < 0.1
    assert set(truth.descent_by_body_mps) == {"payload", "uav1", "uav2", "uav3"}
    assert truth.describe().startswith("truth: payload hanging 0.4 s")
    figures = world_truth([truth.describe()])
    assert figures["payload_hanging_s"] == pytest.approx(0.4, abs=0.05)
    for name, descent in truth.descent_by_body_mps.items():
        assert figures[f"max_descent_{name}_mps"] == pytest.approx(descent, abs=0.005)


def test_each_flight_has_its_own_truth_from_lift_off_to_touch_down() -> None:
    """A flight starts when a UAV rises above the descent floor and ends when every UAV
    is below it: its line carries its own figures, and the benchmark reads them back."""
    truths = FlightTruths(payload_rest_z_m=0.02)
    resting = Plant()
    assert truths.update(resting) is None and truths.current is None
    hanging, _ = hanging_plant()
    for _ in range(3):
        hanging.advance(0.1)
        assert truths.update(hanging) is None
    assert truths.current is not None and truths.current.hanging_s > 0.0
    line = truths.update(resting)
    assert line is not None and line.startswith("truth of flight 1: bar hanging")
    assert truths.current is None and truths.flights_ended == 1
    assert truths.update(resting) is None
    truths.update(hanging)
    second = truths.update(resting)
    assert second is not None and second.startswith("truth of flight 2: ")
    figures = flight_truths(["unrelated", f"sim.world INFO: {line}", f"INFO: {second}"])
    assert len(figures) == 2
    assert figures[0]["bar_hanging_s"] == pytest.approx(0.2, abs=0.05)
    assert world_truth([line, second]) == {}  # neither is the whole run's line
