"""The status model: what the flight process builds for N vehicles survives the channel as
its type; a non-finite number is null; a status that does not fit is refused, by field."""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
import pydantic
import pytest

from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.core import TickResult
from supervisor.flight.modes import Mode
from supervisor.flight.status import FlightStatus, Status
from supervisor.flight.telemetry import MocapView, ShellView, build_telemetry
from supervisor.flight.waypoint import Waypoint
from supervisor.ipc.messages import CHANNEL_MESSAGE, TelemetryMessage
from supervisor.runtime.scheduler import TimingStats
from supervisor.simulate.closed_loop import ClosedLoop
from supervisor.simulate.scenarios import load_scenario, scenario_config
from supervisor.vehicles.types import VehicleView
from tests.conftest import CONFIGS, resting_estimate
from tests.status_examples import status_json

MOCAP = MocapView(connected=True, rate_hz=100.0, frames=10, dropped=0, server="h:22223")


def flight_status(setup: str, resting: bool = True) -> FlightStatus:
    """What the flight process of ``setup`` publishes, its vehicles heard and disarmed:
    resting on the ground, or before any estimate (``resting`` False)."""
    config = load_config(CONFIGS / setup)
    params = config.system.to_params()
    core = flight_core_from_config(config, clock=time.perf_counter)
    estimate = resting_estimate(params) if resting else None
    if estimate is not None:
        core.tick(0.0, estimate)
    vehicles = (VehicleView(connected=True, armed=False, px4_mode="POSCTL"),) * params.n_vehicles
    shell = ShellView(streaming=False, live_view_port=8766)
    return build_telemetry(
        core, estimate, None, vehicles, MOCAP, TimingStats().summary(), shell, 1.0
    )


@pytest.mark.parametrize(
    ("setup", "n"), [("sim.toml", 2), ("sim_tri.toml", 3), ("sim_quad.toml", 4)]
)
def test_the_status_of_n_vehicles_survives_the_channel_as_its_type(setup: str, n: int) -> None:
    status = flight_status(setup)
    assert len(status.uavs) == len(status.armed) == len(status.bar.ends) == n
    assert status.arm_blocked_by is None and status.mocap.healthy
    sent = TelemetryMessage(status=status)
    received = CHANNEL_MESSAGE.validate_json(sent.model_dump_json())
    assert isinstance(received, TelemetryMessage) and received.status == status
    assert received.status.live_view is not None and received.status.live_view.sdk_port == 8766


HOVER_SCENARIO = """
name = "hover"
start = "hover"
start_bar_position = [0.0, 0.0, 1.0]

[[step]]
bar_position = [0.2, 0.0, 1.1]
hold_s = 1.0
"""


def hovering(
    setup: str, folder: Path, extra: str = "", overrides: tuple[str, ...] = ()
) -> ClosedLoop:
    """The closed-loop simulator of ``setup`` hovering under the MPC, before its first tick
    (``extra``: more of the scenario, e.g. a load)."""
    path = folder / "hover.toml"
    path.write_text(HOVER_SCENARIO + extra)
    scenario = load_scenario(str(path))
    config = load_config(CONFIGS / setup, list(overrides))
    loop = ClosedLoop(scenario_config(config, scenario), "centralized", 1)
    loop.place(scenario)
    loop.advance_plant(0.2)
    loop.core.start_in_hover(loop.estimate(), loop.now_s, loop.resting_heights())
    return loop


def in_flight(loop: ClosedLoop, result: TickResult) -> FlightStatus:
    """What the flight process publishes after ``result``, its vehicles armed in offboard."""
    n = loop.core.params.n_vehicles
    vehicles = (VehicleView(connected=True, armed=True, px4_mode="OFFBOARD"),) * n
    shell = ShellView(streaming=True, log_path="/var/log/uavbar/flight-1.mcap")
    summary = TimingStats().summary()
    return build_telemetry(
        loop.core, loop.estimate(), result, vehicles, MOCAP, summary, shell, loop.now_s
    )


@pytest.mark.parametrize("setup", ["sim.toml", "sim_tri.toml"])
def test_a_status_in_flight_survives_the_channel_with_its_plan_and_reference(
    setup: str, tmp_path: Path
) -> None:
    """Hovering on the plant under the MPC (a few ticks of the closed-loop simulator)."""
    loop = hovering(setup, tmp_path)
    status = in_flight(loop, loop.decide())
    n = loop.core.params.n_vehicles
    assert status.mode is Mode.HOVER and status.plan.status is not None
    assert status.plan.thrust_n is not None and len(status.plan.thrust_n) == n
    assert status.reference is not None and len(status.reference.uav_positions) == n
    assert status.bar.error_m is not None and status.bar.error_m < 0.05
    received = CHANNEL_MESSAGE.validate_json(TelemetryMessage(status=status).model_dump_json())
    assert isinstance(received, TelemetryMessage) and received.status == status
    assert status.path is None  # hovering at a setpoint without one


