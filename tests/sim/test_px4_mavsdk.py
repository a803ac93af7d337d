"""MAVSDK, an independent MAVLink implementation, flies a simulated PX4 on loopback."""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import AttitudeRate, OffboardAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
from mavsdk.autopilot import Autopilot

from sim.plant import Plant
from sim.px4 import AutoMode, MainMode
from sim.px4_endpoint import Px4Endpoint

STEP_S = 0.004  # the plant's longest step between two of the vehicle's


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@dataclass
class World:
    plant: Plant
    vehicle: Px4Endpoint
    client_port: int
    watches: list[tuple[Callable[[], bool], asyncio.Future[float]]] = field(default_factory=list)

    async def until(self, condition: Callable[[], bool], timeout_s: float) -> float:
        """Wait until ``condition()`` holds (checked by the world after every step); the
        plant time it first held at."""
        held_at: asyncio.Future[float] = asyncio.get_running_loop().create_future()
        self.watches.append((condition, held_at))
        async with asyncio.timeout(timeout_s):
            return await held_at


@contextlib.asynccontextmanager
async def world() -> AsyncIterator[World]:
    """One simulated PX4 on a plant stepped at real time."""
    plant = Plant()
    plant.place_resting()
    client_port = free_udp_port()
    vehicle = Px4Endpoint(0, plant.uav(1), local_port=0, client_port=client_port)
    await vehicle.start()
    started = time.monotonic()

    async def run() -> None:
        # After a late wake-up (a busy machine) the plant catches up in steps of at most
        # STEP_S, the vehicle stepping and the watches checked after each: a moment the
        # test measures in plant time stays exact to a step.
        while True:
            now = time.monotonic() - started
            while plant.time_s < now - 0.5 * plant.step_s:  # whole plant steps
                plant.advance(min(STEP_S, now - plant.time_s))
                vehicle.step(plant.time_s)
                for condition, held_at in w.watches:
                    if not held_at.done() and condition():
                        held_at.set_result(plant.time_s)
            await asyncio.sleep(0.002)

    w = World(plant, vehicle, client_port)
    task = asyncio.create_task(run())
    try:
        yield w
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
        await vehicle.close()


async def stream(offboard: OffboardAsync, rate: AttitudeRate, seconds: float) -> None:
    for _ in range(round(seconds / 0.02)):
        await offboard.set_attitude_rate(rate)
        await asyncio.sleep(0.02)


@pytest.mark.slow
async def test_mavsdk_arms_flies_offboard_and_kills_a_simulated_px4() -> None:
    async with world() as w:
        configuration = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(configuration) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{w.client_port}")
            system = await mavsdk.first_autopilot(timeout_s=5.0)
            assert system is not None
            assert await system.autopilot_type() == Autopilot.PX4
            action, offboard = ActionAsync(system), OffboardAsync(system)
            telemetry = TelemetryAsync(system)

            await action.arm()
            assert w.vehicle.model.armed
            await stream(offboard, AttitudeRate(0.0, 0.0, 0.0, 0.0), 1.3)  # proof of life
            await offboard.start()
            async with asyncio.timeout(3.0):  # as MAVSDK sees it, from the heartbeat
                async for mode in telemetry.subscribe_flight_mode():
                    if mode == FlightMode.OFFBOARD:
                        break
            await stream(offboard, AttitudeRate(0.0, 0.0, 20.0, 0.6), 1.5)  # climb, turning
            uav = w.plant.body("uav1")
            assert uav.position_m[2] > 0.3
            assert uav.body_rates_radps[2] < -0.1  # yaw right (FRD +z) is FLU −z
            await action.kill()
            assert not w.vehicle.model.armed
            # Motors stop at the next flight-stack step (milliseconds), in the air.
            await w.until(lambda: w.plant.commanded(1)[0] == 0.0, 0.1)
            assert not w.plant.on_ground(1)


@pytest.mark.slow
async def test_stopping_the_setpoints_triggers_the_offboard_loss_failsafe() -> None:
    async with world() as w:
        configuration = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(configuration) as mavsdk:
            await mavsdk.add_any_connection(f"udpin://127.0.0.1:{w.client_port}")
            system = await mavsdk.first_autopilot(timeout_s=5.0)
            assert system is not None
            action, offboard = ActionAsync(system), OffboardAsync(system)
            # PX4's default offboard-loss action holds position (COM_OBL_RC_ACT 0); the
            # lab's is to land. MAVSDK's own parameter client sets it (INT32, bytewise).
            param = ParamAsync(system)
            assert await param.get_param_int("COM_OBL_RC_ACT") == 0
            assert await param.get_param_float("COM_OF_LOSS_T") == 1.0
            await param.set_param_int("COM_OBL_RC_ACT", 4)
            assert w.vehicle.model.parameters.get("COM_OBL_RC_ACT") == 4
            await action.arm()
            await stream(offboard, AttitudeRate(0.0, 0.0, 0.0, 0.0), 1.3)
            await offboard.start()
            await stream(offboard, AttitudeRate(0.0, 0.0, 0.0, 0.6), 1.2)
        # MAVSDK is gone and its setpoints with it (it re-sends the last one while alive).
        model = w.vehicle.model
        left_at = await w.until(lambda: model.main_mode is not MainMode.OFFBOARD, 5.0)
        assert (model.main_mode, model.sub_mode) == (MainMode.AUTO, AutoMode.LAND)
        assert model.setpoint is not None
        assert 1.0 <= left_at - model.setpoint.time_s <= 1.1  # COM_OF_LOSS_T = 1 s
        failsafe = "Failsafe: the autopilot takes over, landing"  # an EVENT, as PX4 v1.15
        assert ("commander_failsafe_enter_generic", failsafe) in w.vehicle.events_sent
        assert model.armed  # landing, not falling
        await w.until(lambda: not model.armed, 30.0)
        assert w.plant.on_ground(1)  # landed, then disarmed itself
