"""The simulated PX4's behaviour (no I/O, time as an argument), as PX4 v1.15.4 was measured
to behave (../shared/reference/px4-observed.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.plant import Plant
from sim.ports import AirframeState
from sim.px4 import (
    COMMANDER_PERIOD_S,
    FORCE_MAGIC,
    PARAMETERS,
    AutoMode,
    FailsafeAction,
    MainMode,
    ParamType,
    Px4Model,
    Px4Parameters,
    Px4Params,
    Result,
    Timesync,
    custom_mode_of,
)
from sim.px4_control import RateController

ARM, SET_MODE, SET_MESSAGE_INTERVAL, TERMINATE = 400, 176, 511, 185
OFFBOARD = (1, 6, 0)
LOITER = (1, 4, 3)


def on_ground(on: bool = True, z_m: float = 0.0) -> AirframeState:
    position = np.array([0.0, 0.0, 0.0 if on else z_m])
    return AirframeState(0.0, position, np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), on)


def airborne(z_m: float = 1.5) -> AirframeState:
    return on_ground(False, z_m)


def stream(model: Px4Model, start_s: float, seconds: float, rate_hz: float = 50.0) -> float:
    t = start_s
    while t < start_s + seconds:
        model.rate_setpoint(np.zeros(3), 0.0, t)
        t += 1.0 / rate_hz
    return t


def event_names(model: Px4Model) -> list[str]:
    return [e.name for e in model.events]


def flying_offboard(params: Px4Params | None = None) -> tuple[Px4Model, float]:
    """Armed in OFFBOARD, in the air, the last setpoint at the returned time."""
    model = Px4Model(1, params)
    t = stream(model, 0.0, 1.2)
    assert model.command(ARM, (1, 0), t, on_ground()) is Result.ACCEPTED
    assert model.command(SET_MODE, OFFBOARD, t, on_ground()) is Result.ACCEPTED
    model.rate_setpoint(np.zeros(3), 0.6, t)
    model.step(t, airborne())
    return model, t


def run(model: Px4Model, start_s: float, stop_s: float, state: AirframeState) -> None:
    """Step the model every 2 ms over [start_s, stop_s]."""
    for t in np.arange(start_s, stop_s + 1e-9, 0.002):
        model.step(float(t), state)


# ---- modes -------------------------------------------------------------------------------
def test_it_boots_disarmed_in_auto_loiter() -> None:
    model = Px4Model(1)
    assert model.mode_name == "AUTO.LOITER"
    assert model.custom_mode == model.intended_custom_mode == 0x03040000
    assert model.base_mode == 29  # CUSTOM_MODE_ENABLED | AUTO | GUIDED | STABILIZE


def test_custom_and_base_mode_encoding() -> None:
    assert custom_mode_of((MainMode.AUTO, int(AutoMode.LAND))) == (4 << 16) | (6 << 24)
    assert custom_mode_of((MainMode.OFFBOARD, 0)) == 0x00060000
    model, _ = flying_offboard()
    assert model.base_mode == 129  # measured: armed OFFBOARD
    model.command(SET_MODE, (1, 3, 0), 2.0, airborne())
    assert (model.mode_name, model.base_mode) == ("POSCTL", 209)


def test_offboard_needs_more_than_a_second_of_setpoints_when_armed() -> None:
    model = Px4Model(1)
    assert model.command(ARM, (1, 0), 0.0, on_ground()) is Result.ACCEPTED
    assert model.command(SET_MODE, OFFBOARD, 0.1, on_ground()) is Result.TEMPORARILY_REJECTED
    assert model.mode_name == "AUTO.LOITER"
    assert model.events[-1].name == "commander_modeswitch_not_avail"
    assert model.events[-1].values == (0x00060000, 7)  # the mode asked for, as measured
    t = stream(model, 0.2, 0.8)  # too short
    assert model.command(SET_MODE, OFFBOARD, t, on_ground()) is Result.TEMPORARILY_REJECTED
    t = stream(model, t, 0.5)
    assert model.command(SET_MODE, OFFBOARD, t, on_ground()) is Result.ACCEPTED
    assert model.mode_name == "OFFBOARD"


def test_a_slow_stream_is_no_proof_of_life() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    t = stream(model, 0.0, 3.0, rate_hz=1.5)
    assert model.command(SET_MODE, OFFBOARD, t, on_ground()) is Result.TEMPORARILY_REJECTED


def test_disarmed_it_may_select_offboard_but_not_arm_in_it_without_a_stream() -> None:
    model = Px4Model(1)
    assert model.command(SET_MODE, OFFBOARD, 0.0, on_ground()) is Result.ACCEPTED
    assert model.base_mode == 1  # measured: OFFBOARD disarmed
    assert model.command(ARM, (1, 0), 0.1, on_ground()) is Result.TEMPORARILY_REJECTED
    assert model.events[-1].name == "commander_arm_denied_resolve_failures"
    t = stream(model, 0.1, 1.2)
    assert model.command(ARM, (1, 0), t, on_ground()) is Result.ACCEPTED
    assert model.events[-1].name == "commander_armed_by"
    assert model.events[-1].values == (4,)  # external command


# ---- arming and vision -------------------------------------------------------------------
def test_arming_checks() -> None:
    model = Px4Model(1, Px4Params(require_vision=True))
    assert model.command(ARM, (1, 0), 0.0, on_ground()) is Result.TEMPORARILY_REJECTED
    assert "no position estimate" in model.status_texts[-1][1]
    model.vision(1.0)
    assert model.command(ARM, (1, 0), 1.1, on_ground(False)) is Result.TEMPORARILY_REJECTED
    assert model.command(ARM, (1, 0), 1.2, on_ground()) is Result.ACCEPTED


def test_a_vision_sample_counts_from_its_capture_time() -> None:
    """Stamped on our clock (what TIMESYNC gives), an old sample is old however recently it
    arrived; unstamped, its arrival counts (PX4 before TIMESYNC converged)."""
    model = Px4Model(1, Px4Params(require_vision=True, vision_timeout_s=0.5))
    model.vision(10.0, sample_s=9.2)  # arrived now, captured 0.8 s ago
    assert not model.vision_fresh(10.0)
    assert model.command(ARM, (1, 0), 10.0, on_ground()) is Result.TEMPORARILY_REJECTED
    model.vision(10.1)  # no stamp: fresh on arrival
    assert model.vision_fresh(10.1)
    model.vision(10.2, sample_s=50.0)  # from the future: counts as arriving now
    assert model.last_vision_s == pytest.approx(10.2)


def test_ekf2_parameters_shape_what_vision_gives() -> None:
    delayed = Px4Model(1, Px4Params(require_vision=True, boot_parameters=(("EKF2_EV_DELAY", 300),)))
    delayed.vision(5.0, sample_s=4.9)
    assert delayed.last_vision_s == pytest.approx(4.6)  # 300 ms of assumed latency
    assert delayed.vision_fresh(5.0) and not delayed.vision_fresh(5.2)
    unfused = Px4Model(1, Px4Params(require_vision=True, boot_parameters=(("EKF2_EV_CTRL", 12),)))
    unfused.vision(5.0)
    assert not unfused.vision_fresh(5.0)  # velocity and yaw only: no position


def test_normal_disarm_is_refused_in_the_air_and_kill_is_not() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    assert model.command(ARM, (0, 0), 1.0, airborne()) is Result.TEMPORARILY_REJECTED
    assert model.events[-1].name == "commander_disarm_denied_not_landed"
    assert model.armed
    assert model.command(ARM, (0, FORCE_MAGIC), 1.0, airborne()) is Result.ACCEPTED
    assert not model.armed
    assert model.events[-1].name == "commander_disarmed_by"
    assert model.step(1.01, airborne()) == (0.0, pytest.approx(np.zeros(3)))


def test_flight_termination_is_latched() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    assert model.command(TERMINATE, (1,), 0.5, airborne()) is Result.ACCEPTED
    assert not model.armed and model.terminated
    assert model.command(ARM, (1, 0), 1.0, on_ground()) is Result.TEMPORARILY_REJECTED
    model.step(1.1, on_ground())
    assert "check_system_flight_term_active" in event_names(model)


def test_unknown_commands_are_unsupported_and_the_heartbeat_rate_is_fixed() -> None:
    model = Px4Model(1)
    assert model.command(31010, (0,) * 7, 0.0, on_ground()) is Result.UNSUPPORTED
    assert model.command(SET_MESSAGE_INTERVAL, (0, 5e5), 0.0, on_ground()) is Result.FAILED
    assert model.command(SET_MESSAGE_INTERVAL, (30, 1e4), 0.0, on_ground()) is Result.ACCEPTED


def test_setpoints_act_only_in_offboard() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    model.actuator_setpoint(np.array([0.0, 0.0, 0.0, 0.5, 0, 0, 0, 0]), 0.1)
    thrust, _ = model.step(0.1, on_ground())
    assert thrust == 0.0  # AUTO.LOITER on the ground: no take-off, motors idle
    t = stream(model, 0.1, 1.2)
    model.command(SET_MODE, OFFBOARD, t, on_ground())
    model.actuator_setpoint(np.array([0.5, -0.5, 0.25, 0.5, 0, 0, 0, 0]), t)
    thrust, torque = model.step(t, on_ground())
    assert thrust == pytest.approx(0.5 * 26.0)
    # FRD (roll, pitch, yaw) = (0.5, -0.5, 0.25) of 1 N m is FLU (0.5, 0.5, -0.25).
    np.testing.assert_allclose(torque, [0.5, 0.5, -0.25])


def test_calibration_mismatch_scales_the_true_thrust() -> None:
    model = Px4Model(1, Px4Params(thrust_scale=0.9))
    model.command(SET_MODE, OFFBOARD, 0.0, on_ground())
    t = stream(model, 0.0, 1.2)
    model.command(ARM, (1, 0), t, on_ground())
    model.rate_setpoint(np.zeros(3), 0.5, t)
    thrust, _ = model.step(t, on_ground())
    assert thrust == pytest.approx(0.9 * 0.5 * 26.0)


# ---- offboard loss -----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("action", "mode_name", "failsafe"),
    [
        (0, "POSCTL", FailsafeAction.FALLBACK_POSCTRL),
        (1, "ALTCTL", FailsafeAction.FALLBACK_ALTCTRL),
        (2, "STABILIZED", FailsafeAction.FALLBACK_STABILIZED),
        (3, "AUTO.RTL", FailsafeAction.RTL),
        (4, "AUTO.LAND", FailsafeAction.LAND),
        (5, "AUTO.LOITER", FailsafeAction.HOLD),
    ],
)
def test_offboard_loss_falls_back_as_com_obl_rc_act_says_and_recovers(
    action: int, mode_name: str, failsafe: FailsafeAction
) -> None:
    model, last = flying_offboard(Px4Params(offboard_loss_action=action))
    run(model, last, last + 0.99, airborne())
    assert model.mode_name == "OFFBOARD"
    run(model, last + 0.992, last + 1.0 + COMMANDER_PERIOD_S, airborne())
    assert (model.mode_name, model.failsafe) == (mode_name, failsafe)
    assert model.intended_custom_mode == 0x00060000  # OFFBOARD is still what the user wants
    assert model.events[-1].name == "commander_failsafe_enter_generic"
    assert model.events[-1].values == (0x00060000, int(failsafe))
    thrust, _ = model.step(last + 1.2, airborne())
    assert thrust > 5.0  # the fallback flies the vehicle (POSCTL holds; it no longer idles)
    model.rate_setpoint(np.zeros(3), 0.5, last + 3.0)  # the setpoints are back
    model.step(last + 3.0 + COMMANDER_PERIOD_S, airborne())
    assert (model.mode_name, model.failsafe) == ("OFFBOARD", None)


def test_offboard_loss_can_disarm_or_terminate() -> None:
    disarm, last = flying_offboard(Px4Params(offboard_loss_action=7))
    run(disarm, last, last + 1.2, airborne())
    assert not disarm.armed and disarm.mode_name == "OFFBOARD"
    assert disarm.events[-1].name == "commander_disarmed_by"
    assert disarm.events[-1].values == (14,)  # failsafe
    terminate, last = flying_offboard(Px4Params(offboard_loss_action=6))
    run(terminate, last, last + 1.2, airborne())
    assert not terminate.armed and terminate.terminated


def test_the_offboard_loss_timeout_is_the_parameter_and_takes_effect_at_once() -> None:
    model, last = flying_offboard()
    assert model.parameters.get("COM_OF_LOSS_T") == 1.0
    model.parameters.set("COM_OF_LOSS_T", 0.5)
    run(model, last, last + 0.49, airborne())
    assert model.mode_name == "OFFBOARD"
    run(model, last + 0.492, last + 0.5 + COMMANDER_PERIOD_S, airborne())
    assert model.mode_name == "POSCTL"  # COM_OBL_RC_ACT 0: PX4's default


def test_offboard_loss_with_land_lands_and_disarms_after_com_disarm_land() -> None:
    model, last = flying_offboard(Px4Params(offboard_loss_action=4))
    model.parameters.set("COM_DISARM_LAND", 1.0)
    run(model, last, last + 1.2, airborne())
    assert model.mode_name == "AUTO.LAND"
    assert any("offboard lost" in text for _, text in model.status_texts)
    run(model, last + 2.0, last + 2.1, on_ground())  # touched down
    assert model.armed and "commander_landing_detected" in event_names(model)
    run(model, last + 2.2, last + 3.2, on_ground())
    assert not model.armed
    assert model.events[-1].values == (6,)  # disarmed: landed
    # Disarming ends the failsafe: the heartbeat shows the intended OFFBOARD again.
    assert (model.mode_name, model.base_mode) == ("OFFBOARD", 1)


def test_after_a_force_disarm_the_heartbeat_shows_offboard_again() -> None:
    """Measured: force-disarmed in the air during the POSCTL fallback, nav_state returns to
    the user's intended OFFBOARD within 12 ms."""
    model, last = flying_offboard()
    run(model, last, last + 1.2, airborne())
    assert model.mode_name == "POSCTL"
    assert model.command(ARM, (0, FORCE_MAGIC), last + 1.3, airborne()) is Result.ACCEPTED
    assert (model.custom_mode, model.base_mode) == (0x00060000, 1)


