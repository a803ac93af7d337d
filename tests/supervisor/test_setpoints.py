"""Setpoints: geofence and feasibility before queuing; hold logic; rate-limited reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from supervisor.flight.feasibility import FeasibilitySettings, SetpointBounds
from supervisor.flight.reference_shaping import RateLimits, ReferenceShaper
from supervisor.flight.setpoints import (
    Arena,
    Setpoint,
    SetpointError,
    SetpointQueue,
    validate_setpoint,
)

ARENA = Arena((-3.0, -3.0, 0.0), (3.0, 3.0, 3.0))
# configs/kth_sml.toml's thrust range and the safety monitor's abort tilt, default margins.
BOUNDS = SetpointBounds(0.5, 26.0, math.radians(45.0))


def test_a_good_setpoint_passes(lab_params: FormationParams) -> None:
    validate_setpoint(
        Setpoint((0.0, 0.0, 1.0), 0.5, theta_l_rad=math.radians(45)), lab_params, ARENA, BOUNDS
    )


@pytest.mark.parametrize("theta_l_deg", [85.0, 86.0, 89.0, 89.99])
def test_theta_l_above_the_maximum_is_refused_by_how_much(
    lab_params: FormationParams, theta_l_deg: float
) -> None:
    setpoint = Setpoint((0.0, 0.0, 1.0), theta_l_rad=math.radians(theta_l_deg))
    excess = theta_l_deg - 75.0
    with pytest.raises(SetpointError, match=f"exceeds the maximum 75.0° by {excess:.1f}°"):
        validate_setpoint(setpoint, lab_params, ARENA, BOUNDS)


def test_an_equilibrium_tilted_beyond_the_abort_tilt_less_its_margin_is_refused(
    lab_params: FormationParams,
) -> None:
    """θ_l allowed up to 89°: at 80° the UAVs tilt ~39.5°, above 45° − 10°."""
    bounds = SetpointBounds(0.5, 26.0, math.radians(45.0), FeasibilitySettings(math.radians(89)))
    setpoint = Setpoint((0.0, 0.0, 1.5), theta_l_rad=math.radians(80.0))
    eq = formation_equilibrium(lab_params, setpoint.reference(2))
    excess = math.degrees(eq.tilts_rad[1]) - 35.0
    assert 0.0 < excess < 10.0
    with pytest.raises(SetpointError) as refused:
        validate_setpoint(setpoint, lab_params, ARENA, bounds)
    assert "thrust" not in str(refused.value)  # 17 N: well inside 26 N less 10 %
    assert (
        f"UAV 2's equilibrium tilt {math.degrees(eq.tilts_rad[1]):.1f}° is above the 45.0°"
        f" abort tilt less its 10.0° margin (35.0°) by {excess:.1f}°" in str(refused.value)
    )
    # Just below the bound it is taken: the check is the bound itself, not a table.
    loose = SetpointBounds(0.5, 26.0, math.radians(45.0 + excess + 0.01), bounds.settings)
    validate_setpoint(setpoint, lab_params, ARENA, loose)


def test_an_equilibrium_thrust_beyond_the_range_less_its_margin_is_refused(
    lab_params: FormationParams,
) -> None:
    """A 14 N thrust limit less 10 % is 12.6 N: hovering with the bar already needs 13.2 N."""
    bounds = SetpointBounds(0.5, 14.0, math.radians(45.0))
    setpoint = Setpoint((0.0, 0.0, 1.0))
    eq = formation_equilibrium(lab_params, setpoint.reference(2))
    with pytest.raises(SetpointError) as refused:
        validate_setpoint(setpoint, lab_params, ARENA, bounds)
    for k in (0, 1):
        assert (
            f"UAV {k + 1}'s equilibrium thrust {eq.thrusts_n[k]:.1f} N is above the 14.0 N limit"
            f" less its 10 % margin (12.6 N) by {eq.thrusts_n[k] - 12.6:.1f} N"
        ) in str(refused.value)
    assert "tilt" not in str(refused.value)
    roomy = SetpointBounds(0.5, max(eq.thrusts_n) / 0.9 + 1e-6, math.radians(45.0))
    validate_setpoint(setpoint, lab_params, ARENA, roomy)


def test_an_equilibrium_thrust_below_the_range_plus_its_margin_is_refused(
    lab_params: FormationParams,
) -> None:
    bounds = SetpointBounds(14.0, 30.0, math.radians(45.0))  # band 17..27 N
    with pytest.raises(SetpointError, match=r"below the 14.0 N minimum plus its 10 % margin"):
        validate_setpoint(Setpoint((0.0, 0.0, 1.0)), lab_params, ARENA, bounds)


def test_the_paper_s_setpoints_are_taken_under_the_default_bounds(
    lab_params: FormationParams,
) -> None:
    """Section VII flies θ_l up to 45° (the paper's sequence: configs/scenarios/paper.toml);
    the issue's large-θ_l flights ramp to 70°."""
    for theta_l_deg in (0.0, 45.0, 70.0, 75.0):
        setpoint = Setpoint((0.0, 0.0, 1.0), theta_l_rad=math.radians(theta_l_deg))
        validate_setpoint(setpoint, lab_params, ARENA, BOUNDS)


@pytest.mark.parametrize(
    ("setpoint", "message"),
    [
        (Setpoint((0.0, 0.0, 2.5)), "UAV 1"),  # UAVs 1 m above the bar hit the ceiling
        (Setpoint((2.6, 0.0, 1.0)), "bar end 2"),  # the bar sticks out of the arena
        (Setpoint((0.0, 0.0, 1.0), theta_l_rad=math.radians(95)), "θ_l 95.0° exceeds"),
        (Setpoint((0.0, 0.0, 1.0), theta_l_rad=math.radians(-5)), "cone angle"),
        (Setpoint((math.nan, 0.0, 1.0)), "finite"),
        (Setpoint((0.0, 0.0, 1.0), hold_s=-1.0), "hold_s"),
    ],
)
def test_bad_setpoints_are_refused_with_the_reason(
    setpoint: Setpoint, message: str, lab_params: FormationParams
) -> None:
    with pytest.raises(SetpointError, match=message):
        validate_setpoint(setpoint, lab_params, ARENA, BOUNDS)


def test_queue_holds_each_setpoint_then_moves_on() -> None:
    queue = SetpointQueue(capacity=3)
    a, b = Setpoint((0, 0, 1), hold_s=2.0), Setpoint((1, 0, 1), hold_s=0.0)
    queue.extend([a, b])
    assert queue.update(False, 0.0) is a
    assert queue.update(True, 1.0) is a  # reached, holding
    assert queue.update(False, 1.5) is a  # left the tolerance: the hold restarts
    assert queue.update(True, 2.0) is a
    assert queue.update(True, 4.0) is b  # held 2 s
    assert queue.update(True, 4.02) is None and queue.active is None


def test_queue_is_bounded_and_all_or_nothing() -> None:
    queue = SetpointQueue(capacity=2)
    queue.extend([Setpoint((0, 0, 1))])
    with pytest.raises(SetpointError, match="at most 2"):
        queue.extend([Setpoint((0, 0, 1)), Setpoint((0, 0, 1))])
    assert len(queue.queued) == 1


def test_reference_moves_at_bounded_rates() -> None:
    limits = RateLimits(position_mps=0.5, yaw_radps=1.0, theta_l_radps=0.2)
    shaper = ReferenceShaper(FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)), limits)
    target = FormationReference((1.0, 0.0, 1.0), math.pi / 2, (math.pi / 2, -math.pi / 2), 0.5)
    previous = shaper.update(target, 0.0)
    for k in range(1, 200):
        ref = shaper.update(target, 0.02 * k)
        assert (
            np.linalg.norm(np.subtract(ref.payload_position_m, previous.payload_position_m))
            <= 0.5 * 0.02 + 1e-12
        )
        assert abs(ref.payload_yaw_rad - previous.payload_yaw_rad) <= 1.0 * 0.02 + 1e-12
        assert abs(ref.cone_angle_rad - previous.cone_angle_rad) <= 0.2 * 0.02 + 1e-12
        previous = ref
    assert previous == target  # reached exactly, no overshoot


