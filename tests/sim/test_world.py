"""The simulated world of ``sitl``: the official Qualisys SDK and our own client read the
plant's bodies from its QTM server."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import statistics
import time
import xml.etree.ElementTree as ET
from collections.abc import AsyncIterator
from typing import Any

import numpy as np
import pytest
import qtm_rt

from geometry import frames
from mocap.client import MocapFrame, QtmClient
from sim.world import SimulatedWorld
from supervisor.app.config import load_config
from supervisor.app.world_process import build_world
from tests.conftest import CONFIGS

BODIES = ("bar", "uav1", "uav2")


@contextlib.asynccontextmanager
async def running_world(
    overrides: tuple[str, ...] = (), setup: str = "sim.toml"
) -> AsyncIterator[SimulatedWorld]:
    """The world of ``setup`` (a file of configs/) running on the wall clock, every vehicle
    on a free port."""
    # No random dropouts: every body of every frame is compared with the plant.
    config = load_config(CONFIGS / setup, ["sim.mocap.dropout_probability=0.0", *overrides])
    free_ports = (0,) * config.system.n_vehicles
    world = build_world(config, qtm_port=0, vehicle_local_ports=free_ports)
    await world.start()
    runner = asyncio.create_task(world.run())
    try:
        yield world
    finally:
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner
        await world.close()


def assert_matches_plant(world: SimulatedWorld, name: str, position_m: Any, R: Any) -> None:
    """Within the measurement model's noise (0.5 mm, 0.1° 1σ) of the resting plant."""
    truth = world.plant.body(name)
    assert np.linalg.norm(np.asarray(position_m) - truth.position_m) < 0.004
    relative = truth.rotation.T @ np.asarray(R)
    angle = np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0))
    assert np.degrees(angle) < 0.7


async def test_qtm_rt_sdk_reads_the_bodies_and_streams_the_plants_poses() -> None:
    async with running_world() as world:
        connection = await qtm_rt.connect("127.0.0.1", port=world.qtm.port, version="1.25")
        assert connection is not None
        try:
            xml = await connection.get_parameters(parameters=["6d"])
            names = [e.text for e in ET.fromstring(xml).findall("*/Body/Name")]
            assert names == list(BODIES)
            packets: list[Any] = []
            await connection.stream_frames(components=["6d"], on_packet=packets.append)
            async with asyncio.timeout(5.0):
                while len(packets) < 20:  # noqa: ASYNC110 - the SDK only offers a callback
                    await asyncio.sleep(0.01)
            await connection.stream_frames_stop()
        finally:
            connection.disconnect()
    numbers = [p.framenumber for p in packets]
    assert numbers == sorted(numbers)
    for packet in packets:
        info, bodies = packet.get_6d()
        assert info.body_count == 3
        for name, (position, rotation) in zip(BODIES, bodies, strict=True):
            position_m = frames.mm_to_m(np.array([position.x, position.y, position.z]))
            R = frames.rotation_from_qtm_matrix(rotation.matrix)
            assert_matches_plant(world, name, position_m, R)


async def test_our_client_gets_the_same_over_udp() -> None:
    async with running_world() as world, QtmClient("127.0.0.1", world.qtm.port) as client:
        received: list[MocapFrame] = []
        async with asyncio.timeout(5.0):
            while len(received) < 20:
                await client.wait_frame()
                received += client.drain()
        stats = client.stats()
    assert stats.body_names == BODIES and stats.udp_port is not None
    assert stats.malformed == stats.out_of_order == 0
    for frame in received:
        for name in BODIES:
            pose = frame.bodies[name]
            assert pose.tracked
            assert_matches_plant(world, name, pose.position_m, pose.rotation())


async def test_a_lab_naming_its_bodies_gets_the_plants_poses_under_those_names() -> None:
    names = ("Bar", "Drone1", "Drone2")
    async with (
        running_world((f"mocap.bodies={list(names)!r}".replace("'", '"'),)) as world,
        QtmClient("127.0.0.1", world.qtm.port) as client,
    ):
        frame = await client.wait_frame()
        assert client.stats().body_names == names
        for name, plant_name in zip(names, BODIES, strict=True):
            pose = frame.bodies[name]
            assert pose.tracked
            assert_matches_plant(world, plant_name, pose.position_m, pose.rotation())


async def test_a_stall_of_the_worlds_own_process_is_counted_and_said() -> None:
    """The world's event loop blocked for 0.2 s (as a busy computer would hold it): a
    stall of about that length is counted, the worst so far. (A shared machine may add
    shorter stalls of its own above the 50 ms threshold, so others are not ruled out.)"""
    async with running_world() as world:
        await asyncio.sleep(0.3)
        before = world.stalls.count
        time.sleep(0.2)  # noqa: ASYNC251 -- the point: the world's own loop does not run
        await asyncio.sleep(0.1)
        assert world.stalls.count > before
        view = world.stalls.view(world.plant.time_s)
        assert 150.0 < view["worst_ms"] < 400.0


async def frames_after(client: QtmClient, count: int, limit_s: float) -> list[MocapFrame]:
    """The frames received from now until ``count`` have arrived (a busy machine may hold
    this process far longer than the frames' own time), at most ``limit_s``."""
    frames: list[MocapFrame] = []
    deadline = time.monotonic() + limit_s
    while len(frames) < count and time.monotonic() < deadline:
        await asyncio.sleep(0.05)
        frames += client.drain()
    return frames


async def test_frames_caught_up_after_a_stall_carry_their_own_times() -> None:
    """The world's loop blocked for 80 ms, then caught up in a burst: each frame of the
    burst is stamped when the world delivered it (the frame period apart), not when it
    left (microseconds apart, which a filter reads as metres per second)."""
    async with running_world() as world, QtmClient("127.0.0.1", world.qtm.port) as client:
        await client.wait_frame()
        await asyncio.sleep(0.2)
        client.drain()
        time.sleep(0.08)  # noqa: ASYNC251 -- the point: the world's own loop does not run
        frames = await frames_after(client, count=30, limit_s=10.0)
    period_us = 1e6 / world.mocap.params.rate_hz
    steps = [
        (b.timestamp_us - a.timestamp_us) / (b.frame_number - a.frame_number)
        for a, b in itertools.pairwise(frames)
    ]
    # A longer stall of the machine's own (beyond 0.1 s, not made up) may widen one step.
    assert len(steps) > 20 and min(steps) > 0.9 * period_us, (period_us, steps)
    assert statistics.median(steps) == pytest.approx(period_us, rel=0.05)
