"""The deadline ticker: absolute deadlines, skipped periods counted, timing statistics."""

from __future__ import annotations

import asyncio
import itertools
import math
import time

import pytest

from supervisor.runtime.scheduler import DeadlineTicker, TickTiming, TimingStats


def busy(seconds: float) -> None:
    """CPU work that holds the event loop, as a long tick would."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


async def test_deadlines_are_absolute_and_never_drift() -> None:
    ticker = DeadlineTicker(0.005)
    timings: list[TickTiming] = []
    try:
        async for timing in ticker:
            timings.append(timing)
            busy(0.002)  # work that a sleep-after-work loop would accumulate as drift
            if len(timings) == 40:
                break
    finally:
        ticker.close()
    t0 = timings[0].deadline_s
    for timing in timings:
        assert timing.deadline_s == pytest.approx(t0 + timing.index * 0.005, abs=1e-12)
        assert timing.started_s >= timing.deadline_s
    # Every period either ticked or was counted as skipped (a busy machine may hold the
    # loop past a whole period: that is skipping, not drift).
    for before, after in itertools.pairwise(timings):
        assert after.index == before.index + 1 + after.skipped


async def test_a_stalled_loop_skips_the_missed_periods() -> None:
    ticker = DeadlineTicker(0.005)
    try:
        first = await anext(ticker)
        busy(0.0175)  # 3.5 periods lost
        late = await anext(ticker)
    finally:
        ticker.close()
    assert late.skipped >= 2
    assert late.index == first.index + 1 + late.skipped
    assert late.deadline_s >= first.deadline_s + 3 * 0.005 - 1e-12


def test_timing_statistics() -> None:
    stats = TimingStats()
    period = 0.02
    for k in range(100):
        stats.record(TickTiming(k, k * period, k * period + 0.0002, 0), 0.001, period)
    stats.record(TickTiming(100, 2.0, 2.0 + 0.015, 0), 0.006, period)  # ends after the next
    stats.record(TickTiming(103, 2.06, 2.06, 2), 0.001, period)  # two periods skipped
    summary = stats.summary()
    assert summary["count"] == 102
    assert summary["missed_deadlines"] == 3
    assert summary["compute_ms_p50"] == pytest.approx(1.0)
    assert 0.2 <= summary["lateness_ms_p99"] <= 15.0


def test_empty_statistics_are_nan_not_errors() -> None:
    summary = TimingStats().summary()
    assert summary["count"] == 0 and math.isnan(summary["compute_ms_p50"])


def test_period_must_be_positive() -> None:
    with pytest.raises(ValueError, match="period_s"):
        DeadlineTicker(0.0)


async def test_a_trigger_inside_the_window_starts_the_tick_at_once() -> None:
    ticker = DeadlineTicker(0.05)
    try:
        first = await anext(ticker)
        ticker.early_window_s = 0.02
        loop = asyncio.get_running_loop()
        loop.call_later(0.01, ticker.trigger)  # 40 ms before the deadline: outside, ignored
        loop.call_later(0.035, ticker.trigger)  # 15 ms before it: inside
        second = await anext(ticker)
    finally:
        ticker.close()
    assert second.deadline_s == pytest.approx(first.deadline_s + 0.05, abs=1e-12)
    assert -0.018 < second.lateness_s < -0.005  # started early, by the trigger


async def test_the_window_never_reaches_back_more_than_half_a_period() -> None:
    ticker = DeadlineTicker(0.04)
    try:
        await anext(ticker)
        ticker.early_window_s = 1.0
        asyncio.get_running_loop().call_later(0.01, ticker.trigger)  # 30 ms early: ignored
        second = await anext(ticker)
    finally:
        ticker.close()
    assert second.lateness_s >= 0.0


async def test_a_trigger_with_no_tick_waiting_starts_nothing_later() -> None:
    ticker = DeadlineTicker(0.02)
    try:
        ticker.trigger()  # before the first tick
        first = await anext(ticker)
        ticker.early_window_s = 0.01
        ticker.trigger()  # between ticks, with no tick waiting yet
        busy(0.012)  # the next tick is now 8 ms away: inside the window
        second = await anext(ticker)
    finally:
        ticker.close()
    assert first.lateness_s >= 0.0
    assert second.lateness_s >= 0.0  # the earlier trigger was not kept for it
