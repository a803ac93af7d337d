"""The simulated PX4's behaviour (no I/O, time as an argument)."""

from __future__ import annotations

import numpy as np
import pytest

from sim.plant import Plant
from sim.ports import AirframeState
from sim.px4 import FORCE_MAGIC, AutoMode, MainMode, Px4Model, Px4Params, Result
from sim.px4_control import RateController

ARM, SET_MODE = 400, 176


def on_ground(on: bool = True) -> AirframeState:
    return AirframeState(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), on)


def stream(model: Px4Model, start_s: float, seconds: float, rate_hz: float = 50.0) -> float:
    t = start_s
    while t < start_s + seconds:
        model.rate_setpoint(np.zeros(3), 0.0, t)
        t += 1.0 / rate_hz
    return t


def test_heartbeat_custom_mode_encoding() -> None:
    model = Px4Model(1)
    assert model.custom_mode == 3 << 16  # POSCTL
    model.main_mode, model.sub_mode = MainMode.AUTO, int(AutoMode.LAND)
    assert model.custom_mode == (4 << 16) | (6 << 24)
    assert model.mode_name == "AUTO.LAND"
    model.main_mode, model.sub_mode = MainMode.OFFBOARD, 0
    assert model.custom_mode == 0x00060000


def test_offboard_needs_more_than_a_second_of_setpoints_when_armed() -> None:
    model = Px4Model(1)
    assert model.command(ARM, (1, 0), 0.0, on_ground()) is Result.ACCEPTED
    assert model.command(SET_MODE, (1, 6, 0), 0.1, on_ground()) is Result.TEMPORARILY_REJECTED
    assert model.main_mode is MainMode.POSCTL
    t = stream(model, 0.2, 0.8)  # too short
    assert model.command(SET_MODE, (1, 6, 0), t, on_ground()) is Result.TEMPORARILY_REJECTED
    t = stream(model, t, 0.5)
    assert model.command(SET_MODE, (1, 6, 0), t, on_ground()) is Result.ACCEPTED
    assert model.mode_name == "OFFBOARD"


def test_a_slow_stream_is_no_proof_of_life() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    t = stream(model, 0.0, 3.0, rate_hz=1.5)
    assert model.command(SET_MODE, (1, 6, 0), t, on_ground()) is Result.TEMPORARILY_REJECTED


def test_disarmed_it_may_select_offboard_but_not_arm_in_it_without_a_stream() -> None:
    model = Px4Model(1)
    assert model.command(SET_MODE, (1, 6, 0), 0.0, on_ground()) is Result.ACCEPTED
    assert model.command(ARM, (1, 0), 0.1, on_ground()) is Result.TEMPORARILY_REJECTED
    t = stream(model, 0.1, 1.2)
    assert model.command(ARM, (1, 0), t, on_ground()) is Result.ACCEPTED


def test_arming_checks() -> None:
    model = Px4Model(1, Px4Params(require_vision=True))
    assert model.command(ARM, (1, 0), 0.0, on_ground()) is Result.DENIED
    assert "no position estimate" in model.status_texts[-1][1]
    model.vision(1.0)
    assert model.command(ARM, (1, 0), 1.1, on_ground(False)) is Result.DENIED  # in the air
    assert model.command(ARM, (1, 0), 1.2, on_ground()) is Result.ACCEPTED


def test_normal_disarm_is_denied_in_the_air_and_kill_is_not() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    assert model.command(ARM, (0, 0), 1.0, on_ground(False)) is Result.DENIED
    assert model.armed
    assert model.command(ARM, (0, FORCE_MAGIC), 1.0, on_ground(False)) is Result.ACCEPTED
    assert not model.armed
    assert model.step(1.01, on_ground(False)) == (0.0, pytest.approx(np.zeros(3)))


def test_unknown_commands_are_unsupported() -> None:
    assert Px4Model(1).command(31010, (0,) * 7, 0.0, on_ground()) is Result.UNSUPPORTED


def test_setpoints_act_only_in_offboard() -> None:
    model = Px4Model(1)
    model.command(ARM, (1, 0), 0.0, on_ground())
    model.actuator_setpoint(np.array([0.0, 0.0, 0.0, 0.5, 0, 0, 0, 0]), 0.1)
    thrust, _ = model.step(0.1, on_ground())
    assert thrust == 0.0  # POSCTL without a pilot: idle
    t = stream(model, 0.1, 1.2)
    model.command(SET_MODE, (1, 6, 0), t, on_ground())
    model.actuator_setpoint(np.array([0.5, -0.5, 0.25, 0.5, 0, 0, 0, 0]), t)
    thrust, torque = model.step(t, on_ground())
    assert thrust == pytest.approx(0.5 * 26.0)
    # FRD (roll, pitch, yaw) = (0.5, -0.5, 0.25) of 1 N m is FLU (0.5, 0.5, -0.25).
    np.testing.assert_allclose(torque, [0.5, 0.5, -0.25])


def test_calibration_mismatch_scales_the_true_thrust() -> None:
    model = Px4Model(1, Px4Params(thrust_scale=0.9))
    model.command(SET_MODE, (1, 6, 0), 0.0, on_ground())
    t = stream(model, 0.0, 1.2)
    model.command(ARM, (1, 0), t, on_ground())
    model.rate_setpoint(np.zeros(3), 0.5, t)
    thrust, _ = model.step(t, on_ground())
    assert thrust == pytest.approx(0.9 * 0.5 * 26.0)


def test_offboard_loss_lands_and_disarms() -> None:
    model = Px4Model(1, Px4Params(offboard_loss_timeout_s=1.0, auto_disarm_land_s=2.0))
    t = stream(model, 0.0, 1.2)
    model.command(ARM, (1, 0), t, on_ground())
    model.command(SET_MODE, (1, 6, 0), t, on_ground())
    model.rate_setpoint(np.zeros(3), 0.6, t)
    last = t
    model.step(last + 0.5, on_ground(False))
    assert model.main_mode is MainMode.OFFBOARD
    model.step(last + 1.05, on_ground(False))
    assert (model.main_mode, model.sub_mode) == (MainMode.AUTO, AutoMode.LAND)
    assert any("offboard lost" in text for _, text in model.status_texts)
    model.step(last + 5.0, on_ground(True))  # touched down
    assert model.armed
    model.step(last + 7.1, on_ground(True))
    assert not model.armed


def test_armed_on_the_ground_without_take_off_disarms_itself() -> None:
    model = Px4Model(1, Px4Params(auto_disarm_preflight_s=10.0))
    model.command(ARM, (1, 0), 0.0, on_ground())
    model.step(9.0, on_ground())
    assert model.armed
    model.step(10.5, on_ground())
    assert not model.armed


def test_non_finite_setpoints_are_ignored() -> None:
    model = Px4Model(1)
    model.rate_setpoint(np.array([np.nan, 0.0, 0.0]), 0.5, 0.0)
    model.actuator_setpoint(np.array([0.0, np.inf, 0.0, 0.5]), 0.0)
    assert model.setpoint is None


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