def test_selecting_a_mode_ends_the_failsafe() -> None:
    model, last = flying_offboard()
    run(model, last, last + 1.2, airborne())
    assert model.command(SET_MODE, LOITER, last + 1.3, airborne()) is Result.ACCEPTED
    assert (model.mode_name, model.failsafe) == ("AUTO.LOITER", None)
    run(model, last + 1.4, last + 2.0, airborne())
    assert model.mode_name == "AUTO.LOITER"  # OFFBOARD no longer intended: no failsafe


# ---- auto-disarm -------------------------------------------------------------------------
def test_armed_on_the_ground_without_take_off_disarms_itself_after_com_disarm_prflt() -> None:
    model = Px4Model(1, Px4Params(auto_disarm_preflight_s=10.0))
    assert model.parameters.get("COM_DISARM_PRFLT") == 10.0
    model.command(ARM, (1, 0), 0.0, on_ground())
    model.step(9.0, on_ground())
    assert model.armed
    model.step(10.1, on_ground())
    assert not model.armed
    assert model.events[-1].values == (7,)  # auto preflight disarming
    model.parameters.set("COM_DISARM_PRFLT", -1.0)  # negative: never
    model.command(ARM, (1, 0), 11.0, on_ground())
    model.step(30.0, on_ground())
    assert model.armed


