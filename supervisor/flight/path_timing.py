"""Paths: a smooth bar trajectory through waypoints, timed within speed, acceleration and
jerk limits (pure: geometry and numbers in, samples out).

Geometry: a cubic spline through the start and the waypoints, on the chord length, with
natural ends (periodic when the path closes on its start): position, tangent and curvature
κ are continuous, and two points give a straight line.

Timing, along the arc length s: the fastest speed law with
    v ≤ speed,   v² κ ≤ a (the normal acceleration),   |dψ/ds| v ≤ ψ̇_max, |dθ_l/ds| v ≤ θ̇_max,
and the tangential acceleration within what the normal one leaves, √(a² − (v²κ)²),
by a forward and a backward pass over a grid of s, starting and ending at rest. The law
s(t) is then averaged over a window of 2a/j seconds: a moving average keeps its speed and
its tangential acceleration within their bounds and bounds the jerk along the path by j.
Last, if any sample's acceleration (tangential and normal together) or speed still exceeds
its limit (the average can raise the speed at a bend a little), time is stretched
uniformly until none does.

The bar's yaw and θ_l move between consecutive waypoints along a smoothstep in s, so
their rates are zero at each waypoint; a waypoint without them keeps the previous ones.
Samples are kept every ``SAMPLE_STEP_S``; ``sample`` interpolates between them.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from geometry.arrays import FloatArray
from supervisor.flight.waypoint import Waypoint

SAMPLE_STEP_S = 0.01
SAME_POINT_M = 1e-3  # waypoints closer than this are one point
_GRID_PER_SEGMENT = 40  # arc-length grid points per spline segment (at least)
_GRID_SPACING_M = 0.005  # ... no coarser than this
_GRID_POINTS = 5_000  # ... unless the path is longer than 25 m: timing stays ~15 ms
MAX_TURN_DEG = 120.0  # the sharpest turn at a waypoint (between its chords)
MAX_DURATION_S = 600.0


class PathError(ValueError):
    """A path that cannot be timed (coincident waypoints, limits that are not positive)."""


@dataclass(frozen=True)
class PathLimits:
    """Bounds of a path's timing: the bar's speed [m/s], acceleration [m/s²] and jerk along
    the path [m/s³], and the rates of its yaw and of θ_l [rad/s]."""

    speed_mps: float
    accel_mps2: float
    jerk_mps3: float
    yaw_radps: float
    theta_l_radps: float

    def __post_init__(self) -> None:
        for name in ("speed_mps", "accel_mps2", "jerk_mps3", "yaw_radps", "theta_l_radps"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise PathError(f"{name} must be a positive number, not {value}")


@dataclass(frozen=True)
class PathSample:
    """The path at one time: the bar's centre [m], velocity [m/s] and acceleration [m/s²]
    (each (3,)), its yaw [rad] and yaw rate [rad/s], θ_l [rad] and its rate [rad/s]."""

    position_m: FloatArray
    velocity_mps: FloatArray
    acceleration_mps2: FloatArray
    yaw_rad: float
    yaw_rate_radps: float
    theta_l_rad: float
    theta_l_rate_radps: float


@dataclass(frozen=True)
class TimedPath:
    """A timed path: samples every ``SAMPLE_STEP_S`` from 0 to ``duration_s``, at rest at
    both ends. Arrays: positions, velocities, accelerations (T, 3); yaws, yaw rates, θ_l,
    θ_l rates (T,)."""

    positions_m: FloatArray
    velocities_mps: FloatArray
    accelerations_mps2: FloatArray
    yaws_rad: FloatArray
    yaw_rates_radps: FloatArray
    thetas_l_rad: FloatArray
    theta_l_rates_radps: FloatArray
    length_m: float

    @property
    def duration_s(self) -> float:
        return (len(self.yaws_rad) - 1) * SAMPLE_STEP_S

    def sample(self, t_s: float) -> PathSample:
        """The path at ``t_s`` after its start (held at its ends outside [0, duration])."""
        last = len(self.yaws_rad) - 1
        where = min(max(t_s / SAMPLE_STEP_S, 0.0), float(last))
        k = min(int(where), last - 1) if last > 0 else 0
        w = where - k if last > 0 else 0.0
        j = min(k + 1, last)

        def blend(values: FloatArray) -> FloatArray:
            mixed: FloatArray = (1.0 - w) * values[k] + w * values[j]
            return mixed

        yaw = self.yaws_rad[k] + w * math.remainder(
            float(self.yaws_rad[j] - self.yaws_rad[k]), 2.0 * math.pi
        )
        return PathSample(
            blend(self.positions_m),
            blend(self.velocities_mps),
            blend(self.accelerations_mps2),
            float(yaw),
            float(blend(self.yaw_rates_radps)),
            float(blend(self.thetas_l_rad)),
            float(blend(self.theta_l_rates_radps)),
        )


@dataclass(frozen=True)
class _Geometry:
    """The spline through the points on a fine grid of its parameter u: arc length S(u),
    position and its first two derivatives in u, and the waypoints' u."""

    u: FloatArray
    arc_m: FloatArray
    p: FloatArray
    p_u: FloatArray
    p_uu: FloatArray
    knots_u: FloatArray


