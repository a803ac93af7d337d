"""The tick core's operator checks (the flights themselves: test_simulation, test_service)."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from geometry.state import P_B, PAYLOAD_PITCH
from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.core import CoreSettings
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import Event, Mode
from supervisor.flight.safety import SafetyLimits
from supervisor.flight.setpoints import Setpoint, SetpointRefusedError
from tests.conftest import CONFIGS, resting_estimate

CONFIG = load_config(CONFIGS / "sim.toml")
LAYOUT = CONFIG.system.to_params().layout


def test_take_off_needs_every_body_measured_and_fresh() -> None:
    x = resting_estimate(CONFIG.system.to_params()).x
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    nan = x.copy()
    nan[LAYOUT.uav_slices(1)[0]] = np.nan  # UAV 1 never seen
    for estimate in (Estimate(nan, 0.01, ("uav1",)), Estimate(x, 0.5, ("bar",))):
        core = flight_core_from_config(CONFIG, clock=time.perf_counter)
        core.tick(0.0, estimate)
        refused = core.request(Event.ARM, 0.0)
        assert not refused.accepted and "motion capture" in refused.reason
        core.tick(0.02, Estimate(x, 0.005, ()))
        assert core.request(Event.ARM, 0.02).accepted  # armed on fresh mocap, then lost
        core.tick(0.04, estimate)
        refused = core.request(Event.TAKEOFF, 0.04)
        assert not refused.accepted and "motion capture" in refused.reason
        assert core.modes.mode is Mode.ARMED
    # One dropped frame (the newest sample of a body untracked, 20 ms old) is no reason.
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.tick(0.0, Estimate(x, 0.02, ("uav2",)))
    core.request(Event.ARM, 0.0)
    assert core.request(Event.TAKEOFF, 0.02).accepted


def test_mocap_lost_beyond_the_coast_limit_hands_the_vehicles_to_px4s_landing() -> None:
    """A gap within the coast limit is flown through; beyond it, the core stops commanding
    (the flight process streams nothing in ``px4_landing``) and says so; then nothing moves
    it but both PX4s having landed."""
    params = CONFIG.system.to_params()
    x = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
    coast_s = SafetyLimits().mocap_coast_s
    for k, age_s in enumerate((0.02, 0.06, coast_s - 0.005)):
        result = core.tick(0.02 * (k + 1), Estimate(x, age_s, ("bar", "uav1", "uav2")))
        assert result.mode is Mode.HOVER and not result.notices
    result = core.tick(0.1, Estimate(x, coast_s + 0.02, ("bar", "uav1", "uav2")))
    assert result.mode is Mode.PX4_LANDING and result.phase.value == "px4"
    [notice] = result.notices
    assert notice.kind == "blind" and "each PX4 lands on its own" in notice.text
    for now_s in (0.12, 0.14):  # mocap back, a fault, an abort: still PX4's landing
        result = core.tick(now_s, Estimate(x, 0.005, ()))
        assert result.mode is Mode.PX4_LANDING and not any(c.motors_on for c in result.commands)
    assert core.request(Event.ABORT, 0.15).accepted and core.modes.mode is Mode.PX4_LANDING
    assert not core.request(Event.LAND, 0.15).accepted
    core.vehicles_landed(0.2)
    assert core.modes.mode.value == "disarmed"


def test_arming_needs_the_resting_pose_a_take_off_starts_from() -> None:
    """Each UAV by its own bar end, the bar level, the UAVs upright, and the hover the
    take-off goes to one the setpoint queue would take; the refusal says what is wrong, and
    nothing changes."""
    params = CONFIG.system.to_params()
    x = resting_estimate(params).x
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    displaced, tilted, tipped, on_a_shelf = x.copy(), x.copy(), x.copy(), x.copy()
    displaced[LAYOUT.uav_slices(1)[0]][0] += 1.0
    tilted[LAYOUT.uav_slices(2)[2]][0] = math.radians(30.0)
    tipped[PAYLOAD_PITCH] = math.radians(10.0)
    for i in LAYOUT.vehicles:  # 1.2 m up: its hover would put the UAVs above the arena's 3 m
        on_a_shelf[LAYOUT.uav_slices(i)[0]][2] += 1.2
    on_a_shelf[P_B][2] += 1.2
    for pose, words in (
        (displaced, "UAV 1 stands 1.00 m from its bar end"),
        (tilted, "UAV 2 is tilted 30°"),
        (tipped, "the bar is not level"),
        (on_a_shelf, "the take-off's hover 1.00 m above cannot be flown: UAV 1 would be at"),
    ):
        core.tick(0.0, Estimate(pose, 0.005, ()))
        refused = core.request(Event.ARM, 0.0)
        assert not refused.accepted and words in refused.reason, refused.reason
        assert core.modes.mode is Mode.DISARMED
    core.tick(0.02, Estimate(x, 0.005, ()))
    assert core.request(Event.ARM, 0.02).accepted


def test_one_link_lost_leaves_that_vehicle_to_px4_and_the_other_sets_its_bar_end_down() -> None:
    """Vehicle 1 lost in a hover: abort in phase ``set_down`` on the decentralized MPC, a
    notice; vehicle 1 is never commanded again, even with its link back; UAV 2's reference
    lowers its bar end, accelerating to the abort rate (the bar level) and carrying that
    descent as its velocity. Both lost: the vehicles are handed to PX4's landing."""
    params = CONFIG.system.to_params()
    x = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
    result = core.tick(0.02, Estimate(x, 0.005, ()), (False, True))
    assert (result.mode, result.phase.value) == (Mode.ABORT, "set_down")
    assert core.controller == "decentralized" and result.commanded == (False, True)
    [notice] = result.notices
    assert notice.kind == "land_other"
    assert "vehicle 1 link lost: UAV 2 sets its bar end down alone" in notice.text
    heights, speeds = [], []
    for k in range(2, 102):  # 2 s, the link back after half of it
        connected = (k > 51, True)
        result = core.tick(0.02 * k, Estimate(x, 0.005, ()), connected)
        assert result.commanded == (False, True) and not result.commands[0].motors_on
        assert result.reference is not None
        heights.append(result.reference.payload_position_m[2])
        speeds.append(-result.reference.velocity_mps[2])
    drops = -np.diff(heights)
    assert np.all(np.diff(drops) >= -1e-12)  # accelerating, then steady
    abort_rate_mps = CoreSettings().abort_rates.position_mps  # the bar level: no catching up
    assert math.isclose(drops.max(), 0.02 * abort_rate_mps, rel_tol=1e-6)
    assert np.allclose(drops, 0.02 * np.asarray(speeds[1:]))

    both = flight_core_from_config(CONFIG, clock=time.perf_counter)
    both.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
    result = both.tick(0.02, Estimate(x, 0.005, ()), (False, False))
    assert result.mode is Mode.PX4_LANDING
    assert "both vehicle links lost" in result.notices[0].text


