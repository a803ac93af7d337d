"""Paths as the tick core flies them: planned from where the queue will be when they start,
checked like setpoints along the whole of their timing, and sampled as references.

A path is queued as a setpoint at its last waypoint that carries its plan
(``Setpoint.path``): the queue flies it like any setpoint (hold, timeout, clear), and while
its timing runs the reference is the path's instead of the shaper's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from controllers.equilibria import EquilibriumError
from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from supervisor.flight.feasibility import SetpointBounds, equilibrium_problems
from supervisor.flight.path_timing import SAMPLE_STEP_S, PathLimits, TimedPath, time_path
from supervisor.flight.reference_shaping import ReferenceShaper
from supervisor.flight.setpoints import Arena, Setpoint, arena_problem
from supervisor.flight.waypoint import Waypoint

CHECK_STEP_S = 0.1  # how often along its timing a path is checked like a setpoint,
MAX_CHECKS = 200  # ... unless that makes more checks than this (~8 ms between ticks)


@dataclass(frozen=True)
class PathPlan:
    """A path to fly: its waypoints and limits, the reference it starts from (at rest) and
    its timing. The UAVs keep the yaws they have about the bar's at the start."""

    waypoints: tuple[Waypoint, ...]
    limits: PathLimits
    start: FormationReference
    timed: TimedPath

    def reference(self, t_s: float, feed_acceleration: bool = True) -> FormationReference:
        """The formation's reference ``t_s`` after the path's start: the path's position,
        yaw, θ_l, velocity, turn and θ_l rates and (``feed_acceleration``) acceleration."""
        sample = self.timed.sample(t_s)
        p, v, a = sample.position_m, sample.velocity_mps, sample.acceleration_mps2
        acceleration = (float(a[0]), float(a[1]), float(a[2])) if feed_acceleration else (0.0,) * 3
        start = self.start
        uav_yaws = tuple(
            sample.yaw_rad + math.remainder(yaw - start.payload_yaw_rad, math.tau)
            for yaw in start.uav_yaw_rad
        )
        return FormationReference(
            (float(p[0]), float(p[1]), float(p[2])),
            sample.yaw_rad,
            uav_yaws,
            sample.theta_l_rad,
            (float(v[0]), float(v[1]), float(v[2])),
            sample.yaw_rate_radps,
            (sample.yaw_rate_radps,) * len(uav_yaws),
            sample.theta_l_rate_radps,
            (acceleration[0], acceleration[1], acceleration[2]),
        )

    def end(self) -> FormationReference:
        """Where it ends, at rest."""
        return self.reference(self.timed.duration_s).at_rest()


def plan_path(
    start: FormationReference, waypoints: Sequence[Waypoint], limits: PathLimits
) -> PathPlan:
    """The path from ``start`` (taken at rest) through ``waypoints``, timed (raises
    ``PathError``)."""
    rest = start.at_rest()
    origin = Waypoint(rest.payload_position_m, rest.payload_yaw_rad, rest.cone_angle_rad)
    return PathPlan(tuple(waypoints), limits, rest, time_path(origin, waypoints, limits))


def path_problem(
    plan: PathPlan,
    params: FormationParams,
    bounds: SetpointBounds,
    arena: Arena,
) -> str | None:
    """Why the vehicles cannot fly ``plan`` (None: they can): at samples every
    ``CHECK_STEP_S`` (on a long path ``MAX_CHECKS`` of them evenly spread) and at its
    greatest acceleration, the equilibrium of the path's reference there (its
    acceleration included) against ``bounds`` and ``arena``."""
    timed = plan.timed
    step_s = max(CHECK_STEP_S, timed.duration_s / MAX_CHECKS)
    times = [*np.arange(0.0, timed.duration_s, step_s).tolist(), timed.duration_s]
    hardest = int(np.argmax(np.linalg.norm(timed.accelerations_mps2, axis=1)))
    for t_s in sorted({*times, hardest * SAMPLE_STEP_S}):
        reference = plan.reference(t_s)
        try:
            eq = formation_equilibrium(params, reference, remember=False)
        except EquilibriumError as error:
            return f"at {t_s:.1f} s along the path: {error}"
        problems = equilibrium_problems(eq, bounds)
        outside = arena_problem(eq, arena)
        if outside is not None:
            problems.append(outside)
        if problems:
            return f"at {t_s:.1f} s along the path: " + "; ".join(problems)
    return None


class PathRunner:
    """Flies the active setpoint's path (pure, time as an argument): from the tick the bar
    is at the path's start — first shaped there when a setpoint before it ended elsewhere
    (timed out) — along its timing to its end, the shaper following so that a clear or the
    next setpoint moves on from where the path was."""

    def __init__(self, feed_acceleration: bool = True) -> None:
        self.feed_acceleration = feed_acceleration
        self._setpoint: Setpoint | None = None
        self._started_s: float | None = None

    def progress(self, now_s: float) -> tuple[PathPlan, float] | None:
        """The path begun last and the time since it began [s] (past its duration once it
        has ended, until the next setpoint starts); None before any or while a path is
        still shaped to its start."""
        if self._setpoint is None or self._setpoint.path is None or self._started_s is None:
            return None
        return self._setpoint.path, now_s - self._started_s

    def flying(self, setpoint: Setpoint | None, now_s: float) -> bool:
        """Whether ``setpoint`` has a path not yet flown to its end."""
        if setpoint is None or setpoint.path is None:
            return False
        if setpoint is not self._setpoint or self._started_s is None:
            return True
        return now_s - self._started_s < setpoint.path.timed.duration_s

    def step(
        self,
        setpoint: Setpoint | None,
        shaper: ReferenceShaper,
        now_s: float,
        stages: Sequence[int],
        dt_s: float,
    ) -> tuple[FormationReference, dict[int, FormationReference]] | None:
        """The reference now and at ``stages`` steps of ``dt_s`` ahead while ``setpoint``'s
        path is flown; None once it is (or without one: the shaper flies the setpoint)."""
        if setpoint is None or setpoint.path is None:
            self._setpoint = None
            return None
        plan = setpoint.path
        if setpoint is not self._setpoint:
            self._setpoint, self._started_s = setpoint, None
        if self._started_s is None:
            if shaper.current != plan.start:
                reference = shaper.update(plan.start, now_s)
                return reference, shaper.preview(plan.start, now_s, stages, dt_s)
            self._started_s = now_s
        t_s = now_s - self._started_s
        if t_s >= plan.timed.duration_s:
            shaper.follow(plan.end(), now_s)
            return None
        reference = plan.reference(t_s, self.feed_acceleration)
        shaper.follow(reference, now_s)
        ahead = {k: plan.reference(t_s + k * dt_s, self.feed_acceleration) for k in stages}
        return reference, ahead