# ---- parameters --------------------------------------------------------------------------
def test_the_parameter_table_has_px4s_names_types_and_defaults() -> None:
    table = Px4Parameters()
    expected = {
        "COM_OF_LOSS_T": (ParamType.REAL32, 1.0),
        "COM_OBL_RC_ACT": (ParamType.INT32, 0),
        "COM_DISARM_PRFLT": (ParamType.REAL32, 10.0),
        "COM_DISARM_LAND": (ParamType.REAL32, 2.0),
        "COM_FAIL_ACT_T": (ParamType.REAL32, 5.0),
        "NAV_DLL_ACT": (ParamType.INT32, 0),
        "MPC_THR_HOVER": (ParamType.REAL32, 0.5),
        "MPC_LAND_SPEED": (ParamType.REAL32, pytest.approx(0.7)),
        "EKF2_EV_CTRL": (ParamType.INT32, 15),
        "EKF2_GPS_CTRL": (ParamType.INT32, 7),
        "EKF2_HGT_REF": (ParamType.INT32, 1),
        "EKF2_EV_DELAY": (ParamType.REAL32, 0.0),
        "MAV_SYS_ID": (ParamType.INT32, 1),
    }
    for name, (kind, value) in expected.items():
        spec = table.spec(name)
        assert spec is not None and spec.type is kind, name
        assert table.get(name) == value, name
    names = [spec.name for spec in PARAMETERS]
    assert names == sorted(names)  # PX4 indexes them by name
    assert isinstance(table.get("COM_OBL_RC_ACT"), int)
    assert table.set("MPC_THR_HOVER", 0.1) and table.get("MPC_THR_HOVER") != 0.1  # float32
    assert not table.set("COM_OBL_RC_ACT", 0)  # unchanged


