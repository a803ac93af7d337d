"""The IMU, magnetometer and barometer a PX4 reads in hardware-in-the-loop simulation
(MAVLink HIL_SENSOR), from the plant's true motion. Pure; time is an argument.

Body frame FRD, world NED, as PX4 expects. The accelerometer measures specific force
(acceleration minus gravity) — −g along body z at rest; the acceleration is the change of
the true velocity between two samples. Every channel carries white noise: PX4 rejects a
magnetometer or barometer whose readings never change as stale (docs/reference/px4-offboard.md §5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import (
    enu_to_ned,
    flu_to_frd,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from sim.ports import AirframeState

GRAVITY_MPS2 = 9.81
SEA_LEVEL_HPA = 1013.25
# HIL_SENSOR.fields_updated: accel 0x7, gyro 0x38, mag 0x1C0, abs_pressure 0x200,
# pressure_alt 0x800, temperature 0x1000.
ALL_FIELDS = 0x7 | 0x38 | 0x1C0 | 0x200 | 0x800 | 0x1000


@dataclass(frozen=True)
class SensorNoise:
    """1σ white noise per sample (typical MEMS figures at 250 Hz)."""

    accel_mps2: float = 0.05
    gyro_radps: float = 0.003
    mag_gauss: float = 0.002
    baro_hpa: float = 0.01
    temperature_degc: float = 0.05


@dataclass(frozen=True)
class HilSample:
    """One HIL_SENSOR's values, in its fields' units."""

    accel_frd_mps2: FloatArray
    gyro_frd_radps: FloatArray
    mag_frd_gauss: FloatArray
    abs_pressure_hpa: float
    pressure_alt_m: float
    temperature_degc: float


class HilSensors:
    """The sensors of one UAV; ``sample`` once per HIL_SENSOR."""

    def __init__(
        self,
        seed: int,
        noise: SensorNoise | None = None,
        *,
        field_ned_gauss: tuple[float, float, float] = (0.21, 0.0, 0.43),
        ground_altitude_m: float = 0.0,
    ) -> None:
        self.noise = noise or SensorNoise()
        self._rng = np.random.default_rng(seed)
        self._field_ned = np.array(field_ned_gauss)
        self._ground_altitude_m = ground_altitude_m
        self._last: tuple[float, FloatArray] | None = None

    def sample(self, state: AirframeState) -> HilSample:
        """The readings for the true ``state`` (its time stamps the acceleration)."""
        n, rng = self.noise, self._rng
        velocity = np.asarray(state.velocity_mps, dtype=float)
        acceleration = np.zeros(3)
        if self._last is not None and state.time_s > self._last[0]:
            acceleration = (velocity - self._last[1]) / (state.time_s - self._last[0])
        self._last = (state.time_s, velocity)
        R_ned_frd = rotation_enu_flu_to_ned_frd(rotation_from_quaternion(state.quaternion))
        specific_force_ned = enu_to_ned(acceleration) - np.array([0.0, 0.0, GRAVITY_MPS2])
        altitude = self._ground_altitude_m + float(state.position_m[2])
        return HilSample(
            accel_frd_mps2=R_ned_frd.T @ specific_force_ned + rng.normal(0.0, n.accel_mps2, 3),
            gyro_frd_radps=flu_to_frd(np.asarray(state.body_rates_radps, dtype=float))
            + rng.normal(0.0, n.gyro_radps, 3),
            mag_frd_gauss=R_ned_frd.T @ self._field_ned + rng.normal(0.0, n.mag_gauss, 3),
            abs_pressure_hpa=pressure_hpa(altitude) + float(rng.normal(0.0, n.baro_hpa)),
            pressure_alt_m=altitude,
            temperature_degc=20.0 + float(rng.normal(0.0, n.temperature_degc)),
        )


def pressure_hpa(altitude_m: float) -> float:
    """The International Standard Atmosphere's pressure at ``altitude_m`` [hPa]."""
    return SEA_LEVEL_HPA * math.pow(1.0 - 2.25577e-5 * altitude_m, 5.25588)
