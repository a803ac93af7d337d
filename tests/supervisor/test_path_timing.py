"""Paths timed within their limits: invariants of the samples, not snapshots."""

from __future__ import annotations

import math

import numpy as np
import pytest

from supervisor.flight.path_timing import (
    SAMPLE_STEP_S,
    PathError,
    PathLimits,
    TimedPath,
    time_path,
)
from supervisor.flight.waypoint import Waypoint

START = Waypoint((0.0, 0.0, 1.5), 0.0, 0.0)
LIMITS = PathLimits(1.0, 1.0, 2.0, math.radians(20.0), math.radians(10.0))
SQUARE = [
    Waypoint((1.5, 0.0, 1.5)),
    Waypoint((1.5, 1.5, 1.8)),
    Waypoint((0.0, 1.5, 1.8)),
    Waypoint((0.0, 0.0, 1.5)),
]
TOLERANCE = 1.02  # the samples' finite differences against the bounds


def _speeds(path: TimedPath) -> np.ndarray:
    speeds: np.ndarray = np.linalg.norm(path.velocities_mps, axis=1)
    return speeds


def _within_limits(path: TimedPath, limits: PathLimits) -> None:
    assert _speeds(path).max() <= limits.speed_mps * TOLERANCE
    assert np.linalg.norm(path.accelerations_mps2, axis=1).max() <= limits.accel_mps2 * TOLERANCE
    assert np.abs(path.yaw_rates_radps).max() <= limits.yaw_radps * TOLERANCE
    assert np.abs(path.theta_l_rates_radps).max() <= limits.theta_l_radps * TOLERANCE


def _consistent(path: TimedPath) -> None:
    """Velocities are the positions' rate and accelerations the velocities' (central
    differences of the samples)."""
    velocity = np.gradient(path.positions_m, SAMPLE_STEP_S, axis=0)
    acceleration = np.gradient(path.velocities_mps, SAMPLE_STEP_S, axis=0)
    assert np.abs(velocity - path.velocities_mps)[1:-1].max() < 2e-3
    assert np.abs(acceleration - path.accelerations_mps2)[1:-1].max() < 0.05


def test_a_straight_path_goes_from_rest_to_rest_within_its_limits() -> None:
    path = time_path(START, [Waypoint((4.0, 0.0, 1.5))], LIMITS)
    assert path.length_m == pytest.approx(4.0, abs=1e-9)
    np.testing.assert_allclose(path.positions_m[0], START.bar_position_m, atol=1e-12)
    np.testing.assert_allclose(path.positions_m[-1], (4.0, 0.0, 1.5), atol=1e-9)
    assert _speeds(path)[[0, -1]].max() == 0.0
    # Straight: y and z never move, and x never goes back or past the end.
    assert np.abs(path.positions_m[:, 1:] - (0.0, 1.5)).max() < 1e-9
    assert np.all(np.diff(path.positions_m[:, 0]) >= -1e-12)
    _within_limits(path, LIMITS)
    _consistent(path)
    # It reaches the speed limit (4 m at 1 m/s and 1 m/s² has room to), and takes at least
    # the time a trapezoid would: 4 s cruising plus 1 s.
    assert _speeds(path).max() == pytest.approx(1.0, abs=1e-6)
    assert path.duration_s >= 5.0


def test_the_jerk_along_a_straight_path_is_bounded() -> None:
    for jerk in (1.0, 4.0):
        limits = PathLimits(1.0, 1.0, jerk, math.radians(20.0), math.radians(10.0))
        path = time_path(START, [Waypoint((4.0, 0.0, 1.5))], limits)
        along = path.accelerations_mps2[:, 0]
        jerks = np.diff(along) / SAMPLE_STEP_S
        assert np.abs(jerks).max() <= jerk * TOLERANCE + 0.05


def test_a_closed_path_passes_every_waypoint_and_ends_on_its_start() -> None:
    path = time_path(START, SQUARE, LIMITS)
    for point in SQUARE:
        gaps = np.linalg.norm(path.positions_m - point.bar_position_m, axis=1)
        assert gaps.min() < 0.01
    np.testing.assert_allclose(path.positions_m[-1], START.bar_position_m, atol=1e-9)
    _within_limits(path, LIMITS)
    _consistent(path)
    # A smooth curve: the bends slow it below the speed limit, it never stops between.
    speeds = _speeds(path)
    quarter = len(speeds) // 4
    assert speeds[quarter:-quarter].min() > 0.3