def _points(start: Waypoint, waypoints: Sequence[Waypoint]) -> list[Waypoint]:
    """Start and waypoints with yaw and θ_l filled in; a first waypoint on the start is the
    start (its yaw and θ_l taken); coincident consecutive waypoints raise ``PathError``."""
    if not waypoints:
        raise PathError("a path needs at least one waypoint")
    yaw, theta = start.bar_yaw_rad, start.theta_l_rad
    assert yaw is not None and theta is not None
    points = [Waypoint(start.bar_position_m, yaw, theta)]
    for index, point in enumerate(waypoints):
        yaw = yaw if point.bar_yaw_rad is None else point.bar_yaw_rad
        theta = theta if point.theta_l_rad is None else point.theta_l_rad
        here = Waypoint(point.bar_position_m, yaw, theta)
        gap = float(np.linalg.norm(np.subtract(here.bar_position_m, points[-1].bar_position_m)))
        if gap >= SAME_POINT_M:
            points.append(here)
        elif index == 0 and len(points) == 1:
            points[0] = here
        else:
            raise PathError(
                f"waypoint {index} lies on the point before it ({gap * 1e3:.1f} mm away): "
                "a path turns or tilts only while it moves"
            )
    if len(points) < 2:
        raise PathError("the path does not move the bar: its waypoints lie on its start")
    _check_turns(points)
    return points


def _check_turns(points: Sequence[Waypoint]) -> None:
    """Raise ``PathError`` at a waypoint where the path doubles back (turns more than
    ``MAX_TURN_DEG`` between its chords): a smooth curve through it would have to stop
    and reverse there, which a smoothed speed law does not do."""
    xyz = np.array([p.bar_position_m for p in points], dtype=float)
    chords = np.diff(xyz, axis=0)
    for k in range(1, len(chords)):
        before, after = chords[k - 1], chords[k]
        cosine = float(before @ after) / float(np.linalg.norm(before) * np.linalg.norm(after))
        turn = math.degrees(math.acos(max(-1.0, min(1.0, cosine))))
        if turn > MAX_TURN_DEG:
            raise PathError(
                f"the path turns by {turn:.0f}° at waypoint {k - 1} (at most "
                f"{MAX_TURN_DEG:.0f}°): fly it as two paths, one ending there"
            )


def _geometry(points: Sequence[Waypoint]) -> _Geometry:
    xyz = np.array([p.bar_position_m for p in points], dtype=float)
    chords = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    knots = np.concatenate(([0.0], np.cumsum(chords)))
    closed = len(points) > 2 and float(np.linalg.norm(xyz[-1] - xyz[0])) < SAME_POINT_M
    if closed:
        xyz[-1] = xyz[0]
    spline = CubicSpline(knots, xyz, bc_type="periodic" if closed else "natural")
    spacing = max(_GRID_SPACING_M, float(chords.sum()) / _GRID_POINTS)
    u = np.unique(
        np.concatenate(
            [
                np.linspace(a, b, max(_GRID_PER_SEGMENT, math.ceil((b - a) / spacing)) + 1)
                for a, b in itertools.pairwise(knots)
            ]
        )
    )
    p, p_u, p_uu = spline(u), spline(u, 1), spline(u, 2)
    speed_u = np.linalg.norm(p_u, axis=1)
    arc = np.concatenate(([0.0], np.cumsum(0.5 * (speed_u[1:] + speed_u[:-1]) * np.diff(u))))
    return _Geometry(u, arc, p, p_u, p_uu, knots)


