"""The reset's wait for the motion capture to track the bodies where the world put them,
on the telemetry the flight process really builds."""

from __future__ import annotations

import asyncio
import socket
import time

import numpy as np
import pytest

from api import world_reset
from api.world_reset import settle_after_reset, tracked_at
from geometry.state import payload_position
from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.estimation import Estimate
from supervisor.flight.status import FlightStatus
from supervisor.flight.telemetry import MocapView, ShellView, build_telemetry
from supervisor.ipc.channel import Channel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.messages import TelemetryMessage
from supervisor.vehicles.types import VehicleView
from tests.api.conftest import ticks
from tests.conftest import CONFIGS, resting_estimate

CONFIG = load_config(CONFIGS / "sim.toml")
PARAMS = CONFIG.system.to_params()
VEHICLE = VehicleView(connected=True, armed=False, px4_mode="POSCTL")
MOCAP = MocapView(connected=True, rate_hz=100.0, frames=0, dropped=0)


def telemetry_of(estimate: Estimate) -> FlightStatus:
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.tick(0.0, estimate)
    shell = ShellView(streaming=False)
    return build_telemetry(core, estimate, None, (VEHICLE, VEHICLE), MOCAP, ticks(0), shell, 0.0)


def positions_of(x: np.ndarray) -> dict[str, list[float]]:
    return {
        "bar": payload_position(x).tolist(),
        "uav1": PARAMS.layout.uav_position(x, 1).tolist(),
        "uav2": PARAMS.layout.uav_position(x, 2).tolist(),
    }


def test_tracked_only_with_fresh_mocap_and_every_body_at_its_place() -> None:
    resting = resting_estimate(PARAMS)
    at_rest = positions_of(resting.x)
    status = telemetry_of(resting)
    assert tracked_at(status, at_rest) and status.arm_blocked_by is None
    moved = resting.x.copy()
    moved[PARAMS.layout.uav_slices(2)[0]][1] += (
        0.6  # pushed aside, farther than a landing leaves it
    )
    status = telemetry_of(Estimate(moved, 0.005, ()))
    assert not tracked_at(status, at_rest)
    assert "UAV 2 stands 0.60 m from its bar end" in str(status.arm_blocked_by)
    stale = telemetry_of(Estimate(resting.x, 0.5, ("bar",)))
    assert not tracked_at(stale, at_rest)
    assert str(stale.arm_blocked_by).startswith("no fresh motion capture of all bodies")


async def test_the_reset_answers_once_the_telemetry_tracks_the_resting_pose(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # What is tested is the answer, not the time limit: a busy machine may take seconds here.
    monkeypatch.setattr(world_reset, "SETTLE_TIMEOUT_S", 60.0)
    resting = resting_estimate(PARAMS)
    moved = resting.x.copy()
    moved[PARAMS.layout.uav_slices(1)[0]][0] += 0.3
    pairs = [socket.socketpair() for _ in range(2)]
    commands, urgent = [await Channel.open(a) for a, _ in pairs]
    flight_side = [await Channel.open(b) for _, b in pairs]
    flight = FlightClient(commands, urgent)
    receiving = asyncio.create_task(flight.run())

    async def publish(estimate: Estimate, count: int) -> None:
        for _ in range(count):
            flight_side[0].send(TelemetryMessage(status=telemetry_of(estimate)))
            await asyncio.sleep(0.04)

    await publish(Estimate(moved, 0.005, ()), 2)
    settling = asyncio.create_task(settle_after_reset(flight, positions_of(resting.x)))
    await publish(Estimate(moved, 0.005, ()), 3)
    assert not settling.done()  # the old pose is no answer
    await publish(resting, 2)
    assert await asyncio.wait_for(settling, 30.0) == {"tracked": True, "arm_blocked_by": None}
    receiving.cancel()
    for channel in (*flight_side, commands, urgent):
        await channel.close()
