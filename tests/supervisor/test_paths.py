"""Paths as the tick core flies them: queued and refused like setpoints, flown along their
timing (supervisor/flight/paths.py); the flights themselves are in test_simulation."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.preview import sampled_stages
from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.core import FlightCore
from supervisor.flight.estimation import Estimate
from supervisor.flight.path_timing import PathLimits
from supervisor.flight.paths import PathRunner, plan_path
from supervisor.flight.reference_shaping import RateLimits, ReferenceShaper
from supervisor.flight.setpoints import Setpoint, SetpointError, SetpointRefusedError
from supervisor.flight.waypoint import Waypoint
from tests.conftest import CONFIGS

CONFIG = load_config(CONFIGS / "sim.toml")
PARAMS = CONFIG.system.to_params()
HOVER = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
LIMITS = PathLimits(1.0, 1.0, 2.0, math.radians(20.0), math.radians(10.0))
DT_S = 0.02
STAGES = sampled_stages(30)


def hovering_core() -> FlightCore:
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    x = formation_equilibrium(PARAMS, HOVER).x
    core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
    return core


def path_setpoint(start: FormationReference, to: tuple[float, float, float]) -> Setpoint:
    plan = plan_path(start, [Waypoint(to)], LIMITS)
    end = plan.end()
    return Setpoint(end.payload_position_m, end.payload_yaw_rad, end.uav_yaw_rad, path=plan)


def test_a_path_is_flown_from_its_start_along_its_timing_to_its_end() -> None:
    """The runner first shapes the reference to the path's start (a setpoint before it
    ended elsewhere), then gives the path's samples, the stages ahead with them, and lets
    the shaper follow; at the end the shaper rests on the path's end."""
    start = FormationReference((0.5, 0.0, 1.0), 0.0, (0.0, 0.0))
    setpoint = path_setpoint(start, (1.5, 0.0, 1.0))
    assert setpoint.path is not None
    shaper = ReferenceShaper(HOVER, RateLimits(position_mps=1.0, acceleration_mps2=1.0))
    runner = PathRunner()
    now_s = 0.0
    while runner.progress(now_s) is None:
        assert runner.flying(setpoint, now_s)
        shaped = runner.step(setpoint, shaper, now_s, STAGES, DT_S)
        assert shaped is not None
        reference, ahead = shaped
        # The stages ahead while moving; none once resting on the start.
        assert set(ahead) in (set(), set(STAGES)) and reference.payload_position_m[0] <= 0.5
        now_s += DT_S
        assert now_s < 5.0, "never reached the path's start"
    progress = runner.progress(now_s)
    assert progress is not None
    began_s = now_s - progress[1]
    samples = []
    while (along := runner.step(setpoint, shaper, now_s, STAGES, DT_S)) is not None:
        reference, ahead = along
        t_s = now_s - began_s
        expected = setpoint.path.timed.sample(t_s)
        np.testing.assert_allclose(reference.payload_position_m, expected.position_m)
        np.testing.assert_allclose(reference.velocity_mps, expected.velocity_mps)
        np.testing.assert_allclose(
            ahead[30].payload_position_m, setpoint.path.timed.sample(t_s + 30 * DT_S).position_m
        )
        assert shaper.current == reference
        samples.append(reference.payload_position_m[0])
        now_s += DT_S
    assert samples[0] == pytest.approx(0.5, abs=1e-4) and max(samples) <= 1.5 + 1e-9
    assert not runner.flying(setpoint, now_s)
    assert shaper.current == setpoint.reference(2)


def test_a_path_is_queued_from_where_the_queue_will_be() -> None:
    core = hovering_core()
    core.queue_setpoints([Setpoint((0.5, 0.5, 1.2))])
    queued = core.queue_path([Waypoint((1.0, 1.0, 1.2)), Waypoint((1.5, 0.5, 1.2))], 1.0, 1.0)
    assert queued.path is not None
    assert queued.path.start.payload_position_m == (0.5, 0.5, 1.2)
    assert queued.bar_position_m == pytest.approx((1.5, 0.5, 1.2))
    assert core.queue.queued[-1] is queued


