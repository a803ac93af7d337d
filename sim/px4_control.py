"""The flight-control loops of the simulated PX4: body-rate PID (what PX4's rate
controller does with SET_ATTITUDE_TARGET body rates) and the position/attitude cascade its
own modes use (position and altitude hold, stabilized, land). Pure; SI units; body frame
FLU, arena ENU.

PX4 runs its rate loop at 250 Hz–1 kHz; here it runs whenever the world steps it (every
plant chunk, ~500 Hz), integrating over the actual elapsed time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from geometry.arrays import FloatArray


@dataclass(frozen=True)
class RateGains:
    """Per-axis (roll, pitch, yaw) gains of the rate PID: angular acceleration per rate
    error [1/s], per integrated error [1/s²], per rate change [1] (derivative on the
    measurement). Torque = J × (that acceleration); the integral is clamped."""

    kp: tuple[float, float, float] = (18.0, 18.0, 10.0)
    ki: tuple[float, float, float] = (20.0, 20.0, 10.0)
    kd: tuple[float, float, float] = (0.3, 0.3, 0.0)
    integral_limit_radps: float = 0.5


@dataclass
class RateController:
    """Body-rate PID → body torque [N m], saturated per axis. Per-axis floats, not
    3-vectors: the world runs it for every UAV every ~2 ms, where numpy's per-call cost
    was most of a simulated PX4's time."""

    inertia_kgm2: tuple[float, float, float]
    torque_max_nm: float
    gains: RateGains = field(default_factory=RateGains)
    _integral: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    _last_rates: tuple[float, float, float] | None = None

    def reset(self) -> None:
        self._integral = [0.0, 0.0, 0.0]
        self._last_rates = None

    def torque(self, rates_sp: FloatArray, rates: FloatArray, dt: float) -> FloatArray:
        """The torque that drives the body rates ``rates`` toward ``rates_sp`` [rad/s]."""
        g = self.gains
        limit = g.integral_limit_radps
        w = (float(rates[0]), float(rates[1]), float(rates[2]))
        w_sp = (float(rates_sp[0]), float(rates_sp[1]), float(rates_sp[2]))
        last = self._last_rates if dt > 0.0 else None
        self._last_rates = w
        J = self.inertia_kgm2
        accel = [0.0, 0.0, 0.0]
        for axis in range(3):
            error = w_sp[axis] - w[axis]
            if dt > 0.0:
                self._integral[axis] = min(max(self._integral[axis] + error * dt, -limit), limit)
            derivative = 0.0 if last is None else (w[axis] - last[axis]) / dt
            accel[axis] = (
                g.kp[axis] * error + g.ki[axis] * self._integral[axis] - g.kd[axis] * derivative
            )
        # J·α + ω × (J ω)
        Jw = (J[0] * w[0], J[1] * w[1], J[2] * w[2])
        gyroscopic = (
            w[1] * Jw[2] - w[2] * Jw[1],
            w[2] * Jw[0] - w[0] * Jw[2],
            w[0] * Jw[1] - w[1] * Jw[0],
        )
        bound = self.torque_max_nm
        return np.array(
            [min(max(J[i] * accel[i] + gyroscopic[i], -bound), bound) for i in range(3)]
        )


@dataclass(frozen=True)
class HoldGains:
    """Position hold/land cascade: position [1/s²], velocity [1/s], vertical-velocity
    integral [1/s²·s⁻¹... as acceleration per m/s·s], attitude [1/s], max tilt."""

    kp: float = 1.5
    kv: float = 2.5
    ki_z: float = 1.0
    k_attitude: float = 6.0
    max_tilt_rad: float = math.radians(20.0)


@dataclass
class HoldController:
    """PX4's own position modes, reduced: hold a position (or descend at a rate) with a
    level attitude and held yaw; returns (thrust [N], body-rate setpoint [rad/s]).
    ``hover_thrust_n`` is the thrust PX4 believes hovers the vehicle (MPC_THR_HOVER times
    the vehicle's thrust at normalized 1.0): the model updates it when that parameter
    changes."""

    hover_thrust_n: float
    gains: HoldGains = field(default_factory=HoldGains)
    _integral_z: float = 0.0

    def reset(self) -> None:
        self._integral_z = 0.0

    def command(
        self,
        target_m: FloatArray,
        climb_rate_mps: float | None,
        yaw_rad: float,
        position_m: FloatArray,
        velocity_mps: FloatArray,
        rotation: FloatArray,
        dt: float,
        *,
        hold_horizontal: bool = True,
    ) -> tuple[float, FloatArray]:
        """``climb_rate_mps`` None holds ``target_m``; a value tracks that vertical speed
        (negative: descend) while holding x, y. ``hold_horizontal`` False holds the height
        only, level (PX4's altitude mode with centred sticks: the vehicle drifts)."""
        g = self.gains
        accel = g.kp * (target_m - position_m) - g.kv * velocity_mps
        if not hold_horizontal:
            accel[0:2] = 0.0
        if climb_rate_mps is not None:
            accel[2] = g.kv * (climb_rate_mps - velocity_mps[2])
        self._integral_z = float(np.clip(self._integral_z + accel[2] * dt, -2.0, 2.0))
        accel[2] += g.ki_z * self._integral_z
        mass_g = self.hover_thrust_n
        force = mass_g / 9.81 * accel + np.array([0.0, 0.0, mass_g])
        horizontal = math.hypot(force[0], force[1])
        limit = math.tan(g.max_tilt_rad) * max(force[2], 0.0)
        if horizontal > limit and horizontal > 0.0:
            force[0:2] *= limit / horizontal
        force[2] = max(force[2], 0.0)
        return self._track(force, yaw_rad, rotation)

    def level(self, yaw_rad: float, rotation: FloatArray) -> tuple[float, FloatArray]:
        """PX4's stabilized mode with centred sticks: level attitude, held yaw, the hover
        thrust (MPC_THR_HOVER is what the centred throttle stick maps to), no height hold."""
        return self._track(np.array([0.0, 0.0, self.hover_thrust_n]), yaw_rad, rotation)

    def _track(
        self, force: FloatArray, yaw_rad: float, rotation: FloatArray
    ) -> tuple[float, FloatArray]:
        """Thrust along the body z axis and the body rates that turn it toward ``force``
        (arena ENU [N]) with heading ``yaw_rad``."""
        g = self.gains
        norm = float(np.linalg.norm(force))
        z_desired = force / norm if norm > 0.0 else np.array([0.0, 0.0, 1.0])
        heading = np.array([math.cos(yaw_rad), math.sin(yaw_rad), 0.0])
        y_desired = np.cross(z_desired, heading)
        y_desired /= np.linalg.norm(y_desired)
        R_desired = np.column_stack([np.cross(y_desired, z_desired), y_desired, z_desired])
        error_matrix = R_desired.T @ rotation - rotation.T @ R_desired
        e_R = 0.5 * np.array([error_matrix[2, 1], error_matrix[0, 2], error_matrix[1, 0]])
        thrust = float(force @ rotation[:, 2])
        rates_sp: FloatArray = -g.k_attitude * e_R
        return max(thrust, 0.0), rates_sp
