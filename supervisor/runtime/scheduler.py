"""The control loop's clock: ticks on absolute deadlines t0 + k·h, with timing statistics.

asyncio's own timers wake up to a millisecond late (the selector's timeout is rounded up
to whole milliseconds), too coarse for a 20 ms loop that wants sub-millisecond lateness.
``DeadlineTicker`` therefore waits in a small helper thread (a timed lock wait wakes within
tens of microseconds) and wakes the event loop with ``call_soon_threadsafe``. A tick that
finds itself a whole period late skips the missed deadlines (counted), never bunches up.

A deadline is the latest a tick starts. ``trigger`` (the arrival of a mocap frame) starts
the waiting tick at once when it comes within ``early_window_s`` before the deadline, so
the frame is used the moment it is there instead of waiting for the clock; a frame that is
late does not hold the tick back beyond its deadline.
"""

from __future__ import annotations

import asyncio
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from supervisor.flight.status import TickSummary


@dataclass(frozen=True)
class TickTiming:
    """When tick ``index`` was due and started (monotonic seconds), and ticks skipped
    before it because the loop was a whole period late."""

    index: int
    deadline_s: float
    started_s: float
    skipped: int

    @property
    def lateness_s(self) -> float:
        """How late the tick started; negative when a trigger started it early."""
        return self.started_s - self.deadline_s


class _WakeThread:
    """Sleeps until a deadline on its own thread, then resolves a future on the loop."""

    def __init__(self, loop: asyncio.AbstractEventLoop, clock: Callable[[], float]) -> None:
        self._loop = loop
        self._clock = clock
        self._lock = threading.Condition()
        self._request: tuple[float, asyncio.Future[None]] | None = None
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="tick-wake", daemon=True)
        self._thread.start()

    def wait_until(self, deadline_s: float) -> asyncio.Future[None]:
        future: asyncio.Future[None] = self._loop.create_future()
        with self._lock:
            self._request = (deadline_s, future)
            self._lock.notify()
        return future

    def stop(self) -> None:
        with self._lock:
            self._stopped = True
            self._lock.notify()
        self._thread.join(timeout=1.0)

    def _run(self) -> None:
        while True:
            with self._lock:
                while self._request is None and not self._stopped:
                    self._lock.wait()
                if self._stopped:
                    return
                assert self._request is not None
                deadline, future = self._request
                self._request = None
                # A timed wait on the lock wakes as precisely as a sleep, but close() (or a
                # tick that a trigger started early asking for the next) cuts it short.
                remaining = deadline - self._clock()
                while remaining > 0.0 and self._request is None and not self._stopped:
                    self._lock.wait(remaining)
                    remaining = deadline - self._clock()
                if self._stopped:
                    return
            try:
                self._loop.call_soon_threadsafe(_resolve, future)
            except RuntimeError:  # the loop closed while we slept
                return


def _resolve(future: asyncio.Future[None]) -> None:
    if not future.done():
        future.set_result(None)