def test_a_path_flown_is_in_the_status_with_its_points_and_how_long_since_it_began(
    tmp_path: Path,
) -> None:
    """Hovering on the plant: a path queued is not in the status until it is the active
    setpoint; then its waypoints, limits and timing, its points every 0.25 s from the bar's
    hover to its last waypoint (for drawing), and the time since it began, which grows with
    the ticks. It survives the channel."""
    loop = hovering("sim.toml", tmp_path)

    def tick() -> FlightStatus:
        result = loop.decide()
        loop.apply(result)
        loop.driver.finish(result)
        status = in_flight(loop, result)
        loop.advance_plant(loop.now_s + 0.02)
        return status

    tick()
    waypoints = [Waypoint((0.6, 0.0, 1.0)), Waypoint((0.6, 0.5, 1.2), bar_yaw_rad=0.3)]
    queued = loop.core.queue_path(waypoints, speed_mps=0.4, accel_mps2=0.5, hold_s=1.0)
    assert queued.path is not None
    timed = queued.path.timed
    elapsed = []
    for _ in range(50):  # 1 s of flight
        status = tick()
        assert status.path is not None, "the path is the active setpoint from the first tick"
        elapsed.append(status.path.elapsed_s)
    shown = status.path
    assert shown is not None
    assert shown.waypoints == [[0.6, 0.0, 1.0], [0.6, 0.5, 1.2]]
    assert (shown.speed_mps, shown.accel_mps2, shown.jerk_mps3) == (0.4, 0.5, 2.0)
    assert (shown.length_m, shown.duration_s) == (timed.length_m, timed.duration_s)
    assert 4.0 < shown.duration_s < 20.0, shown.duration_s
    every_quarter_second = [*timed.positions_m[:-1:25], timed.positions_m[-1]]  # and its end
    assert shown.points == np.round(every_quarter_second, 3).tolist()  # to the millimetre
    assert shown.points[0] == pytest.approx([0.0, 0.0, 1.0], abs=0.01)  # from the hover
    assert shown.points[-1] == [0.6, 0.5, 1.2]
    begun = [t for t in elapsed if t is not None]
    assert begun == sorted(begun) and 0.9 < begun[-1] <= 1.0, elapsed
    received = CHANNEL_MESSAGE.validate_json(TelemetryMessage(status=status).model_dump_json())
    assert isinstance(received, TelemetryMessage) and received.status == status


PUSH = """
[[load]]
body = "bar"
force_n = [1.5, 0.0, 0.0]
"""


def test_the_loads_the_observer_estimates_are_in_the_status(tmp_path: Path) -> None:
    """Hovering with a steady 1.5 N push on the bar: after 3 s the status's loads carry
    it (the split with the UAVs below is not unique, so the net force is what is checked),
    none at the observer's bound, and survive the channel; with the observer off they are
    null."""
    loop = hovering("sim.toml", tmp_path, PUSH)
    scenario = load_scenario(str(tmp_path / "hover.toml"))
    for load in scenario.load:
        loop.plant.add_load(load.external_load())
    for _ in range(150):
        result = loop.decide()
        loop.apply(result)
        loop.driver.finish(result)
        loop.advance_plant(loop.now_s + 0.02)
    status = in_flight(loop, result)
    assert status.loads is not None and status.loads.at_bound == []
    bodies = [status.loads.bar_force_n, *status.loads.uav_forces_n]
    net = np.sum([[c if c is not None else math.nan for c in body] for body in bodies], axis=0)
    assert net == pytest.approx([1.5, 0.0, 0.0], abs=0.3)
    received = CHANNEL_MESSAGE.validate_json(TelemetryMessage(status=status).model_dump_json())
    assert isinstance(received, TelemetryMessage) and received.status == status
    off = hovering("sim.toml", tmp_path, PUSH, ("mpc.force_observer_s=0",))
    assert in_flight(off, off.decide()).loads is None


def test_what_is_not_known_is_null_never_nan() -> None:
    """No estimate yet: no position, no yaw, no estimate age; no tick: no percentiles."""
    status = flight_status("sim.toml", resting=False)
    assert status.bar.position == [None, None, None] and status.bar.yaw is None
    assert all(uav.position == [None, None, None] for uav in status.uavs)
    assert status.mocap.age_ms is None and status.tick.compute_ms_p50 is None
    text = status.model_dump_json()
    assert "NaN" not in text and '"position":[null,null,null]' in text
    again = FlightStatus.model_validate_json(text)
    assert again == status


def test_a_non_finite_number_is_made_null_where_a_number_may_be_unknown() -> None:
    bar = status_json()["bar"] | {"yaw": math.nan, "error_m": math.inf}
    status = Status.model_validate(status_json(bar=bar))
    assert status.bar.yaw is None and status.bar.error_m is None


@pytest.mark.parametrize(
    ("changes", "where", "words"),
    [
        ({"mode": "hovering"}, "mode", "Input should be"),
        ({"armed": [False]}, "armed", "at least 2 items"),
        ({"armed": [False] * 9}, "armed", "at most 8 items"),
        ({"armed": [False] * 3}, "", "armed has 3 entries for 2 uavs"),
        ({"time_s": "12.5"}, "time_s", "Input should be a valid number"),
        ({"armed": [0, 1]}, "armed.0", "Input should be a valid boolean"),
        ({"mode_for_s": math.nan}, "mode_for_s", "finite number"),
        ({"surprise": 1}, "surprise", "Extra inputs are not permitted"),
    ],
)
def test_a_status_that_does_not_fit_is_refused_by_field(
    changes: dict[str, object], where: str, words: str
) -> None:
    with pytest.raises(pydantic.ValidationError) as refused:
        Status.model_validate(status_json(**changes))
    problems = {".".join(str(part) for part in e["loc"]): e["msg"] for e in refused.value.errors()}
    assert any(loc == where and words in msg for loc, msg in problems.items()), problems


def test_a_missing_field_is_named() -> None:
    body = status_json()
    del body["bar"]["position"]
    with pytest.raises(pydantic.ValidationError) as refused:
        Status.model_validate(body)
    assert [e["loc"] for e in refused.value.errors()] == [("bar", "position")]
