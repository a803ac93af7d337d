"""Bar setpoints: validation and the bounded queue.

A setpoint is checked against the arena geofence and equilibrium feasibility *before* it
is queued: the bar, every cable's attachment and every UAV of its equilibrium must lie
inside the arena (with a margin), and the vehicles must be able to hold that equilibrium
(θ_l, thrust and tilt within ``SetpointBounds``, ``supervisor.flight.feasibility``). The
queue starts the next setpoint when the current one has been reached and held for
``hold_s``. Between setpoints the reference moves at bounded rates
(``supervisor.flight.reference_shaping``), never in steps.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from controllers.equilibria import EquilibriumError
from controllers.formation_equilibria import (
    FormationEquilibrium,
    FormationReference,
    formation_equilibrium,
)
from controllers.formation_params import FormationParams
from geometry.state import payload_position
from supervisor.errors import OperatorError
from supervisor.flight.feasibility import SetpointBounds, equilibrium_problems, theta_l_problem

if TYPE_CHECKING:
    from supervisor.flight.paths import PathPlan


class SetpointError(OperatorError, ValueError):
    """A setpoint that cannot be flown (outside the arena, no equilibrium, not finite)."""


class SetpointRefusedError(SetpointError):
    """Setpoints the queue does not take now (a mode that flies none, or no room): none of
    them was queued."""


class SetpointQueueFullError(SetpointRefusedError):
    """Setpoints that do not fit the queue: none of them was queued."""


@dataclass(frozen=True)
class Setpoint:
    """One queue entry, as the operator states it (the API's and the scenarios' names):
    bar centre [m, arena frame], bar yaw, UAV yaws, θ_l (the cone angle) [rad], hold [s],
    and optionally how long to wait for it to be reached before moving on anyway [s].
    With ``path`` it is the end of a path, flown along it (``supervisor.flight.paths``)."""

    bar_position_m: tuple[float, float, float]
    bar_yaw_rad: float = 0.0
    uav_yaw_rad: tuple[float, ...] | None = None
    theta_l_rad: float = 0.0
    hold_s: float = 5.0
    timeout_s: float | None = None
    path: PathPlan | None = None

    def uav_yaws(self, n_vehicles: int) -> tuple[float, ...]:
        """The UAVs' yaws [rad]: as given, or each the bar's."""
        return (
            self.uav_yaw_rad if self.uav_yaw_rad is not None else (self.bar_yaw_rad,) * n_vehicles
        )

    def reference(self, n_vehicles: int) -> FormationReference:
        """The equilibrium family this setpoint asks for of ``n_vehicles`` UAVs."""
        return FormationReference(
            self.bar_position_m, self.bar_yaw_rad, self.uav_yaws(n_vehicles), self.theta_l_rad
        )


@dataclass(frozen=True)
class Arena:
    """The flight volume (arena frame, z up) [m] and the margin kept from its walls."""

    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]
    margin_m: float = 0.2

    @classmethod
    def between(cls, min_m: Sequence[float], max_m: Sequence[float]) -> Arena:
        """The box from corner ``min_m`` to corner ``max_m`` (three numbers each)."""
        return cls((min_m[0], min_m[1], min_m[2]), (max_m[0], max_m[1], max_m[2]))

    def contains(self, point: np.ndarray, margin_m: float | None = None) -> bool:
        margin = self.margin_m if margin_m is None else margin_m
        return bool(
            np.all(point >= np.asarray(self.min_m) + margin)
            and np.all(point <= np.asarray(self.max_m) - margin)
        )


def validate_setpoint(
    setpoint: Setpoint, params: FormationParams, arena: Arena, bounds: SetpointBounds
) -> None:
    """Raise ``SetpointError`` naming what is wrong; return quietly when it can be flown."""
    values = [*setpoint.bar_position_m, setpoint.bar_yaw_rad, setpoint.theta_l_rad, setpoint.hold_s]
    values += list(setpoint.uav_yaw_rad or ())
    if not all(math.isfinite(v) for v in values):
        raise SetpointError("setpoint values must be finite numbers")
    if setpoint.hold_s < 0.0:
        raise SetpointError("hold_s must be >= 0")
    given = setpoint.uav_yaw_rad
    if given is not None and len(given) != params.n_vehicles:
        raise SetpointError(
            f"uav_yaw: one yaw per UAV ({params.n_vehicles}), UAV 1's first; got {len(given)}"
        )
    too_steep = theta_l_problem(setpoint.theta_l_rad, bounds)
    problems = [too_steep] if too_steep is not None else []
    try:
        eq = formation_equilibrium(params, setpoint.reference(params.n_vehicles))
    except EquilibriumError as error:
        raise SetpointError("; ".join(problems) or str(error)) from error
    problems += equilibrium_problems(eq, bounds)
    if problems:
        raise SetpointError("; ".join(problems))
    outside = arena_problem(eq, arena)
    if outside is not None:
        raise SetpointError(outside)


def arena_problem(eq: FormationEquilibrium, arena: Arena) -> str | None:
    """Which point of ``eq`` (the bar's centre, an end, a UAV) lies outside ``arena`` with
    its margin, and where (None: all inside)."""
    vehicles = eq.layout.vehicles
    points = {
        "bar centre": payload_position(eq.x),
        **{f"bar end {i}": eq.attachments_m[i - 1] for i in vehicles},
        **{f"UAV {i}": eq.uav_position(i) for i in vehicles},
    }
    for name, point in points.items():
        outside = point_outside(name, point, arena)
        if outside is not None:
            return outside
    return None


def point_outside(name: str, point: np.ndarray, arena: Arena) -> str | None:
    """That ``name`` at ``point`` [m] would be outside ``arena`` with its margin, and
    where (None: inside)."""
    if arena.contains(point):
        return None
    where = ", ".join(f"{v:.2f}" for v in point)
    return (
        f"{name} would be at ({where}) m, outside the arena "
        f"{list(arena.min_m)}..{list(arena.max_m)} with a {arena.margin_m} m margin"
    )


def validate_setpoints(
    setpoints: list[Setpoint], params: FormationParams, arena: Arena, bounds: SetpointBounds
) -> None:
    """``validate_setpoint`` on each; the error names which one when there are several."""
    for index, setpoint in enumerate(setpoints):
        try:
            validate_setpoint(setpoint, params, arena, bounds)
        except SetpointError as error:
            if len(setpoints) == 1:
                raise
            raise SetpointError(f"setpoint {index}: {error}") from None


class SetpointQueue:
    """Bounded FIFO of validated setpoints with the active one and its hold timer."""

    def __init__(self, capacity: int = 32) -> None:
        self.capacity = capacity
        self._queued: deque[Setpoint] = deque()
        self.active: Setpoint | None = None
        self.timed_out = 0
        self.queued_total = 0
        """How many setpoints were ever queued."""
        self.finished = 0
        """How many setpoints have ended (held, timed out, or finished from outside)."""
        self._reached_since_s: float | None = None
        self._active_since_s = 0.0

    @property
    def queued(self) -> list[Setpoint]:
        return list(self._queued)

    def extend(self, setpoints: list[Setpoint]) -> None:
        """Queue all of them or none (raises ``SetpointError`` when they do not fit)."""
        self.check_room(len(setpoints))
        self._queued.extend(setpoints)
        self.queued_total += len(setpoints)

    def check_room(self, count: int) -> None:
        """Raise ``SetpointQueueFullError`` unless ``count`` more setpoints fit."""
        if len(self._queued) + count > self.capacity:
            raise SetpointQueueFullError(
                f"the queue holds at most {self.capacity} setpoints ({len(self._queued)} queued)"
            )

    def finish_active(self) -> None:
        """End the active setpoint now, as if held (the next one starts at ``update``)."""
        if self.active is not None:
            self.active = None
            self.finished += 1
            self._reached_since_s = None

    def drop_queued(self) -> None:
        """Drop the queued setpoints; the active one is flown on."""
        self._queued.clear()

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
                self.finish_active()
        if self.active is None and self._queued:
            self.active = self._queued.popleft()
            self._active_since_s = now_s
        return self.active