def test_one_of_three_links_lost_the_other_two_set_the_plate_down_together() -> None:
    """Three UAVs and a plate, vehicle 2 lost in a hover: the other two are flown on the
    decentralized MPC and lower the payload, their attachments' mean at the abort rate,
    the plate level at its yaw; vehicle 2 gets nothing. Two of three lost: too few to hold
    it, every PX4 lands on its own."""
    config = load_config(CONFIGS / "sim_tri.toml")
    params = config.system.to_params()
    yaws = (0.0,) * params.n_vehicles
    x = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.3, yaws)).x
    core = flight_core_from_config(config, clock=time.perf_counter)
    core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07, 0.07))
    result = core.tick(0.02, Estimate(x, 0.005, ()), (True, False, True))
    assert (result.mode, result.phase.value) == (Mode.ABORT, "set_down")
    assert core.controller == "decentralized" and result.commanded == (True, False, True)
    [notice] = result.notices
    assert "vehicle 2 link lost: UAVs 1, 3 set the payload down" in notice.text, notice.text
    references = []
    for k in range(2, 80):
        result = core.tick(0.02 * k, Estimate(x, 0.005, ()), (True, False, True))
        assert not result.commands[1].motors_on and result.reference is not None
        references.append(result.reference)
    assert all(r.payload_yaw_rad == 0.3 and r.cone_angle_rad == 0.0 for r in references)
    heights = np.array([r.payload_position_m[2] for r in references])
    drops = -np.diff(heights)
    abort_rate_mps = CoreSettings().abort_rates.position_mps
    assert np.all(drops >= -1e-12) and math.isclose(drops.max(), 0.02 * abort_rate_mps)
    # Straight down: the plate's centre keeps its place in the horizontal.
    centres = np.array([r.payload_position_m[:2] for r in references])
    assert np.allclose(centres, centres[0], atol=1e-12)

    two_lost = flight_core_from_config(config, clock=time.perf_counter)
    two_lost.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07, 0.07))
    result = two_lost.tick(0.02, Estimate(x, 0.005, ()), (False, True, False))
    assert result.mode is Mode.PX4_LANDING
    assert "vehicle links 1, 3 lost" in result.notices[0].text