def test_px4_params_are_the_initial_values_and_boot_parameters_override_them() -> None:
    model = Px4Model(
        2,
        Px4Params(
            offboard_loss_timeout_s=0.5,
            offboard_loss_action=4,
            land_speed_mps=0.8,
            hover_thrust_n=13.0,
            thrust_max_n=26.0,
            boot_parameters=(("MAV_SYS_ID", 7), ("EKF2_HGT_REF", 3), ("NO_SUCH", 1.0)),
        ),
    )
    p = model.parameters
    assert (p.get("COM_OF_LOSS_T"), p.get("COM_OBL_RC_ACT")) == (0.5, 4)
    assert p.get("MPC_LAND_SPEED") == pytest.approx(0.8)
    assert p.get("MPC_THR_HOVER") == pytest.approx(0.5)
    assert (p.get("EKF2_HGT_REF"), "NO_SUCH" in p) == (3, False)
    assert model.system_id == 7  # MAV_SYS_ID, read at boot


def test_the_hover_thrust_parameter_drives_the_own_modes() -> None:
    model, last = flying_offboard()
    run(model, last, last + 1.2, airborne())
    held, _ = model.step(last + 1.3, airborne())
    model.parameters.set("MPC_THR_HOVER", 0.6)
    pushed, _ = model.step(last + 1.302, airborne())
    assert pushed > held + 2.0