def test_yaw_takes_the_short_way_round() -> None:
    shaper = ReferenceShaper(FormationReference((0.0, 0.0, 1.0), math.radians(170), (0.0, 0.0)))
    shaper.update(FormationReference((0.0, 0.0, 1.0), math.radians(-170), (0.0, 0.0)), 0.0)
    ref = shaper.update(FormationReference((0.0, 0.0, 1.0), math.radians(-170), (0.0, 0.0)), 0.1)
    assert ref.payload_yaw_rad > math.radians(170)  # through 180°, not back through 0°


def test_queue_gives_up_on_a_setpoint_after_its_timeout() -> None:
    queue = SetpointQueue()
    a, b = Setpoint((0, 0, 1), hold_s=2.0, timeout_s=5.0), Setpoint((1, 0, 1))
    queue.extend([a, b])
    assert queue.update(False, 10.0) is a
    assert queue.update(True, 14.0) is a  # reached late: holding
    assert queue.update(True, 15.0) is b  # 5 s since it started, held or not
    assert queue.timed_out == 1
    assert queue.update(False, 100.0) is b  # no timeout: waits as long as it takes


def test_reference_accelerates_gently_and_carries_its_velocity() -> None:
    limits = RateLimits(position_mps=0.4, acceleration_mps2=0.5)
    shaper = ReferenceShaper(FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)), limits)
    target = FormationReference((1.0, 1.0, 1.5), 0.0, (0.0, 0.0))
    dt = 0.02
    positions, velocities = [], []
    for k in range(300):
        ref = shaper.update(target, dt * k)
        positions.append(ref.payload_position_m)
        velocities.append(ref.velocity_mps)
    p, v = np.array(positions), np.array(velocities)
    speed = np.linalg.norm(v, axis=1)
    assert speed.max() <= 0.4 + 1e-12
    assert speed.max() > 0.39  # long enough a move to cruise
    changes = np.linalg.norm(np.diff(v, axis=0), axis=1)
    stop = int(np.argmax(speed[1:] == 0.0))  # the tick it lands on the target
    assert changes[:stop].max() <= 0.5 * dt + 1e-12
    assert changes[stop] <= 2 * 0.5 * dt  # the last, slow step onto the target
    # The velocity it carries is the one it moves with.
    np.testing.assert_allclose(np.diff(p, axis=0)[:stop], v[1 : stop + 1] * dt, atol=1e-12)
    assert positions[-1] == target.payload_position_m and velocities[-1] == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("feed", [True, False])