def test_yaw_and_theta_move_between_waypoints_at_bounded_rates() -> None:
    waypoints = [
        Waypoint((2.0, 0.0, 1.5), bar_yaw_rad=math.radians(90.0), theta_l_rad=math.radians(20.0)),
        Waypoint((2.0, 2.0, 1.5)),  # keeps the yaw and θ_l of the point before
    ]
    path = time_path(START, waypoints, LIMITS)
    at_first = np.argmin(np.linalg.norm(path.positions_m - (2.0, 0.0, 1.5), axis=1))
    assert path.yaws_rad[at_first] == pytest.approx(math.radians(90.0), abs=1e-3)
    assert path.thetas_l_rad[at_first] == pytest.approx(math.radians(20.0), abs=1e-3)
    assert path.yaws_rad[-1] == pytest.approx(math.radians(90.0), abs=1e-9)
    assert path.thetas_l_rad[-1] == pytest.approx(math.radians(20.0), abs=1e-9)
    _within_limits(path, LIMITS)
    # 90° at 20°/s takes 4.5 s at least, though the 2 m alone would take 3.
    assert path.duration_s > 4.5


def test_a_yaw_change_takes_the_short_way_round() -> None:
    start = Waypoint((0.0, 0.0, 1.5), math.radians(170.0), 0.0)
    path = time_path(start, [Waypoint((2.0, 0.0, 1.5), math.radians(-170.0))], LIMITS)
    turned = np.unwrap(path.yaws_rad)
    assert turned[-1] - turned[0] == pytest.approx(math.radians(20.0), abs=1e-6)


def test_sampling_interpolates_and_holds_the_ends() -> None:
    path = time_path(START, [Waypoint((1.0, 0.0, 1.5))], LIMITS)
    before, after = path.sample(-1.0), path.sample(path.duration_s + 1.0)
    np.testing.assert_allclose(before.position_m, path.positions_m[0])
    np.testing.assert_allclose(after.position_m, path.positions_m[-1])
    halfway = path.sample(2.5 * SAMPLE_STEP_S)
    np.testing.assert_allclose(
        halfway.position_m, 0.5 * (path.positions_m[2] + path.positions_m[3]), atol=1e-12
    )


@pytest.mark.parametrize(
    ("waypoints", "message"),
    [
        ([], "at least one waypoint"),
        ([Waypoint(START.bar_position_m)], "does not move"),
        ([Waypoint((1.0, 0.0, 1.5)), Waypoint((1.0, 0.0, 1.5))], "waypoint 1 lies on"),
        # Out and back: a smooth curve would have to stop and reverse at the far end.
        ([Waypoint((2.0, 0.0, 1.5)), Waypoint((0.0, 0.0, 1.5))], "turns by 180° at waypoint 0"),
        ([Waypoint((2.0, 0.0, 1.5)), Waypoint((1.0, 0.2, 1.5))], "turns by 169°"),
    ],
)
def test_waypoints_that_make_no_path_are_refused(waypoints: list[Waypoint], message: str) -> None:
    with pytest.raises(PathError, match=message):
        time_path(START, waypoints, LIMITS)


@pytest.mark.parametrize("bad", [0.0, -1.0, math.nan, math.inf])
def test_limits_must_be_positive_numbers(bad: float) -> None:
    with pytest.raises(PathError, match="speed_mps"):
        PathLimits(bad, 1.0, 1.0, 1.0, 1.0)


def test_a_path_longer_than_ten_minutes_is_refused_before_it_is_sampled() -> None:
    slow = PathLimits(0.001, 1.0, 2.0, math.radians(20.0), math.radians(10.0))
    with pytest.raises(PathError, match=r"would take 40\d\d s .*at most 600 s"):
        time_path(START, [Waypoint((4.0, 0.0, 1.5))], slow)


def test_a_right_angle_is_flown_through() -> None:
    path = time_path(START, [Waypoint((1.0, 0.0, 1.5)), Waypoint((1.0, 1.0, 1.5))], LIMITS)
    _within_limits(path, LIMITS)
    assert np.all(np.isfinite(path.accelerations_mps2))
