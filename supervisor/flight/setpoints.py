"""Bar setpoints: validation, the bounded queue, and the rate-limited reference.

A setpoint is checked against the arena geofence and equilibrium feasibility *before* it
is queued: the bar, both bar ends and both UAVs of its equilibrium must lie inside the
arena (with a margin). The queue starts the next setpoint when the current one has been
reached and held for ``hold_s``. Between setpoints the reference moves at bounded rates
(``ReferenceShaper``), never in steps.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from controllers.equilibria import EquilibriumError, Reference, bar_equilibrium
from controllers.params import BarSystemParams
from geometry.arrays import FloatArray
from geometry.state import bar_position


class SetpointError(ValueError):
    """A setpoint that cannot be flown (outside the arena, no equilibrium, not finite)."""


@dataclass(frozen=True)
class Setpoint:
    """One queue entry: bar centre [m, arena frame], bar yaw, UAV yaws, θ_l [rad], hold [s],
    and optionally how long to wait for it to be reached before moving on anyway [s]."""

    bar_position_m: tuple[float, float, float]
    bar_yaw_rad: float = 0.0
    uav_yaw_rad: tuple[float, float] | None = None
    theta_l_rad: float = 0.0
    hold_s: float = 5.0
    timeout_s: float | None = None

    @staticmethod
    def from_json(entry: Any) -> Setpoint:
        """A setpoint from the API's JSON form (``bar_position`` [m], ``bar_yaw``,
        ``uav_yaw``, ``theta_l`` [rad], ``hold_s`` [s]); raises ``SetpointError``."""
        if not isinstance(entry, dict) or "bar_position" not in entry:
            raise SetpointError("a setpoint is an object with at least 'bar_position'")
        try:
            x, y, z = (float(v) for v in entry["bar_position"])
            uav_yaw = entry.get("uav_yaw")
            yaws = None if uav_yaw is None else tuple(float(v) for v in uav_yaw)
            if yaws is not None and len(yaws) != 2:
                raise ValueError("uav_yaw takes two angles")
            return Setpoint(
                (x, y, z),
                float(entry.get("bar_yaw", 0.0)),
                (yaws[0], yaws[1]) if yaws is not None else None,
                float(entry.get("theta_l", 0.0)),
                float(entry.get("hold_s", 5.0)),
            )
        except (TypeError, ValueError) as error:
            raise SetpointError(f"malformed setpoint: {error}") from None

    def reference(self) -> Reference:
        """The equilibrium family this setpoint asks for (UAV yaws default to the bar's)."""
        yaws = (
            self.uav_yaw_rad
            if self.uav_yaw_rad is not None
            else (self.bar_yaw_rad, self.bar_yaw_rad)
        )
        return Reference(self.bar_position_m, self.bar_yaw_rad, yaws, self.theta_l_rad)


@dataclass(frozen=True)
class Arena:
    """The flight volume (arena frame, z up) [m] and the margin kept from its walls."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    margin_m: float = 0.2

    def contains(self, point: np.ndarray, margin_m: float | None = None) -> bool:
        margin = self.margin_m if margin_m is None else margin_m
        return bool(
            np.all(point >= np.asarray(self.min_m) + margin)
            and np.all(point <= np.asarray(self.max_m) - margin)
        )


def validate_setpoint(setpoint: Setpoint, params: BarSystemParams, arena: Arena) -> None:
    """Raise ``SetpointError`` naming what is wrong; return quietly when it can be flown."""
    values = [*setpoint.bar_position_m, setpoint.bar_yaw_rad, setpoint.theta_l_rad, setpoint.hold_s]
    values += list(setpoint.uav_yaw_rad or ())
    if not all(math.isfinite(v) for v in values):
        raise SetpointError("setpoint values must be finite numbers")
    if setpoint.hold_s < 0.0:
        raise SetpointError("hold_s must be >= 0")
    try:
        eq = bar_equilibrium(params, setpoint.reference())
    except EquilibriumError as error:
        raise SetpointError(str(error)) from error
    points = {
        "bar centre": bar_position(eq.x),
        "bar end 1": eq.bar_ends_m[0],
        "bar end 2": eq.bar_ends_m[1],
        "UAV 1": eq.uav_position(1),
        "UAV 2": eq.uav_position(2),
    }
    for name, point in points.items():
        if not arena.contains(point):
            where = ", ".join(f"{v:.2f}" for v in point)
            raise SetpointError(
                f"{name} would be at ({where}) m, outside the arena "
                f"{list(arena.min_m)}..{list(arena.max_m)} with a {arena.margin_m} m margin"
            )


class SetpointQueue:
    """Bounded FIFO of validated setpoints with the active one and its hold timer."""

    def __init__(self, capacity: int = 32) -> None:
        self.capacity = capacity
        self._queued: deque[Setpoint] = deque()
        self.active: Setpoint | None = None
        self.timed_out = 0
        self._reached_since_s: float | None = None
        self._active_since_s = 0.0

    @property
    def queued(self) -> list[Setpoint]:
        return list(self._queued)

    def extend(self, setpoints: list[Setpoint]) -> None:
        """Queue all of them or none (raises ``SetpointError`` when they do not fit)."""
        if len(self._queued) + len(setpoints) > self.capacity:
            raise SetpointError(
                f"the queue holds at most {self.capacity} setpoints ({len(self._queued)} queued)"
            )
        self._queued.extend(setpoints)

    def clear(self) -> None:
        """Drop the queued setpoints and the active one."""
        self._queued.clear()
        self.active = None
        self._reached_since_s = None

    def update(self, reached: bool, now_s: float) -> Setpoint | None:
        """Advance: the active setpoint ends once reached and held ``hold_s`` (or when its
        ``timeout_s`` has passed, counted in ``timed_out``); then the next one starts.
        Returns the setpoint to fly now (None when there is none)."""
        active = self.active
        if active is not None:
            if not reached:
                self._reached_since_s = None
            elif self._reached_since_s is None:
                self._reached_since_s = now_s
            held = (
                self._reached_since_s is not None and now_s - self._reached_since_s >= active.hold_s
            )
            expired = active.timeout_s is not None and now_s - self._active_since_s >= (
                active.timeout_s
            )
            if held or expired:
                self.timed_out += int(expired and not held)
                self.active = None
                self._reached_since_s = None
        if self.active is None and self._queued:
            self.active = self._queued.popleft()
            self._active_since_s = now_s
        return self.active


@dataclass(frozen=True)
class RateLimits:
    """How fast the reference may move: bar position [m/s] and its acceleration [m/s²],
    yaws [rad/s], θ_l [rad/s]."""

    position_mps: float = 0.3
    acceleration_mps2: float = 0.3
    yaw_radps: float = math.radians(20.0)
    theta_l_radps: float = math.radians(10.0)


def _approach(current: float, target: float, max_step: float) -> float:
    return current + max(-max_step, min(max_step, target - current))


def _approach_angle(current: float, target: float, max_step: float) -> float:
    """One step the short way round; lands on ``target`` itself (not target ± 2π)."""
    error = math.remainder(target - current, 2.0 * math.pi)
    if abs(error) <= max_step:
        return target
    return current + math.copysign(max_step, error)


def _move(
    position: FloatArray, velocity: FloatArray, target: FloatArray, limits: RateLimits, dt: float
) -> tuple[FloatArray, FloatArray]:
    """One step of a trapezoidal profile toward ``target``: speed ≤ ``position_mps``,
    acceleration ≤ ``acceleration_mps2``, slowing down in time to stop on the target."""
    offset = target - position
    distance = float(np.linalg.norm(offset))
    a = limits.acceleration_mps2
    if distance == 0.0 and not velocity.any():
        return target, velocity
    direction = offset / distance if distance > 0.0 else np.zeros(3)
    # The fastest speed from which steps of a·dt less per tick still stop on the target
    # (the discrete form of √(2 a d)).
    step = a * dt
    stopping = step * (math.sqrt(0.25 + 2.0 * distance / (step * dt)) - 0.5) if step > 0 else 0.0
    wanted = direction * min(limits.position_mps, stopping)
    change = wanted - velocity
    change_norm = float(np.linalg.norm(change))
    if change_norm > a * dt:
        change *= a * dt / change_norm
    new_velocity = velocity + change
    if distance <= float(np.linalg.norm(new_velocity)) * dt + 1e-9:
        return target, np.zeros(3)
    return position + new_velocity * dt, new_velocity


class ReferenceShaper:
    """Moves the reference toward the target at bounded rates (time as an argument). The
    bar position follows a trapezoidal velocity profile and the reference carries that
    velocity (zero once the target is reached); yaws and θ_l move at bounded rates."""

    def __init__(self, start: Reference, limits: RateLimits = RateLimits()) -> None:
        self.current = start
        self.limits = limits
        self._last_s: float | None = None

    def reset(self, reference: Reference) -> None:
        """Jump to ``reference`` (when a flight phase starts from where the system is)."""
        self.current = reference
        self._last_s = None

    def update(self, target: Reference, now_s: float) -> Reference:
        """The reference at ``now_s``, moved toward ``target``."""
        dt = 0.0 if self._last_s is None else max(0.0, now_s - self._last_s)
        self._last_s = now_s
        c, lim = self.current, self.limits
        position, velocity = _move(
            np.array(c.bar_position_m),
            np.array(c.velocity_mps),
            np.array(target.bar_position_m),
            lim,
            dt,
        )
        yaw_step = lim.yaw_radps * dt
        yaws = (
            _approach_angle(c.bar_yaw_rad, target.bar_yaw_rad, yaw_step),
            _approach_angle(c.uav_yaw_rad[0], target.uav_yaw_rad[0], yaw_step),
            _approach_angle(c.uav_yaw_rad[1], target.uav_yaw_rad[1], yaw_step),
        )
        before = (c.bar_yaw_rad, *c.uav_yaw_rad)
        rates = tuple(
            math.remainder(new - old, 2.0 * math.pi) / dt if dt > 0.0 else 0.0
            for new, old in zip(yaws, before, strict=True)
        )
        self.current = Reference(
            (float(position[0]), float(position[1]), float(position[2])),
            yaws[0],
            (yaws[1], yaws[2]),
            _approach(c.theta_l_rad, target.theta_l_rad, lim.theta_l_radps * dt),
            (float(velocity[0]), float(velocity[1]), float(velocity[2])),
            (rates[0], rates[1], rates[2]),
        )
        return self.current