def test_reference_carries_its_profiles_acceleration_when_fed(feed: bool) -> None:
    """Fed, the acceleration is the velocity's change over the step just taken: the bound
    along the move while speeding up, zero cruising, against it slowing down, zero held;
    not fed, always zero."""
    limits = RateLimits(position_mps=0.4, acceleration_mps2=0.5)
    start = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    shaper = ReferenceShaper(start, limits, feed_acceleration=feed)
    target = FormationReference((1.0, 1.0, 1.5), 0.0, (0.0, 0.0))
    dt = 0.02
    velocities, accelerations = [np.zeros(3)], []
    for k in range(300):
        ref = shaper.update(target, dt * k)
        velocities.append(np.array(ref.velocity_mps))
        accelerations.append(np.array(ref.acceleration_mps2))
    a = np.array(accelerations)
    if not feed:
        assert not a.any()
        return
    moving = [k for k in range(1, 300) if velocities[k + 1].any()]
    np.testing.assert_allclose(a[moving], (np.diff(velocities, axis=0)[moving]) / dt, atol=1e-9)
    direction = np.array([1.0, 1.0, 0.5]) / 1.5
    along = a @ direction
    assert along.max() == pytest.approx(0.5) and along.min() == pytest.approx(-0.5)
    assert not a[-1].any()  # held on the target


def test_a_turn_through_180_degrees_lands_on_the_target_itself() -> None:
    shaper = ReferenceShaper(FormationReference((0.0, 0.0, 1.0), math.radians(170), (0.0, 0.0)))
    target = FormationReference((0.0, 0.0, 1.0), math.radians(-170), (0.0, 0.0))
    for k in range(100):
        ref = shaper.update(target, 0.02 * k)
    assert ref == target  # not 190°: "reached" compares references


def test_a_turning_reference_carries_its_turn_rates() -> None:
    limits = RateLimits(yaw_radps=0.5)
    shaper = ReferenceShaper(FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)), limits)
    target = FormationReference((0.0, 0.0, 1.0), 1.0, (1.0, -1.0))
    shaper.update(target, 0.0)
    turning = shaper.update(target, 0.02)
    assert turning.payload_yaw_rate_radps == pytest.approx(0.5)
    assert turning.uav_yaw_rates_radps == pytest.approx((0.5, -0.5))
    for k in range(2, 200):
        ref = shaper.update(target, 0.02 * k)
    assert ref == target and ref.payload_yaw_rate_radps == 0.0
    assert ref.uav_yaw_rates_radps == (0.0, 0.0)


def test_a_reference_moving_its_theta_l_carries_the_rate() -> None:
    shaper = ReferenceShaper(
        FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)), RateLimits(theta_l_radps=0.2)
    )
    target = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), 0.5)
    shaper.update(target, 0.0)
    assert shaper.update(target, 0.02).cone_angle_rate_radps == pytest.approx(0.2)
    for k in range(2, 200):
        ref = shaper.update(target, 0.02 * k)
    assert ref == target and ref.cone_angle_rate_radps == 0.0
