"""The mocap phase lock: deadlines settle just after frame arrivals, and only then."""

from __future__ import annotations

import math

import numpy as np
import pytest

from supervisor.phase_lock import MocapPhaseLock
from supervisor.scheduler import DeadlineTicker

TICK_S = 0.02


def fly_ticks(
    frame_period_s: float, phase_s: float, jitter_s: float, ticks: int
) -> tuple[MocapPhaseLock, list[float], list[float]]:
    """Ticks on trimmed deadlines over a frame stream; (lock, frame ages at tick, steps)."""
    rng = np.random.default_rng(1)
    arrivals = phase_s + frame_period_s * np.arange(int(ticks * TICK_S / frame_period_s) + 2)
    arrivals = arrivals + rng.normal(0.0, jitter_s, arrivals.size)
    lock = MocapPhaseLock(TICK_S)
    deadline, seen, ages, steps = 0.0, 0, [], []
    for _ in range(ticks):
        arrived = int(np.searchsorted(arrivals, deadline, side="right"))
        lock.observe(arrivals[seen:arrived])
        if arrived:
            ages.append(deadline - arrivals[arrived - 1])
        seen = arrived
        step = lock.correction(deadline + TICK_S)
        steps.append(step)
        deadline += TICK_S + step
    return lock, ages, steps


def test_deadlines_settle_just_after_the_arrivals() -> None:
    lock, ages, steps = fly_ticks(0.01, 0.0037, 50e-6, 200)
    settled = np.array(ages[-100:])
    assert lock.frame_period_s == pytest.approx(0.01, rel=1e-3)
    assert np.all(settled > 0.0)  # the frame has arrived when its tick starts ...
    assert np.median(settled) < 0.7e-3  # ... and waited well under a millisecond
    assert max(abs(s) for s in steps) <= lock.max_step_s + 1e-12


def test_without_the_lock_a_frame_waits_up_to_a_period() -> None:
    _, ages, _ = fly_ticks(0.01, 0.0037, 50e-6, 20)  # before it has seen enough frames
    assert ages[5] == pytest.approx(0.0063, abs=3e-4)


def test_a_frame_rate_that_does_not_divide_the_tick_rate_moves_nothing() -> None:
    _, _, steps = fly_ticks(1.0 / 60.0, 0.003, 50e-6, 100)
    assert all(step == 0.0 for step in steps)


def test_too_few_or_unusable_frames_move_nothing() -> None:
    lock = MocapPhaseLock(TICK_S)
    lock.observe([0.001, 0.011, math.nan, math.inf])
    assert lock.correction(0.02) == 0.0
    lock.observe([0.5] * 30)  # a burst with no spacing: no period to estimate
    assert lock.correction(0.52) == 0.0


def test_the_ticker_moves_its_following_deadlines() -> None:
    clock = [10.0]
    ticker = DeadlineTicker(TICK_S, start_s=10.0, clock=lambda: clock[0])
    assert ticker.next_deadline_s == 10.0
    ticker.shift(0.003)
    assert ticker.next_deadline_s == pytest.approx(10.003)
    ticker.shift(math.nan)
    assert ticker.next_deadline_s == pytest.approx(10.003)