class DeadlineTicker:
    """``async for timing in ticker`` yields once per period on t0 + k·period."""

    def __init__(
        self,
        period_s: float,
        start_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (math.isfinite(period_s) and period_s > 0.0):
            raise ValueError("period_s must be finite and > 0")
        self.period_s = period_s
        self._clock = clock
        self._t0 = start_s
        self._index = 0
        self._wake: _WakeThread | None = None
        self._waiting: tuple[float, asyncio.Future[None]] | None = None
        self.early_window_s = 0.0
        """How long before its deadline ``trigger`` may start a tick [s]; 0: never early."""

    def __aiter__(self) -> DeadlineTicker:
        return self

    async def __anext__(self) -> TickTiming:
        if self._wake is None:
            self._wake = _WakeThread(asyncio.get_running_loop(), self._clock)
        if self._t0 is None:
            self._t0 = self._clock()
        deadline = self.next_deadline_s
        now = self._clock()
        skipped = 0
        if now - deadline >= self.period_s:  # a whole period (or more) late: drop them
            skipped = int((now - deadline) // self.period_s)
            self._index += skipped
            deadline = self.next_deadline_s
        if now < deadline:
            wake = self._wake.wait_until(deadline)
            self._waiting = (deadline, wake)
            try:
                await wake
            finally:
                self._waiting = None
        timing = TickTiming(self._index, deadline, self._clock(), skipped)
        self._index += 1
        return timing

    @property
    def next_deadline_s(self) -> float:
        """The deadline of the next tick (before skips); NaN before the first tick."""
        if self._t0 is None:
            return math.nan
        return self._t0 + self._index * self.period_s

    def trigger(self) -> None:
        """Start the waiting tick now if its deadline is at most ``early_window_s`` away (and
        never more than half a period: ticks stay at least that far apart). Call it from the
        event loop's thread."""
        if self._waiting is None:
            return
        deadline, wake = self._waiting
        if self._clock() >= deadline - min(self.early_window_s, 0.5 * self.period_s):
            _resolve(wake)

    def shift(self, delta_s: float) -> None:
        """Move every following deadline by ``delta_s`` (the phase lock trims t0 with it)."""
        if self._t0 is not None and math.isfinite(delta_s):
            self._t0 += delta_s

    def close(self) -> None:
        """Stop the wake-up thread."""
        if self._wake is not None:
            self._wake.stop()
            self._wake = None


PERCENTILES_REFRESH_TICKS = 50


class TimingStats:
    """Rolling statistics of the last ``window`` ticks, plus totals since start. The
    percentiles are computed anew once ``PERCENTILES_REFRESH_TICKS`` ticks came since (or
    the ticks doubled, early on), not for every status read: the status is read 25 times a
    second, and sorting the window that often took a tenth of the flight process's time."""

    def __init__(self, window: int = 3000) -> None:
        self.count = 0
        self.missed_deadlines = 0
        self._compute_ms: deque[float] = deque(maxlen=window)
        self._lateness_ms: deque[float] = deque(maxlen=window)
        self._latency_ms: deque[float] = deque(maxlen=window)
        self._percentiles_at_count = -1
        self._percentiles: dict[str, float | None] = {}

    def record(self, timing: TickTiming, compute_s: float, period_s: float) -> None:
        """A tick missed its deadline when it was skipped, or started so late, or computed so
        long, that its commands went out after the next deadline."""
        self.count += 1
        late = timing.lateness_s + compute_s >= period_s
        self.missed_deadlines += timing.skipped + int(late)
        self._compute_ms.append(compute_s * 1e3)
        self._lateness_ms.append(timing.lateness_s * 1e3)

    def record_latency(self, latency_ms: float) -> None:
        """A tick's setpoints went out ``latency_ms`` after the mocap frame they answer
        arrived."""
        self._latency_ms.append(latency_ms)

    def summary(self) -> TickSummary:
        """The totals, and the percentiles of the recent window (None while it is empty)."""
        since = self._percentiles_at_count
        if self.count - since >= min(PERCENTILES_REFRESH_TICKS, max(since, 1)):
            compute_p50, compute_p99 = _percentiles(self._compute_ms)
            latency_p50, latency_p99 = _percentiles(self._latency_ms)
            self._percentiles = {
                "compute_ms_p50": compute_p50,
                "compute_ms_p99": compute_p99,
                "lateness_ms_p99": _percentiles(self._lateness_ms)[1],
                "latency_ms_p50": latency_p50,
                "latency_ms_p99": latency_p99,
            }
            self._percentiles_at_count = self.count
        return TickSummary(
            count=self.count, missed_deadlines=self.missed_deadlines, **self._percentiles
        )


def _percentiles(values: deque[float]) -> tuple[float | None, float | None]:
    """The median and the 99th percentile of ``values`` (None, None: there are none)."""
    if not values:
        return None, None
    median, p99 = np.percentile(np.fromiter(values, float), (50, 99))
    return float(median), float(p99)
