"""The rate-limited reference: between setpoints the reference moves at bounded rates
(position with a trapezoidal speed profile, yaws, the cone angle θ_l), never in steps, and
carries its velocity, turn rates and cone-angle rate so the MPC regulates to a moving
(relative) equilibrium."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from controllers.formation_equilibria import FormationReference
from geometry.arrays import FloatArray


@dataclass(frozen=True)
class RateLimits:
    """How fast the reference may move: payload position [m/s] and its acceleration
    [m/s²], yaws [rad/s], the cone angle θ_l [rad/s]."""

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
    acceleration ≤ ``acceleration_mps2``, slowing down in time to stop on the target.
    Returns the new position and velocity."""
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
    payload's position follows a trapezoidal velocity profile and the reference carries
    that velocity (zero once the target is reached) and, with ``feed_acceleration``, the
    profile's acceleration over the step just taken (the UAVs' tilt and thrust that the
    payload's acceleration needs, ``FormationReference.acceleration_mps2``); yaws and the
    cone angle move at bounded rates."""

    def __init__(
        self,
        start: FormationReference,
        limits: RateLimits = RateLimits(),
        feed_acceleration: bool = True,
    ) -> None:
        self.current = start
        self.limits = limits
        self.feed_acceleration = feed_acceleration
        self._last_s: float | None = None
        self._braking: tuple[float, FormationReference] | None = None  # [m/s²], the stop

    def reset(self, reference: FormationReference) -> None:
        """Jump to ``reference`` (when a flight phase starts from where the system is)."""
        self.current = reference
        self._last_s = None

    def stopping_point(self, acceleration_mps2: float) -> FormationReference:
        """Where the reference comes to rest braking at ``acceleration_mps2`` from its
        velocity now, along it."""
        velocity = np.array(self.current.velocity_mps)
        speed = float(np.linalg.norm(velocity))
        stop = np.array(self.current.payload_position_m) + velocity * speed / (
            2.0 * acceleration_mps2
        )
        return replace(
            self.current.at_rest(),
            payload_position_m=(float(stop[0]), float(stop[1]), float(stop[2])),
        )

    def brake(self, acceleration_mps2: float, stop: FormationReference) -> None:
        """While the target is ``stop`` and until the reference rests, allow
        ``acceleration_mps2`` (if above the limits') and its speed now (if above theirs):
        a move faster than the limits (a path) is stopped as it was flown, not at the
        limits' gentler rates. Any other target is flown at the limits."""
        self._braking = (acceleration_mps2, stop)

    def follow(self, reference: FormationReference, now_s: float) -> None:
        """Take ``reference`` as where the reference is at ``now_s`` (a path flies it)."""
        self.current = reference
        self._last_s = now_s

    def preview(
        self, target: FormationReference, now_s: float, stages: Sequence[int], step_s: float
    ) -> dict[int, FormationReference]:
        """The references at ``stages`` steps of ``step_s`` after ``now_s`` (the MPC's
        stages ahead), were the target to stay ``target``; this shaper is left as it is.
        Empty when the reference rests on the target: every stage would be the
        reference."""
        if not stages or self.current == target.at_rest():
            return {}
        ahead = ReferenceShaper(self.current, self.limits, self.feed_acceleration)
        ahead._last_s, ahead._braking = now_s, self._braking
        wanted = set(stages)
        references = {}
        for k in range(1, max(stages) + 1):
            reference = ahead.update(target, now_s + k * step_s)
            if k in wanted:
                references[k] = reference
        return references

    def update(self, target: FormationReference, now_s: float) -> FormationReference:
        """The reference at ``now_s``, moved toward ``target``."""
        dt = 0.0 if self._last_s is None else max(0.0, now_s - self._last_s)
        self._last_s = now_s
        c, lim = self.current, self._limits_now(target)
        position, velocity = _move(
            np.array(c.payload_position_m),
            np.array(c.velocity_mps),
            np.array(target.payload_position_m),
            lim,
            dt,
        )
        yaw_step = lim.yaw_radps * dt
        yaws = [
            _approach_angle(now, wanted, yaw_step)
            for now, wanted in zip(
                (c.payload_yaw_rad, *c.uav_yaw_rad),
                (target.payload_yaw_rad, *target.uav_yaw_rad),
                strict=True,
            )
        ]
        before = (c.payload_yaw_rad, *c.uav_yaw_rad)
        rates = [
            math.remainder(new - old, 2.0 * math.pi) / dt if dt > 0.0 else 0.0
            for new, old in zip(yaws, before, strict=True)
        ]
        cone = _approach(c.cone_angle_rad, target.cone_angle_rad, lim.theta_l_radps * dt)
        moving = self.feed_acceleration and dt > 0.0 and velocity.any()
        acceleration = (velocity - np.array(c.velocity_mps)) / dt if moving else np.zeros(3)
        self.current = FormationReference(
            (float(position[0]), float(position[1]), float(position[2])),
            yaws[0],
            tuple(yaws[1:]),
            cone,
            (float(velocity[0]), float(velocity[1]), float(velocity[2])),
            rates[0],
            tuple(rates[1:]),
            (cone - c.cone_angle_rad) / dt if dt > 0.0 else 0.0,
            (float(acceleration[0]), float(acceleration[1]), float(acceleration[2])),
        )
        return self.current

    def _limits_now(self, target: FormationReference) -> RateLimits:
        """The limits, raised while braking to ``target`` (``brake``) until the reference
        rests."""
        if self._braking is None:
            return self.limits
        braking, stop = self._braking
        speed = float(np.linalg.norm(self.current.velocity_mps))
        if speed == 0.0 or target != stop:
            self._braking = None
            return self.limits
        return replace(
            self.limits,
            position_mps=max(self.limits.position_mps, speed),
            acceleration_mps2=max(self.limits.acceleration_mps2, braking),
        )