def _smoothstep_profile(
    values: Sequence[float], knots_arc: FloatArray, arc: FloatArray, wrap: bool
) -> tuple[FloatArray, FloatArray]:
    """A value moving from each waypoint's to the next along a smoothstep in s, and its
    derivative in s; ``wrap`` takes each change the short way round (angles)."""
    value = np.empty_like(arc)
    slope = np.empty_like(arc)
    segment = np.clip(np.searchsorted(knots_arc, arc, side="right") - 1, 0, len(values) - 2)
    for k in range(len(values) - 1):
        mine = segment == k
        length = knots_arc[k + 1] - knots_arc[k]
        change = values[k + 1] - values[k]
        if wrap:
            change = math.remainder(change, 2.0 * math.pi)
        sigma = np.clip((arc[mine] - knots_arc[k]) / length, 0.0, 1.0)
        value[mine] = values[k] + change * sigma * sigma * (3.0 - 2.0 * sigma)
        slope[mine] = change * 6.0 * sigma * (1.0 - sigma) / length
    return value, slope


def _speed_law(
    arc: FloatArray, curvature: FloatArray, speed_cap: FloatArray, accel: float
) -> FloatArray:
    """The fastest speed on the grid ``arc`` from rest to rest under ``speed_cap`` and the
    acceleration ``accel`` shared between the normal (v²κ) and tangential parts."""
    cap = speed_cap.copy()
    bend = curvature > 1e-9
    cap[bend] = np.minimum(cap[bend], np.sqrt(accel / curvature[bend]))
    ds = np.diff(arc)
    v = cap.copy()
    v[0] = v[-1] = 0.0

    def tangential(speed: float, kappa: float) -> float:
        normal = speed * speed * kappa
        return math.sqrt(max(accel * accel - normal * normal, 0.0))

    for i in range(len(ds)):
        reachable = math.sqrt(v[i] ** 2 + 2.0 * tangential(v[i], curvature[i]) * ds[i])
        v[i + 1] = min(v[i + 1], reachable)
    for i in range(len(ds) - 1, -1, -1):
        reachable = math.sqrt(v[i + 1] ** 2 + 2.0 * tangential(v[i + 1], curvature[i + 1]) * ds[i])
        v[i] = min(v[i], reachable)
    return v


def _arc_law(arc: FloatArray, v: FloatArray) -> FloatArray:
    """s(t) every SAMPLE_STEP_S of a speed law on the grid ``arc``: between grid points the
    acceleration is constant (v² linear in s), so s is quadratic in t there."""
    ds = np.diff(arc)
    accel = (v[1:] ** 2 - v[:-1] ** 2) / (2.0 * ds)
    t_grid = np.concatenate(([0.0], np.cumsum(2.0 * ds / np.maximum(v[1:] + v[:-1], 1e-12))))
    if not t_grid[-1] <= MAX_DURATION_S:
        raise PathError(
            f"the path would take {t_grid[-1]:.0f} s within its limits (at most "
            f"{MAX_DURATION_S:.0f} s): fly it faster or as several paths"
        )
    t = np.arange(0.0, t_grid[-1] + SAMPLE_STEP_S, SAMPLE_STEP_S)
    k = np.clip(np.searchsorted(t_grid, t, side="right") - 1, 0, len(ds) - 1)
    tau = np.minimum(t - t_grid[k], t_grid[k + 1] - t_grid[k])
    s: FloatArray = np.minimum(arc[k] + v[k] * tau + 0.5 * accel[k] * tau**2, arc[-1])
    return s


def _averaged(s_m: FloatArray, window_s: float) -> FloatArray:
    """s(t) sampled every SAMPLE_STEP_S, averaged over ``window_s`` (held at its ends)."""
    width = max(1, round(window_s / SAMPLE_STEP_S))
    if width == 1:
        return s_m
    padded = np.concatenate((np.full(width, s_m[0]), s_m, np.full(width, s_m[-1])))
    smoothed: FloatArray = np.convolve(padded, np.ones(width) / width, mode="valid")
    # valid gives len + width + 1 values: the law starts a window earlier than the first
    # sample's move and ends a window later; keep from the last value still at 0.
    moving = np.flatnonzero(smoothed > s_m[0])
    first = max(int(moving[0]) - 1, 0) if moving.size else 0
    ending = np.flatnonzero(smoothed < s_m[-1])
    last = int(ending[-1]) + 1 if ending.size else len(smoothed) - 1
    return smoothed[first : last + 1]