def test_a_path_is_refused_like_a_setpoint() -> None:
    grounded = flight_core_from_config(CONFIG, clock=time.perf_counter)  # disarmed
    with pytest.raises(SetpointRefusedError):
        grounded.queue_path([Waypoint((1.0, 0.0, 1.0))], 1.0, 1.0)
    core = hovering_core()
    with pytest.raises(SetpointError, match="outside the arena"):
        core.queue_path([Waypoint((1.0, 0.0, 1.0)), Waypoint((9.0, 0.0, 1.0))], 1.0, 1.0)
    # 12 m/s² of acceleration tilts the UAVs beyond what any setpoint may ask.
    with pytest.raises(SetpointError, match=r"along the path: .*tilt"):
        core.queue_path([Waypoint((1.5, 0.0, 1.0))], 3.0, 12.0, jerk_mps3=100.0)
    with pytest.raises(SetpointError, match="lies on the point before"):
        core.queue_path([Waypoint((1.0, 0.0, 1.0)), Waypoint((1.0, 0.0, 1.0))], 1.0, 1.0)
    with pytest.raises(SetpointError, match="θ_l"):
        core.queue_path([Waypoint((1.0, 0.0, 1.0), theta_l_rad=math.radians(80.0))], 1.0, 1.0)
    assert not core.queue.queued and core.queue.active is None


def test_a_cleared_path_stops_the_bar_where_it_is() -> None:
    """Clear mid-path: the reference brakes from the path's speed where it was, at the
    path's acceleration, rather than jumping back or stopping dead."""
    core = hovering_core()
    core.queue_path([Waypoint((2.0, 0.0, 1.0))], 1.0, 1.0)
    x = formation_equilibrium(PARAMS, HOVER).x
    now_s, reference = 0.0, None
    for _ in range(150):  # 3 s into a 3-s-odd path
        now_s += DT_S
        result = core.tick(now_s, Estimate(x, 0.005, ()))
        reference = result.reference
    assert reference is not None and reference.velocity_mps[0] > 0.3
    core.clear_setpoints()
    speeds = []
    for _ in range(100):
        now_s += DT_S
        result = core.tick(now_s, Estimate(x, 0.005, ()))
        assert result.reference is not None
        speeds.append(result.reference.velocity_mps[0])
    assert speeds[0] > 0.2 and speeds[-1] == 0.0
    assert np.all(np.diff(speeds) <= 1e-12)
    # Braked at the path's 1 m/s² (the flight rates' 0.3 m/s² would take over 3 s); the
    # trapezoid's last step lands on the stop, a little more in one tick.
    assert np.median(-np.diff(speeds)[: speeds.index(0.0) - 1]) / DT_S == pytest.approx(1.0)
    assert max(-np.diff(speeds)) / DT_S <= 1.5
    assert speeds.index(0.0) * DT_S < 1.5


def test_braking_ends_when_the_target_changes() -> None:
    """A cleared path's braking is allowed the path's acceleration and speed only toward
    its stop: a setpoint queued during it is flown at the flight rates."""
    limits = RateLimits(position_mps=0.3, acceleration_mps2=0.3)
    moving = FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), 0.0, (1.0, 0.0, 0.0))
    shaper = ReferenceShaper(moving, limits)
    shaper.follow(moving, 0.0)
    stop = shaper.stopping_point(1.0)
    assert stop.payload_position_m[0] == pytest.approx(0.5)
    shaper.brake(1.0, stop)
    braked = shaper.update(stop, DT_S)
    assert 1.0 - 1.0 * DT_S - 1e-9 <= braked.velocity_mps[0] < 1.0  # at most 1 m/s²
    elsewhere = FormationReference((3.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    speeds = [shaper.update(elsewhere, DT_S * k).velocity_mps[0] for k in range(2, 200)]
    steps = -np.diff([braked.velocity_mps[0], *speeds])
    assert steps.max() <= 0.3 * DT_S + 1e-12  # the flight rates' 0.3 m/s², not 1 m/s²
    assert speeds[-1] == pytest.approx(0.3)
