"""The mocap phase lock: deadlines settle just after frame arrivals, and only then."""

from __future__ import annotations

import math

import numpy as np
import pytest

from supervisor.runtime.phase_lock import MocapPhaseLock
from supervisor.runtime.scheduler import DeadlineTicker

TICK_S = 0.02


def fly_ticks(
    frame_period_s: float, phase_s: float, jitter_s: float, ticks: int
) -> tuple[MocapPhaseLock, list[float], list[float]]:
    """Ticks over a frame stream as the ticker runs them — at the first arrival inside the
    trigger window, else at the deadline — on deadlines the lock trims.
    Returns (lock, the newest frame's age at each tick start, the steps)."""
    rng = np.random.default_rng(1)
    arrivals = phase_s + frame_period_s * np.arange(int(ticks * TICK_S / frame_period_s) + 2)
    arrivals = arrivals + rng.normal(0.0, jitter_s, arrivals.size)
    lock = MocapPhaseLock(TICK_S)
    deadline, seen, ages, steps = 0.0, 0, [], []
    for _ in range(ticks):
        window = min(lock.trigger_window_s, 0.5 * TICK_S)
        inside = arrivals[(arrivals >= deadline - window) & (arrivals <= deadline)]
        start = float(inside.min()) if window > 0.0 and inside.size else deadline
        arrived = int(np.searchsorted(arrivals, start, side="right"))
        lock.observe((k, float(arrivals[k])) for k in range(seen, arrived))
        if arrived:
            ages.append(start - arrivals[arrived - 1])
        seen = arrived
        step = lock.correction(deadline + TICK_S)
        steps.append(step)
        deadline += TICK_S + step
    return lock, ages, steps


def test_ticks_settle_on_the_arrivals() -> None:
    lock, ages, steps = fly_ticks(0.01, 0.0037, 50e-6, 200)
    settled = np.array(ages[-100:])
    assert lock.frame_period_s == pytest.approx(0.01, rel=1e-3)
    assert np.all(settled == 0.0)  # every tick starts as its frame arrives
    assert max(abs(s) for s in steps) <= lock.max_step_s + 1e-12


def test_a_late_frame_is_waited_for_up_to_half_a_frame_period() -> None:
    lock, ages, _ = fly_ticks(0.01, 0.0037, 1.5e-3, 300)  # arrivals ±4.5 ms (3σ)
    settled = np.array(ages[-150:])
    assert lock.locked
    assert np.all(settled < 0.005)  # the tick's own frame, never the one before it
    assert np.median(settled) == 0.0


def test_without_the_lock_a_frame_waits_up_to_a_period() -> None:
    _, ages, _ = fly_ticks(0.01, 0.0037, 50e-6, 20)  # before it has seen enough frames
    assert ages[5] == pytest.approx(0.0063, abs=3e-4)


def test_a_frame_rate_that_does_not_divide_the_tick_rate_moves_nothing() -> None:
    _, _, steps = fly_ticks(1.0 / 60.0, 0.003, 50e-6, 100)
    assert all(step == 0.0 for step in steps)


def test_too_few_or_unusable_frames_move_nothing() -> None:
    lock = MocapPhaseLock(TICK_S)
    lock.observe([(1, 0.001), (2, 0.011), (3, math.nan), (4, math.inf)])
    assert lock.correction(0.02) == 0.0
    lock.observe((n, 0.5) for n in range(5, 35))  # a burst with no spacing: no period
    assert lock.correction(0.52) == 0.0 and not lock.locked


def test_a_restarted_frame_count_starts_a_new_record() -> None:
    lock = MocapPhaseLock(TICK_S)
    lock.observe((n, 0.01 * n) for n in range(100, 130))
    lock.correction(0.3)
    assert lock.locked
    lock.observe((n, 0.3 + 0.01 * n) for n in range(5))  # QTM restarted: too few so far
    assert lock.correction(0.32) == 0.0 and not lock.locked


def test_dropped_frames_and_heavy_jitter_keep_the_period_and_phase() -> None:
    rng = np.random.default_rng(2)
    numbers = np.array([n for n in range(200) if rng.random() > 0.2])  # a fifth dropped
    arrivals = 0.0037 + 0.01 * numbers + rng.gamma(2.0, 1e-3, numbers.size)  # late tails
    lock = MocapPhaseLock(TICK_S, max_step_s=0.01)  # the whole correction, unclamped
    lock.observe(zip(numbers.tolist(), arrivals.tolist(), strict=True))
    expected_arrival = 0.0037 + 0.002  # + 0.01 n; the delays' mean is 2 ms
    wanted = 0.003  # a deadline this much earlier than half a period after an arrival
    step = lock.correction(2.0 + expected_arrival + 0.005 - wanted)
    assert lock.locked and lock.frame_period_s == pytest.approx(0.01, rel=0.02)
    # The fitted line's end is known to ~0.3 ms (1σ) with 1.4 ms of delay spread.
    assert step == pytest.approx(wanted, abs=1e-3)


def test_the_ticker_moves_its_following_deadlines() -> None:
    clock = [10.0]
    ticker = DeadlineTicker(TICK_S, start_s=10.0, clock=lambda: clock[0])
    assert ticker.next_deadline_s == 10.0
    ticker.shift(0.003)
    assert ticker.next_deadline_s == pytest.approx(10.003)
    ticker.shift(math.nan)
    assert ticker.next_deadline_s == pytest.approx(10.003)


def test_the_trigger_window_opens_half_a_frame_period_before_the_expected_arrival() -> None:
    lock, _, _ = fly_ticks(0.01, 0.0037, 50e-6, 200)
    assert lock.locked
    assert lock.trigger_window_s == pytest.approx(lock.frame_period_s)


def test_an_unlocked_stream_opens_no_window() -> None:
    sixty_hz, _, _ = fly_ticks(1.0 / 60.0, 0.003, 50e-6, 100)
    assert not sixty_hz.locked and sixty_hz.trigger_window_s == 0.0
    lock = MocapPhaseLock(TICK_S)
    assert lock.trigger_window_s == 0.0
    lock.observe([(1, 0.001), (2, 0.011)])
    lock.correction(0.02)
    assert not lock.locked and lock.trigger_window_s == 0.0
