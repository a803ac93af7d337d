"""When a real PX4 SITL gets its next sensor sample (``sim.px4_sitl``).

PX4 built without lockstep stamps each HIL_SENSOR on arrival. When the world's process
stalls and then catches up, the samples it computes for the missed world time would
reach PX4 microseconds apart, and PX4's rate controller differentiates the gyro across
that gap for its D term. Measured on three PX4 v1.15.4 SITL under the plate (ULogs,
``sim.px4_ulog``): after a 16 ms stall, samples 2–5 µs apart, an angular acceleration of
1302 rad/s², the pitch torque setpoint at 7.7 (saturated at 1), and a 0.63 rad/s pitch
rate nobody asked for; that flight left the plate 7 cm off its reference.
A real IMU samples on its own clock, so a sample is never sent sooner than most of a
period after the last by the wall clock: the one held back is not sent late, the next
carries the world's newer state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MIN_WALL_GAP_OF_PERIOD = 0.75
TIME_RESOLUTION_S = 1e-9  # world times a rounding apart are the same instant


@dataclass
class SensorSchedule:
    """Every ``period_s`` of world time, and never sooner than ``min_wall_gap_s`` after
    the last sample by the wall clock (times are arguments)."""

    period_s: float
    min_wall_gap_s: float
    next_world_s: float = 0.0
    last_wall_s: float = -math.inf

    @classmethod
    def at_rate(cls, rate_hz: float) -> SensorSchedule:
        period_s = 1.0 / rate_hz
        return cls(period_s, MIN_WALL_GAP_OF_PERIOD * period_s)

    def take(self, world_s: float, wall_s: float) -> bool:
        """Whether a sample goes out now; if so, it is counted as sent."""
        due = world_s >= self.next_world_s - TIME_RESOLUTION_S
        if not due or wall_s - self.last_wall_s < self.min_wall_gap_s:
            return False
        self.next_world_s = max(self.next_world_s + self.period_s, world_s)
        self.last_wall_s = wall_s
        return True
