"""Phase-locking the control loop's deadlines to the arrival of mocap frames.

A tick uses the newest mocap frame; if the deadlines fall at a random phase of the frame
stream, that frame has waited anywhere up to a frame period (10 ms at 100 Hz) before its
tick starts. When the frame period divides the tick period, every deadline can instead
fall just after an arrival. ``MocapPhaseLock`` estimates the arrival phase from the last
second of receive times (a circular mean, so jitter averages out, with its spread) and
tells the ticker how far to move its deadlines: to ``margin + 3σ`` after the mean arrival,
by at most ``max_step_s`` per tick so a disturbed estimate never jerks the loop. The
deadlines stay absolute (t0 + k·h, with t0 trimmed), and without a usable stream — too few
frames, or a frame rate that does not divide the tick rate — nothing moves.
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
        margin_s: float = 0.3e-3,
        max_step_s: float = 0.5e-3,
        window: int = 100,
    ) -> None:
        self.tick_period_s = tick_period_s
        self.margin_s = margin_s
        self.max_step_s = max_step_s
        self._arrivals: deque[float] = deque(maxlen=window)
        self.frame_period_s = math.nan
        """The frame period of the last estimate [s] (NaN before one)."""
        self.jitter_s = math.nan
        """The arrivals' spread (circular standard deviation) of the last estimate [s]."""

    def observe(self, receive_times_s: Iterable[float]) -> None:
        """Record the receive times of the frames a tick drained (non-finite ones ignored)."""
        self._arrivals.extend(t for t in receive_times_s if math.isfinite(t))

    def correction(self, next_deadline_s: float) -> float:
        """How far to move the deadlines from ``next_deadline_s`` on [s]; 0 when unlocked."""
        if len(self._arrivals) < MIN_FRAMES:
            return 0.0
        arrivals = np.fromiter(self._arrivals, float)
        intervals = np.diff(arrivals)
        period = float(np.median(intervals[intervals > 0.0])) if np.any(intervals > 0) else 0.0
        if period <= 0.0:
            return 0.0
        ratio = self.tick_period_s / period
        if ratio < 0.5 or abs(ratio - round(ratio)) > RATE_TOLERANCE * ratio:
            return 0.0
        angles = 2.0 * math.pi * ((arrivals - next_deadline_s) % period) / period
        mean_sin, mean_cos = float(np.mean(np.sin(angles))), float(np.mean(np.cos(angles)))
        resultant = math.hypot(mean_sin, mean_cos)
        if resultant < 1e-6:  # arrivals spread evenly: no phase to lock to
            return 0.0
        self.frame_period_s = period
        self.jitter_s = period / (2.0 * math.pi) * math.sqrt(-2.0 * math.log(min(resultant, 1.0)))
        arrival_offset = math.atan2(mean_sin, mean_cos) / (2.0 * math.pi) * period
        wanted = math.remainder(arrival_offset + self.margin_s + 3.0 * self.jitter_s, period)
        return max(-self.max_step_s, min(self.max_step_s, wanted))
