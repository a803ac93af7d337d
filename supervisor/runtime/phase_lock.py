"""Phase-locking the control loop's deadlines to the arrival of mocap frames.

A tick uses the newest mocap frame; if the deadlines fall at a random phase of the frame
stream, that frame has waited anywhere up to a frame period (10 ms at 100 Hz) before its
tick starts. When the frame period divides the tick period, every tick can instead start
as its frame arrives. ``MocapPhaseLock`` fits the last second of receive times against
QTM's frame numbers (a straight line: the numbers count camera frames, so dropped frames
and jitter do not bias the period or the phase) and tells the ticker how far to move its
deadlines — to half a frame period after the expected arrival — by at most
``max_step_s`` per tick, so a disturbed estimate never jerks the loop. The deadlines stay
absolute (t0 + k·h, with t0 trimmed), and without a usable stream — too few frames, or a
frame rate that does not divide the tick rate — nothing moves.

A deadline is then only the latest start: while locked, the ticker lets a frame arriving
within half a frame period of its expected time start the tick at once
(``trigger_window_s``). An on-time frame waits for nothing; a late one is waited for up to
half a frame period, since a tick a few milliseconds late with the fresh frame controls
better than one on time with a frame a period older; a frame later still (or lost) leaves
the tick to its deadline and the newest frame it has.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable

import numpy as np

MIN_FRAMES = 20
RATE_TOLERANCE = 0.02  # how close tick period / frame period must be to an integer


class MocapPhaseLock:
    """Where the next deadlines should move to, from the frames' receive times."""

    def __init__(
        self,
        tick_period_s: float,
        max_step_s: float = 0.5e-3,
        window: int = 100,
    ) -> None:
        self.tick_period_s = tick_period_s
        self.max_step_s = max_step_s
        self._arrivals: deque[tuple[int, float]] = deque(maxlen=window)
        self.frame_period_s = math.nan
        """The frame period of the last estimate [s] (NaN before one)."""
        self.locked = False
        """Whether the last ``correction`` found a stream to lock to."""

    @property
    def trigger_window_s(self) -> float:
        """How long before its deadline a frame may start a tick [s]: from half a frame
        period before the expected arrival on (a frame period); 0 while unlocked."""
        return self.frame_period_s if self.locked else 0.0

    def observe(self, frames: Iterable[tuple[int, float]]) -> None:
        """Record (frame number, receive time) of newly received frames, oldest first;
        non-finite times are ignored, and a frame number that does not increase (QTM started
        counting anew) starts a new record."""
        for number, receive_time_s in frames:
            if not math.isfinite(receive_time_s):
                continue
            if self._arrivals and number <= self._arrivals[-1][0]:
                self._arrivals.clear()
            self._arrivals.append((number, receive_time_s))

    def correction(self, next_deadline_s: float) -> float:
        """How far to move the deadlines from ``next_deadline_s`` on [s]; 0 when unlocked."""
        self.locked = False
        if len(self._arrivals) < MIN_FRAMES:
            return 0.0
        numbers = np.array([n for n, _ in self._arrivals], dtype=float)
        times = np.array([t for _, t in self._arrivals])
        numbers -= numbers[-1]  # the fit's intercept is then the newest frame's arrival
        centred = numbers - numbers.mean()
        per_number = float(centred @ (times - times.mean()) / (centred @ centred))
        if not per_number > 0.0:
            return 0.0
        period = per_number * float(np.median(np.diff(numbers)))  # frames as delivered
        ratio = self.tick_period_s / period
        if ratio < 0.5 or abs(ratio - round(ratio)) > RATE_TOLERANCE * ratio:
            return 0.0
        newest_arrival = times.mean() - per_number * numbers.mean()
        self.frame_period_s = period
        self.locked = True
        arrival_offset = math.remainder(newest_arrival - next_deadline_s, period)
        wanted = math.remainder(arrival_offset + 0.5 * period, period)
        return max(-self.max_step_s, min(self.max_step_s, wanted))
