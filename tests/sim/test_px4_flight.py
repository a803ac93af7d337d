"""The simulated PX4's own modes fly: each offboard-loss fallback on a rigid quadrotor
(a bare rigid body, no bar: what is tested is the flight stack, not the plant)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pytest

from geometry.arrays import FloatArray
from geometry.frames import (
    quaternion_from_rotation,
    quaternion_from_rotation_vector,
    rotation_from_quaternion,
)
from sim.ports import AirframeState
from sim.px4 import COMMANDER_PERIOD_S, Px4Model, Px4Params, Result

G = 9.81
DT = 0.002


@dataclass
class RigidBody:
    """A quadrotor as one rigid body over a flat floor (z = 0), semi-implicit Euler."""

    mass_kg: float = 13.2 / G
    inertia_kgm2: FloatArray = field(default_factory=lambda: np.array([0.0348, 0.0459, 0.0977]))
    position_m: FloatArray = field(default_factory=lambda: np.zeros(3))
    velocity_mps: FloatArray = field(default_factory=lambda: np.zeros(3))
    rotation: FloatArray = field(default_factory=lambda: np.eye(3))
    rates_radps: FloatArray = field(default_factory=lambda: np.zeros(3))
    time_s: float = 0.0
    thrust_n: float = 0.0
    torque_nm: FloatArray = field(default_factory=lambda: np.zeros(3))

    @property
    def on_ground(self) -> bool:
        return bool(self.position_m[2] <= 1e-4 and self.thrust_n < self.mass_kg * G)

    def state(self) -> AirframeState:
        return AirframeState(
            self.time_s, self.position_m.copy(), self.velocity_mps.copy(),
            quaternion_from_rotation(self.rotation), self.rates_radps.copy(), self.on_ground,
        )  # fmt: skip

    def step(self) -> None:
        J, w = self.inertia_kgm2, self.rates_radps
        self.rates_radps = w + DT * (self.torque_nm - np.cross(w, J * w)) / J
        turn = rotation_from_quaternion(quaternion_from_rotation_vector(self.rates_radps * DT))
        self.rotation = self.rotation @ turn
        accel = self.rotation[:, 2] * self.thrust_n / self.mass_kg - np.array([0.0, 0.0, G])
        self.velocity_mps = self.velocity_mps + DT * accel
        self.position_m = self.position_m + DT * self.velocity_mps
        if self.position_m[2] <= 0.0:  # the floor: no bounce, no sliding
            self.position_m[2] = 0.0
            self.velocity_mps = np.zeros(3)
            if self.thrust_n < self.mass_kg * G:
                self.rates_radps = np.zeros(3)
        self.time_s += DT


@dataclass
class Flight:
    model: Px4Model
    body: RigidBody
    stopped_s: float = 0.0

    def fly(self, until_s: float, client: bool = False, target_z_m: float = 2.0) -> None:
        """Run the flight stack and the body to ``until_s``; ``client`` streams rate
        setpoints at 50 Hz that hold ``target_z_m`` (an altitude loop of its own)."""
        while self.body.time_s < until_s:
            t = self.body.time_s
            if client and round(t / DT) % 10 == 0:
                z, vz = self.body.position_m[2], self.body.velocity_mps[2]
                thrust = (13.2 + 1.345 * (2.0 * (target_z_m - z) - 2.5 * vz)) / 26.0
                self.model.rate_setpoint(np.zeros(3), float(np.clip(thrust, 0.0, 1.0)), t)
                self.stopped_s = t
            self.body.thrust_n, self.body.torque_nm = self.model.step(t, self.body.state())
            self.body.step()


def take_off(action: int, land_speed_mps: float = 0.7, auto_disarm_land_s: float = 2.0) -> Flight:
    """Armed in OFFBOARD at 2 m, hovering on a client's setpoints; then they stop."""
    params = Px4Params(
        offboard_loss_action=action,
        land_speed_mps=land_speed_mps,
        auto_disarm_land_s=auto_disarm_land_s,
    )
    flight = Flight(Px4Model(1, params), RigidBody())
    model = flight.model
    flight.fly(1.2, client=True, target_z_m=0.0)  # proof of life, on the ground
    assert model.command(176, (1, 6, 0), 1.2, flight.body.state()) is Result.ACCEPTED
    assert model.command(400, (1, 0), 1.2, flight.body.state()) is Result.ACCEPTED
    flight.fly(6.0, client=True, target_z_m=2.0)
    assert flight.body.position_m[2] == pytest.approx(2.0, abs=0.05)
    return flight


