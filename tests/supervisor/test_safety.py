"""The swing monitor, its hand-over from the decentralized to the centralized MPC, and the
notices that forced decisions leave."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from geometry.state import payload_points
from supervisor.app.assembly import (
    arena_from_config,
    flight_core_from_config,
    safety_limits_from_config,
)
from supervisor.app.config import ConfigError, load_config
from supervisor.flight.core import NoticeKind
from supervisor.flight.estimation import Estimate, Refusals
from supervisor.flight.modes import Mode
from supervisor.flight.safety import Fault, Response, SafetyLimits, SafetyMonitor, chosen_response
from tests.conftest import CONFIGS

CONFIG = load_config(CONFIGS / "sim.toml")
PARAMS = CONFIG.system.to_params()


def hovering_state(bar_yaw_rad: float) -> np.ndarray:
    """The hover equilibrium with the bar (and its UAVs) turned to ``bar_yaw_rad``."""
    return formation_equilibrium(
        PARAMS, FormationReference((0.0, 0.0, 1.0), bar_yaw_rad, (0.0, 0.0))
    ).x


def swing_faults(
    bar_yaw_deg: float, reference_deg: float, mode: Mode = Mode.HOVER, limit_deg: float = 20.0
) -> list[str]:
    monitor = SafetyMonitor(
        PARAMS,
        arena_from_config(CONFIG),
        SafetyLimits(max_bar_yaw_error_rad=math.radians(limit_deg)),
    )
    estimate = Estimate(hovering_state(math.radians(bar_yaw_deg)), 0.01, ())
    faults = monitor.check(0.0, estimate, mode, None, (True, True), math.radians(reference_deg))
    assert all(f.response is Response.CENTRALIZE for f in faults if f.monitor == "swing")
    return [f.message for f in faults if f.monitor == "swing"]


@pytest.mark.parametrize(
    "bar_yaw_deg, reference_deg, expected",
    [
        (25.0, 0.0, ["bar yaw +25.0° off its reference"]),
        (-21.0, 0.0, ["bar yaw -21.0° off its reference"]),
        (15.0, 0.0, []),
        (-179.0, 179.0, []),  # 2° apart across ±180°
        (160.0, -170.0, ["bar yaw -30.0° off its reference"]),  # 30° apart across ±180°
    ],
)
def test_the_bar_turned_away_from_its_reference_is_a_swing(
    bar_yaw_deg: float, reference_deg: float, expected: list[str]
) -> None:
    assert swing_faults(bar_yaw_deg, reference_deg) == expected


def test_the_swing_monitor_watches_hover_and_tracking_only_and_can_be_off() -> None:
    assert swing_faults(40.0, 0.0, Mode.TRACKING)
    for mode in (Mode.TAKEOFF, Mode.LANDING, Mode.ABORT):
        assert swing_faults(40.0, 0.0, mode) == []
    assert swing_faults(40.0, 0.0, limit_deg=0.0) == []


def test_a_swing_hands_the_decentralized_bar_to_the_centralized_mpc() -> None:
    core = flight_core_from_config(CONFIG, "decentralized", clock=time.thread_time)
    still = Estimate(hovering_state(0.0), 0.01, ())
    core.start_in_hover(still, 0.0, (0.05, 0.1, 0.1))
    assert not core.tick(0.02, still).notices
    assert core.controller == "decentralized"
    swung = Estimate(hovering_state(math.radians(30.0)), 0.01, ())
    result = core.tick(0.04, swung)
    assert core.controller == "centralized"
    assert [str(n) for n in result.notices if n.kind is NoticeKind.SWING] == [
        "swing: bar yaw +30.0° off its reference; switched to the centralized MPC"
    ]
    assert result.mode is Mode.HOVER  # it keeps flying: no abort
    assert list(core.notices) == [(0.04, result.notices[-1])]
    # The centralized MPC meets the same swing with the fault reported, nothing switched.
    again = core.tick(0.06, swung)
    assert [f.monitor for f in again.faults] == ["swing"] and core.controller == "centralized"
    assert not again.notices


def test_the_hand_over_angle_is_a_setting() -> None:
    default = safety_limits_from_config(CONFIG).max_bar_yaw_error_rad
    assert default == pytest.approx(math.radians(20.0))
    off = load_config(CONFIGS / "sim.toml", ["safety.max_bar_yaw_error_deg=0"])
    assert safety_limits_from_config(off).max_bar_yaw_error_rad == 0.0
    for bad in ("-5", "180", "nan"):
        with pytest.raises(ConfigError, match=r"safety\.max_bar_yaw_error_deg"):
            load_config(CONFIGS / "sim.toml", [f"safety.max_bar_yaw_error_deg={bad}"])


def test_a_forced_abort_is_kept_as_a_notice() -> None:
    core = flight_core_from_config(CONFIG, "centralized", clock=time.thread_time)
    core.start_in_hover(Estimate(hovering_state(0.0), 0.01, ()), 0.0, (0.05, 0.1, 0.1))
    outside = hovering_state(0.0)
    outside[0:3] += (50.0, 0.0, 0.0)  # the bar far outside the arena
    result = core.tick(0.02, Estimate(outside, 0.01, ()))
    assert result.mode is Mode.ABORT
    [(when, notice)] = core.notices
    assert when == 0.02 and notice.kind is NoticeKind.ABORT
    assert str(notice).startswith("abort: ") and "bar left the arena" in str(notice)


def test_the_most_severe_response_is_chosen() -> None:
    coast = Fault("mocap", "uav1 stale", Response.COAST)
    swing = Fault("swing", "bar yaw +30°", Response.CENTRALIZE)
    fence = Fault("geofence", "bar left the arena", Response.ABORT)
    assert chosen_response([]) is None
    assert chosen_response([coast]) is Response.COAST
    assert chosen_response([coast, swing]) is Response.CENTRALIZE
    assert chosen_response([swing, fence, coast]) is Response.ABORT


def test_one_link_lost_asks_the_other_to_land_both_lost_hands_over_to_px4() -> None:
    monitor = SafetyMonitor(PARAMS, arena_from_config(CONFIG))
    estimate = Estimate(hovering_state(0.0), 0.005, ())
    for connected, response, message in (
        ((False, True), Response.LAND_OTHER, "vehicle 1 link lost"),
        ((True, False), Response.LAND_OTHER, "vehicle 2 link lost"),
        ((False, False), Response.PX4_LAND, "both vehicle links lost"),
    ):
        [fault] = monitor.check(0.0, estimate, Mode.HOVER, None, connected)
        assert (fault.monitor, fault.message, fault.response) == ("link", message, response)
    assert monitor.check(0.0, estimate, Mode.HOVER, None, (True, True)) == []
    land_other = Fault("link", "vehicle 1 link lost", Response.LAND_OTHER)
    abort = Fault("tilt", "UAV 2 tilted", Response.ABORT)
    assert chosen_response([abort, land_other]) is Response.LAND_OTHER


def test_a_run_of_refused_poses_in_flight_hands_over_to_px4_and_names_why() -> None:
    core = flight_core_from_config(CONFIG, "centralized", clock=time.thread_time)
    limit = core.safety.limits.max_refused_poses
    assert limit == CONFIG.safety.max_refused_poses == 10
    core.start_in_hover(Estimate(hovering_state(0.0), 0.01, ()), 0.0, (0.05, 0.1, 0.1))
    why = "1.000 m from its prediction, 0.004 m reachable in 90 ms"
    short = Estimate(hovering_state(0.0), 0.01, (), (Refusals("uav1", limit - 1, why),))
    assert core.tick(0.02, short).mode is Mode.HOVER
    run = Estimate(hovering_state(0.0), 0.01, (), (Refusals("uav1", limit, why),))
    result = core.tick(0.04, run)
    assert result.mode is Mode.PX4_LANDING
    [notice] = result.notices
    assert notice.kind is NoticeKind.BLIND
    assert notice.text.startswith(f"uav1: {limit} poses in a row refused ({why})")


def test_repeated_frames_are_refused_only_while_the_bodies_move() -> None:
    """On the ground a resting system may repeat itself exactly (no noise): not refused."""
    core = flight_core_from_config(CONFIG, "centralized", clock=time.thread_time)
    assert not core.bodies_in_motion  # disarmed
    core.start_in_hover(Estimate(hovering_state(0.0), 0.01, ()), 0.0, (0.05, 0.1, 0.1))
    assert core.bodies_in_motion


def slack_state(shorter_m: float) -> np.ndarray:
    """The hover equilibrium with UAV 1 moved ``shorter_m`` along its cable towards the bar."""
    x = hovering_state(0.0)
    end = payload_points(x, PARAMS.payload.attachments_m)[0]
    position = PARAMS.layout.uav_slices(1)[0]
    direction = x[position] - end
    x[position] -= shorter_m * direction / np.linalg.norm(direction)
    return x


def first_slack_abort(episode_s: float, period_s: float, duration_s: float) -> float | None:
    """Ticks at 50 Hz in hover with cable 1 slack (8 cm) for ``episode_s`` every
    ``period_s``: when the slack monitor first aborts (None: never)."""
    monitor = SafetyMonitor(PARAMS, arena_from_config(CONFIG), safety_limits_from_config(CONFIG))
    taut, slack = hovering_state(0.0), slack_state(0.08)
    for k in range(round(duration_s / 0.02)):
        now_s = k * 0.02
        x = slack if (now_s % period_s) < episode_s - 1e-9 else taut
        faults = monitor.check(now_s, Estimate(x, 0.01, ()), Mode.HOVER, None, (True, True))
        if any(f.monitor == "slack" and f.response is Response.ABORT for f in faults):
            return now_s
    return None


def test_intermittent_slack_adds_up_to_an_abort() -> None:
    """0.2 s episodes every 2 s never reach the 0.5 s of one episode; three of them add up
    to 0.5 s within the 10 s window (the first abort during the third)."""
    aborted_s = first_slack_abort(0.2, 2.0, 30.0)
    assert aborted_s is not None and 4.0 < aborted_s < 4.2


def test_rare_short_slack_and_a_single_episode_below_the_limit_do_not_abort() -> None:
    assert first_slack_abort(0.1, 5.0, 60.0) is None  # 0.2 s in any 10 s
    assert first_slack_abort(0.4, 1000.0, 20.0) is None  # one 0.4 s episode
    assert first_slack_abort(0.0, 1.0, 20.0) is None  # taut throughout


def test_one_long_slack_episode_aborts_naming_the_cable() -> None:
    monitor = SafetyMonitor(PARAMS, arena_from_config(CONFIG), SafetyLimits())
    estimate = Estimate(slack_state(0.08), 0.01, ())
    messages = []
    for k in range(30):
        faults = monitor.check(k * 0.02, estimate, Mode.TRACKING, None, (True, True))
        messages += [f.message for f in faults if f.monitor == "slack"]
    assert messages[0] == "cable 1 slack for 0.50 s"  # tick 25: 0.5 s after the first
    assert len(messages) == 5


def test_a_stall_is_not_counted_as_slack() -> None:
    """Two ticks 3 s apart, both slack: at most 0.2 s (twice the coast limit) is added."""
    limits = SafetyLimits(slack_time_s=10.0)
    monitor = SafetyMonitor(PARAMS, arena_from_config(CONFIG), limits)
    estimate = Estimate(slack_state(0.08), 0.01, ())
    for now_s in (0.0, 3.0, 3.2):
        faults = monitor.check(now_s, estimate, Mode.HOVER, None, (True, True))
    assert [f.message for f in faults if f.monitor == "slack"] == []
    faults = monitor.check(3.4, estimate, Mode.HOVER, None, (True, True))
    assert [f.message for f in faults] == [
        "cables slack 0.60 s in all within the last 10 s (cable 1 now)"
    ]