def time_path(start: Waypoint, waypoints: Sequence[Waypoint], limits: PathLimits) -> TimedPath:
    """The timed path from ``start`` (its yaw and θ_l given) through ``waypoints``, at rest
    at both ends. Raises ``PathError`` for waypoints that cannot make a path."""
    points = _points(start, waypoints)
    geometry = _geometry(points)
    arc = geometry.arc_m
    speed_u = np.linalg.norm(geometry.p_u, axis=1)
    cross = np.linalg.norm(np.cross(geometry.p_u, geometry.p_uu), axis=1)
    curvature = cross / np.maximum(speed_u, 1e-12) ** 3
    knots_arc = np.interp(geometry.knots_u, geometry.u, arc)
    yaws, yaw_slope = _smoothstep_profile(
        [float(p.bar_yaw_rad or 0.0) for p in points], knots_arc, arc, wrap=True
    )
    thetas, theta_slope = _smoothstep_profile(
        [float(p.theta_l_rad or 0.0) for p in points], knots_arc, arc, wrap=False
    )
    cap = np.full_like(arc, limits.speed_mps)
    for slope, rate in ((yaw_slope, limits.yaw_radps), (theta_slope, limits.theta_l_radps)):
        steep = np.abs(slope) > 1e-12
        cap[steep] = np.minimum(cap[steep], rate / np.abs(slope[steep]))
    v = _speed_law(arc, curvature, cap, limits.accel_mps2)
    s = _averaged(_arc_law(arc, v), 2.0 * limits.accel_mps2 / limits.jerk_mps3)
    return _sampled(geometry, arc, s, (yaws, yaw_slope), (thetas, theta_slope), limits)


def _sampled(
    geometry: _Geometry,
    arc: FloatArray,
    s: FloatArray,
    yaw: tuple[FloatArray, FloatArray],
    theta: tuple[FloatArray, FloatArray],
    limits: PathLimits,
) -> TimedPath:
    """Samples of the path along the law ``s`` (every SAMPLE_STEP_S), time stretched
    uniformly until every speed, acceleration and rate is within ``limits``."""
    s_dot = np.gradient(s, SAMPLE_STEP_S)
    s_ddot = np.gradient(s_dot, SAMPLE_STEP_S)
    s_dot[0] = s_dot[-1] = 0.0
    u = np.interp(s, arc, geometry.u)

    def at(values: FloatArray) -> FloatArray:
        columns = [np.interp(u, geometry.u, values[:, k]) for k in range(values.shape[1])]
        return np.stack(columns, axis=1)

    p, p_u, p_uu = at(geometry.p), at(geometry.p_u), at(geometry.p_uu)
    norm_u = np.linalg.norm(p_u, axis=1)
    u_dot = s_dot / norm_u
    u_ddot = (s_ddot - np.einsum("ij,ij->i", p_u, p_uu) / norm_u * u_dot**2) / norm_u
    velocity = p_u * u_dot[:, None]
    acceleration = p_uu * (u_dot**2)[:, None] + p_u * u_ddot[:, None]
    yaw_value, yaw_rate = np.interp(s, arc, yaw[0]), np.interp(s, arc, yaw[1]) * s_dot
    theta_value, theta_rate = np.interp(s, arc, theta[0]), np.interp(s, arc, theta[1]) * s_dot
    stretch = max(
        1.0,
        float(np.linalg.norm(velocity, axis=1).max()) / limits.speed_mps,
        math.sqrt(float(np.linalg.norm(acceleration, axis=1).max()) / limits.accel_mps2),
        float(np.abs(yaw_rate).max()) / limits.yaw_radps,
        float(np.abs(theta_rate).max()) / limits.theta_l_radps,
    )
    if not math.isfinite(stretch):
        raise PathError("the path cannot be timed within its limits")
    if stretch > 1.0 + 1e-6:
        # A little more than needed: the resampled law's own rounding must not ask again.
        old_t = np.arange(len(s)) * SAMPLE_STEP_S * stretch * 1.001
        new_t = np.arange(0.0, old_t[-1] + SAMPLE_STEP_S, SAMPLE_STEP_S)
        return _sampled(geometry, arc, np.interp(new_t, old_t, s), yaw, theta, limits)
    return TimedPath(
        p, velocity, acceleration, yaw_value, yaw_rate, theta_value, theta_rate, float(arc[-1])
    )
