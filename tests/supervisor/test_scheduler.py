"""The deadline ticker: absolute deadlines, skipped periods counted, timing statistics."""

from __future__ import annotations

import asyncio
import itertools
import threading
import time

import pytest

from supervisor.runtime.scheduler import (
    PERCENTILES_REFRESH_TICKS,
    DeadlineTicker,
    TickTiming,
    TimingStats,
)


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
    stats.record_latency(4.0)
    summary = stats.summary()
    assert summary.count == 102
    assert summary.missed_deadlines == 3
    assert summary.compute_ms_p50 == pytest.approx(1.0)
    assert summary.lateness_ms_p99 is not None and 0.2 <= summary.lateness_ms_p99 <= 15.0
    assert summary.latency_ms_p50 == summary.latency_ms_p99 == 4.0


def test_the_percentiles_follow_the_ticks_without_a_sort_per_status_read() -> None:
    stats, period = TimingStats(), 0.02
    seen: list[float | None] = []
    for k in range(600):
        compute_s = 0.001 if k < 200 else 0.003
        stats.record(TickTiming(k, k * period, k * period, 0), compute_s, period)
        summary = stats.summary()
        assert summary.count == k + 1  # the totals are always exact
        seen.append(summary.compute_ms_p50)
    assert seen[0] == pytest.approx(1.0)  # known from the first tick on
    assert seen[199] == pytest.approx(1.0)
    # the median is 3 ms once the window holds more of them (from tick 400 on), and the
    # status says so at most one refresh later
    first_3ms = next(k for k, p50 in enumerate(seen) if p50 == pytest.approx(3.0))
    assert 400 <= first_3ms <= 400 + PERCENTILES_REFRESH_TICKS
    assert seen[-1] == pytest.approx(3.0)


def test_empty_statistics_are_unknown_not_errors() -> None:
    summary = TimingStats().summary()
    assert summary.count == 0 and summary.compute_ms_p50 is None
    assert summary.latency_ms_p99 is None


def test_period_must_be_positive() -> None:
    with pytest.raises(ValueError, match="period_s"):
        DeadlineTicker(0.0)


class HandClock:
    """A clock that stands still until the test moves it: the trigger tests then depend on
    no scheduling (a 10 s period outlasts the test; the wake thread never fires)."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s


async def waiting_tick(ticker: DeadlineTicker) -> asyncio.Task[TickTiming]:
    """The next tick, started and left waiting for its deadline."""
    task = asyncio.create_task(ticker.__anext__())
    await asyncio.sleep(0)
    return task


async def settle() -> None:
    for _ in range(3):
        await asyncio.sleep(0)


async def test_a_trigger_inside_the_window_starts_the_tick_at_once() -> None:
    clock = HandClock()
    ticker = DeadlineTicker(10.0, clock=clock)
    try:
        first = await anext(ticker)
        ticker.early_window_s = 2.0
        tick = await waiting_tick(ticker)
        clock.now_s = 6.0  # 4 s before the deadline: outside the window, ignored
        ticker.trigger()
        await settle()
        assert not tick.done()
        clock.now_s = 8.5  # 1.5 s before it: inside
        ticker.trigger()
        await settle()
        assert tick.done()
        second = tick.result()
    finally:
        ticker.close()
    assert first.lateness_s == 0.0
    assert second.deadline_s == 10.0
    assert second.lateness_s == -1.5  # started early, by the trigger


async def test_the_window_never_reaches_back_more_than_half_a_period() -> None:
    clock = HandClock()
    ticker = DeadlineTicker(10.0, clock=clock)
    try:
        await anext(ticker)
        ticker.early_window_s = 100.0
        tick = await waiting_tick(ticker)
        clock.now_s = 4.0  # 6 s early: more than half a period, ignored
        ticker.trigger()
        await settle()
        assert not tick.done()
        clock.now_s = 5.5
        ticker.trigger()
        await settle()
        assert tick.done() and tick.result().lateness_s == -4.5
    finally:
        ticker.close()


async def test_a_trigger_with_no_tick_waiting_starts_nothing_later() -> None:
    clock = HandClock()
    ticker = DeadlineTicker(10.0, clock=clock)
    try:
        ticker.trigger()  # before the first tick
        first = await anext(ticker)
        ticker.early_window_s = 2.0
        clock.now_s = 9.0  # inside the next tick's window, with no tick waiting yet
        ticker.trigger()
        tick = await waiting_tick(ticker)
        await settle()
        assert not tick.done()  # the earlier trigger was not kept for it
        tick.cancel()
    finally:
        ticker.close()
    assert first.lateness_s == 0.0
    with pytest.raises(asyncio.CancelledError):
        await tick


def wake_threads() -> int:
    return sum(thread.name == "tick-wake" for thread in threading.enumerate())


async def test_close_ends_the_wake_thread_waiting_for_a_far_deadline() -> None:
    ticker = DeadlineTicker(3600.0)
    await anext(ticker)
    tick = await waiting_tick(ticker)
    waiting = wake_threads()
    ticker.close()
    tick.cancel()
    assert wake_threads() == waiting - 1