def test_setpoints_are_taken_only_in_a_mode_that_flies_them() -> None:
    """Disarmed, landing, aborting or killed a setpoint is refused (nothing is kept for the
    next take-off); armed it is taken, and a disarm empties the queue again."""
    params = CONFIG.system.to_params()
    x = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    setpoint = Setpoint((0.3, 0.0, 1.0), 0.0, None, 0.0, 1.0)
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.tick(0.0, resting_estimate(params))
    with pytest.raises(
        SetpointRefusedError, match=r"mode 'disarmed' \(disarmed on the ground\): arm first"
    ):
        core.queue_setpoints([setpoint])
    assert core.request(Event.ARM, 0.02).accepted
    core.queue_setpoints([setpoint])
    assert core.queue.queued == [setpoint]
    assert core.request(Event.DISARM, 0.04).accepted
    assert core.queue.queued == [] and core.queue.active is None
    for event in (Event.LAND, Event.ABORT, Event.KILL):
        core = flight_core_from_config(CONFIG, clock=time.perf_counter)
        core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
        core.queue_setpoints([setpoint, setpoint])
        assert core.request(event, 0.02).accepted
        assert core.queue.queued == [] and core.queue.active is None
        with pytest.raises(SetpointRefusedError, match=f"mode '{core.modes.mode.value}'"):
            core.queue_setpoints([setpoint])
        assert core.queue.queued == []


@pytest.mark.parametrize("gain", [0.0, 0.4])
def test_a_bar_held_low_raises_the_thrust_only_with_the_integral_action(gain: float) -> None:
    """Hovering with the bar measured 5 cm below its held reference for 3 s: the MPC's
    answer is the same every tick without the integral; with it the reference it is given
    climbs by gain × 5 cm per second, and the thrust with it."""
    # A solve late on a busy machine would fly the shifted plan: this test is about the law.
    # The force observer off: it would take up the missing force first.
    overrides = [
        f"mpc.integral_gain_per_s={gain}",
        "mpc.late_after_s=10.0",
        "mpc.force_observer_s=0",
    ]
    config = load_config(CONFIGS / "sim.toml", overrides)
    x = formation_equilibrium(
        config.system.to_params(), FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))
    ).x
    core = flight_core_from_config(config, clock=time.perf_counter)
    core.start_in_hover(Estimate(x, 0.005, ()), 0.0, (0.02, 0.07, 0.07))
    core.tick(0.02, Estimate(x, 0.005, ()))  # the hover holds the reference it starts at
    low = x.copy()
    heights = [P_B.start + 2, *(LAYOUT.uav_slices(i)[0].start + 2 for i in LAYOUT.vehicles)]
    low[heights] -= 0.05  # the bar and both UAVs
    thrusts = []
    for k in range(2, 152):
        result = core.tick(0.02 * k, Estimate(low, 0.005, ()))
        assert result.mode is Mode.HOVER and result.plan is not None
        thrusts.append(result.commands[0].thrust_n + result.commands[1].thrust_n)
    if gain == 0.0:
        assert thrusts[-1] == pytest.approx(thrusts[10], abs=1e-6)
    else:
        assert thrusts[-1] > thrusts[10] + 0.1