def test_position_mode_holds_where_the_setpoints_stopped() -> None:
    """COM_OBL_RC_ACT 0 (PX4's default) with no RC: POSCTL holds (measured 8 s)."""
    flight = take_off(0)
    flight.fly(flight.stopped_s + 1.0 + COMMANDER_PERIOD_S + DT)
    assert flight.model.mode_name == "POSCTL"
    start = flight.body.position_m.copy()
    flight.fly(flight.body.time_s + 8.0)
    assert flight.model.armed and not flight.body.on_ground
    np.testing.assert_allclose(flight.body.position_m, start, atol=0.1)
    assert np.linalg.norm(flight.body.velocity_mps) < 0.05


def test_altitude_mode_holds_the_height() -> None:
    flight = take_off(1)
    flight.fly(flight.stopped_s + 1.2)
    assert flight.model.mode_name == "ALTCTL"
    flight.fly(flight.body.time_s + 8.0)
    assert flight.body.position_m[2] == pytest.approx(2.0, abs=0.15)


def test_stabilized_mode_stays_level_on_the_hover_thrust() -> None:
    flight = take_off(2)
    flight.fly(flight.stopped_s + 1.2)
    assert flight.model.mode_name == "STABILIZED"
    flight.fly(flight.body.time_s + 3.0)
    assert flight.body.rotation[2, 2] > 0.999  # level
    assert abs(flight.body.velocity_mps[2]) < 0.3  # no height hold, but no climb or fall


@pytest.mark.parametrize("land_speed_mps", [0.7, 1.0])
def test_land_descends_at_mpc_land_speed_and_disarms(land_speed_mps: float) -> None:
    """The descent rate is the parameter's (the hold loop's integrator overshoots it by
    by up to a fifth for a second or two: a simplification of PX4's smoothed descent)."""
    flight = take_off(4, land_speed_mps=land_speed_mps, auto_disarm_land_s=2.0)
    flight.fly(flight.stopped_s + 2.5)
    assert flight.model.mode_name == "AUTO.LAND"
    assert flight.model.parameters.get("MPC_LAND_SPEED") == pytest.approx(land_speed_mps)
    assert flight.body.velocity_mps[2] == pytest.approx(-land_speed_mps, rel=0.2)
    flight.fly(flight.body.time_s + 2.0 / land_speed_mps)
    assert flight.body.on_ground and flight.model.armed
    flight.fly(flight.body.time_s + 2.3)
    assert not flight.model.armed
    assert flight.model.mode_name == "OFFBOARD"  # disarmed: the intended mode again


def test_hold_mode_loiters() -> None:
    flight = take_off(5)
    flight.fly(flight.stopped_s + 1.2)
    assert flight.model.mode_name == "AUTO.LOITER"
    start = flight.body.position_m.copy()
    flight.fly(flight.body.time_s + 5.0)
    np.testing.assert_allclose(flight.body.position_m, start, atol=0.1)


def test_return_flies_back_over_home_and_lands() -> None:
    flight = take_off(3)
    flight.body.position_m[0:2] = [1.5, -1.0]  # pushed away from home (the take-off point)
    flight.fly(flight.stopped_s + 1.2)
    assert flight.model.mode_name == "AUTO.RTL"
    flight.fly(flight.body.time_s + 20.0)
    assert not flight.model.armed and flight.body.on_ground
    np.testing.assert_allclose(flight.body.position_m[0:2], [0.0, 0.0], atol=0.35)


def test_setpoints_coming_back_resume_offboard() -> None:
    flight = take_off(4)
    flight.fly(flight.stopped_s + 1.5)
    assert flight.model.mode_name == "AUTO.LAND"
    flight.fly(flight.body.time_s + 0.3, client=True, target_z_m=2.0)
    assert flight.model.mode_name == "OFFBOARD"