# ---- time synchronization ----------------------------------------------------------------
def exchange(sync: Timesync, t_s: float, offset_s: float, rtt_s: float = 0.001) -> bool:
    """One request at ``t_s`` (our clock) answered by a client whose clock is ours plus
    ``offset_s``, received ``rtt_s`` later."""
    ts1 = round(t_s * 1e9)
    sync.sent(ts1)
    tc1 = round((t_s + rtt_s / 2 + offset_s) * 1e9)
    return sync.update(round((t_s + rtt_s) * 1e9), tc1, ts1)


def test_timesync_converges_after_500_answers_as_px4() -> None:
    sync = Timesync()
    offset_s = 1234.5678
    for k in range(499):
        assert exchange(sync, 0.1 * k, offset_s)
    assert not sync.converged and sync.local_time_s(0) is None
    assert exchange(sync, 49.9, offset_s)
    assert sync.converged
    local = sync.local_time_s(round((50.0 + offset_s) * 1e6))
    assert local == pytest.approx(50.0, abs=1e-4)


def test_timesync_gates_answers() -> None:
    sync = Timesync()
    assert not exchange(sync, 1.0, 5.0, rtt_s=0.012)  # a round trip of 10 ms or more
    assert not sync.update(2_000_000_000, 7, 999)  # a ts1 we never sent
    assert not sync.update(2_000_000_000, 0, 999)  # a request, not an answer
    assert sync.samples == 0 and sync.rejected == 3


def test_timesync_resets_after_a_clock_jump() -> None:
    sync = Timesync()
    for k in range(500):
        exchange(sync, 0.1 * k, 10.0)
    assert sync.converged
    for k in range(6):
        exchange(sync, 50.0 + 0.1 * k, 20.0)
    assert not sync.converged and sync.sequence == 0


# ---- the arming-check report -------------------------------------------------------------
def test_the_arming_check_report_goes_out_when_the_checks_change() -> None:
    model = Px4Model(1, Px4Params(require_vision=True))
    model.step(0.0, on_ground())
    assert event_names(model) == [
        "commander_arming_check_summary",
        "check_modes_offboard_signal",
        "check_modes_local_pos",
        "commander_health_summary",
    ]
    summary = model.events[0]
    assert int(summary.values[3]) & (1 << 14) == 0  # offboard cannot arm
    model.events.clear()
    model.step(0.1, on_ground())
    assert not model.events  # unchanged: no report
    model.vision(0.15)
    model.step(0.2, on_ground())
    assert event_names(model)[1:-1] == ["check_modes_offboard_signal"]
    model.events.clear()
    model.request_report()
    model.step(0.3, on_ground())
    assert event_names(model)[0] == "commander_arming_check_summary"


def test_non_finite_setpoints_are_ignored() -> None:
    model = Px4Model(1)
    model.rate_setpoint(np.array([np.nan, 0.0, 0.0]), 0.5, 0.0)
    model.actuator_setpoint(np.array([0.0, np.inf, 0.0, 0.5]), 0.0)
    assert model.setpoint is None
    assert math.isinf(model.last_vision_s)


def test_rate_controller_tracks_a_rate_step_on_the_plant() -> None:
    """In the air (no ground), a rate step is reached and held; torques stay saturated."""
    plant = Plant(ground=False)
    controller = RateController((0.0348, 0.0459, 0.0977), 1.0)
    target = np.array([0.5, -0.3, 1.0])
    for _ in range(1000):  # 1 s at 1 kHz
        rates = plant.body("uav1").body_rates_radps
        torque = controller.torque(target, rates, 0.001)
        assert np.all(np.abs(torque) <= 1.0)
        plant.command(1, 0.0, torque)
        plant.step()
    np.testing.assert_allclose(plant.body("uav1").body_rates_radps, target, atol=0.05)
