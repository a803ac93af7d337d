"""The real PX4's sensor samples (sim/sensor_schedule.py): on time in world time, never in
a burst by the wall clock after the world's process stalled."""

from __future__ import annotations

import itertools
import random

import pytest

from sim.sensor_schedule import SensorSchedule

WORLD_STEP_S = 0.002  # the world advances every 2 ms (sim.world)


def sent_samples(steps: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """(world_s, wall_s) of the samples a 250 Hz schedule sends along ``steps``."""
    schedule = SensorSchedule.at_rate(250.0)
    return [(world, wall) for world, wall in steps if schedule.take(world, wall)]


def test_a_world_on_time_gets_every_sample_of_the_rate() -> None:
    steps = [(k * WORLD_STEP_S, 10.0 + k * WORLD_STEP_S) for k in range(500)]
    sent = sent_samples(steps)
    assert len(sent) == 250
    assert {round(b[0] - a[0], 9) for a, b in itertools.pairwise(sent)} == {0.004}


def test_after_a_stall_the_caught_up_samples_are_not_sent_at_once() -> None:
    """16 ms without the world, then it catches up in 1 ms chunks within the same wall
    instant: one sample of the catch-up goes out, the next only most of a period later
    and with the world's newer state."""
    before = [(k * WORLD_STEP_S, k * WORLD_STEP_S) for k in range(50)]  # to 0.098 s
    stall_end_wall_s = 0.098 + 0.016
    catch_up = [(0.098 + k * 0.001, stall_end_wall_s + k * 1e-6) for k in range(1, 17)]
    after = [(0.114 + k * WORLD_STEP_S, stall_end_wall_s + k * WORLD_STEP_S) for k in range(1, 6)]
    sent = sent_samples(before + catch_up + after)
    in_burst = [s for s in sent if stall_end_wall_s <= s[1] < stall_end_wall_s + 0.001]
    assert len(in_burst) == 1
    following = sent[sent.index(in_burst[0]) + 1]
    assert following[1] - in_burst[0][1] >= 0.75 * 0.004
    assert following[0] > 0.114  # the caught-up state, not one from the stall


@pytest.mark.parametrize("seed", range(5))
def test_under_random_stalls_no_two_samples_come_closer_than_three_quarters_of_a_period(
    seed: int,
) -> None:
    rng = random.Random(seed)
    steps, world, wall, stalled_s = [], 0.0, 0.0, 0.0
    for _ in range(5000):
        stall_s = rng.uniform(0.01, 0.05) if rng.random() < 0.02 else 0.0
        stalled_s += stall_s
        wall += stall_s + rng.uniform(0.0015, 0.0025)
        while world < wall - 1e-9:  # the world catches up in 1 ms chunks
            world = min(wall, world + 0.001)
            steps.append((world, wall + rng.uniform(0.0, 2e-5)))
    sent = sent_samples(steps)
    gaps = [b[1] - a[1] for a, b in itertools.pairwise(sent)]
    assert min(gaps) >= 0.75 * 0.004
    assert len(sent) / (wall - stalled_s) > 0.9 * 250  # while the world runs, the rate holds
