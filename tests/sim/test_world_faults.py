"""Faults in the simulated world: a simulated PX4's reboot and link on the bench (no
sockets), the world advanced by hand (reboot in the air, reset), and the QTM stream on
loopback as the official Qualisys SDK and our own client see it."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

import numpy as np
import pytest
import qtm_rt

from mocap.client import QtmClient
from mocap.qtm_protocol import BodyPose, MocapFrame
from px4_mavlink.px4_messages import MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET
from sim.faults import (
    LinkLost,
    MocapBodyLost,
    MocapFreeze,
    MocapJump,
    MocapSilent,
    Px4Reboot,
    UdpLoss,
)
from sim.px4 import BOOT_MODE, FORCE_MAGIC, MainMode
from sim.px4_endpoint import Px4Endpoint
from sim.world import SimulatedWorld, WorldRefusedError
from supervisor.app.config import load_config
from supervisor.app.sim_assembly import mocap_params_from_config, plant_params_from_config
from supervisor.app.world_process import build_world
from tests.conftest import CONFIGS
from tests.sim.test_px4_endpoint import Bench, Resting, of_type
from tests.sim.test_world import running_world

ARM, DISARM = (1.0, FORCE_MAGIC, 0, 0, 0, 0, 0), (0.0, FORCE_MAGIC, 0, 0, 0, 0, 0)


class Recording(Resting):
    """An airframe on the ground that keeps the commands it gets."""

    def __init__(self) -> None:
        self.commands: list[float] = []

    def command(self, thrust_n: float, torque_nm: Any) -> None:
        self.commands.append(thrust_n + float(np.abs(torque_nm).sum()))


# ---- one simulated PX4 on the bench ---------------------------------------------------------
def test_a_reboot_cuts_the_motors_silences_the_link_and_boots_as_at_power_on() -> None:
    bench = Bench()
    px4 = bench.px4
    airframe = px4.airframe = Recording()
    px4.model.parameters.set("COM_OF_LOSS_T", 0.7)  # set over MAVLink before: kept
    px4.model.set_mode(1, int(MainMode.OFFBOARD), 0, 0.0, airframe.state())
    bench.run(5.0)
    px4.model.command(400, ARM, bench.now_s, airframe.state())
    assert px4.armed
    px4.power_off()
    assert airframe.commands[-1] == 0.0 and not px4.armed
    bench.log.clear()
    bench.out.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    assert not bench.deliver()  # nobody home
    bench.run(8.0)
    assert bench.log == [] and set(airframe.commands[-100:]) == {0.0}
    assert px4.counters.datagrams == 0

    px4.boot(8.0)
    bench.run(9.0)
    assert not px4.armed and px4.model.intended == BOOT_MODE  # not OFFBOARD: booted afresh
    assert px4.model.parameters.get("COM_OF_LOSS_T") == pytest.approx(0.7)
    beats = bench.of("HEARTBEAT")
    assert beats[0][0] == pytest.approx(8.002) and beats[0][1].base_mode & 128 == 0
    # Its clock restarted: time since boot, not since the world began.
    (_, attitude), *_ = bench.of("ATTITUDE")
    assert attitude.time_boot_ms < 50
    # The first event after the boot is announced as a sequence reset.
    messages = [m for _, m in bench.log if m.get_type() in ("EVENT", "CURRENT_EVENT_SEQUENCE")]
    announce, first = messages[0], messages[1]
    assert announce.get_type() == "CURRENT_EVENT_SEQUENCE"
    assert announce.flags & MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET and announce.sequence == 0
    assert first.get_type() == "EVENT" and first.sequence == 0
    bench.out.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    assert len(of_type(bench.deliver(), "PARAM_VALUE")) == 1  # heard again


def test_the_datagram_filter_drops_what_arrives_and_what_leaves() -> None:
    bench = Bench()
    asked: list[bool] = []

    def only_leaving(inbound: bool) -> bool:
        asked.append(inbound)
        return not inbound

    bench.px4.datagram_filter = only_leaving
    bench.out.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    assert not bench.deliver() and bench.px4.counters.datagrams == 0
    bench.run(0.5)
    assert bench.log and asked[0] is True and False in asked
    bench.px4.datagram_filter = lambda inbound: inbound
    bench.log.clear()
    bench.run(1.5)
    assert bench.log == []
    bench.out.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    bench.deliver()
    assert bench.px4.counters.datagrams == 1 and bench.log == []  # heard, answer lost


# ---- the world, advanced by hand ------------------------------------------------------------
def world_of(*overrides: str, setup: str = "sim.toml") -> SimulatedWorld:
    """The world of ``setup`` (a file of configs/), not started: advanced by hand."""
    config = load_config(CONFIGS / setup, ["sim.mocap.dropout_probability=0.0", *overrides])
    return build_world(config, qtm_port=0, vehicle_local_ports=(0,) * config.system.n_vehicles)


def endpoints(world: SimulatedWorld) -> list[Px4Endpoint]:
    """Its simulated PX4s, one per UAV of its plant."""
    vehicles = [v for v in world.vehicles if isinstance(v, Px4Endpoint)]
    assert len(vehicles) == world.plant.layout.n_uavs
    return vehicles


def run(world: SimulatedWorld, duration_s: float) -> None:
    end_s = world.plant.time_s + duration_s
    while world.plant.time_s < end_s - 1e-9:
        world.advance(world.plant.time_s + 0.002)


def test_a_px4_rebooting_in_the_air_falls_and_boots_disarmed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    world = world_of()
    plant = world.plant
    plant.place_hanging((np.array([-0.9, 0.0, 2.0]), np.array([0.9, 0.0, 2.0])))
    px4s = endpoints(world)
    for px4 in px4s:  # holding the hover where they are (AUTO.LOITER, its boot mode)
        px4.model.command(400, ARM, 0.0, px4.airframe.state())
    run(world, 0.5)
    heights = [plant.body(f"uav{i}").position_m[2] for i in (1, 2)]
    assert heights == pytest.approx([2.0, 2.0], abs=0.1)
    with caplog.at_level(logging.INFO, logger="sim.world"):
        started = world.inject(Px4Reboot(1, 1.0))
        assert started.started_s == pytest.approx(0.5)
        assert not px4s[0].powered and not px4s[0].armed
        run(world, 0.6)
        assert plant.commanded(1)[0] == 0.0
        assert plant.body("uav1").position_m[2] < heights[0] - 0.5  # falling
        assert plant.body("uav2").position_m[2] > 1.5  # the other one still flies
        run(world, 0.5)
    assert px4s[0].powered and not px4s[0].armed and px4s[0].model.intended == BOOT_MODE
    assert world.fault_views() == []
    lines = [r.getMessage() for r in caplog.records]
    assert any(line.startswith("fault started at 0.500 s: px4_reboot vehicle=1") for line in lines)
    assert any("fault ended at" in line and "(expired): px4_reboot" in line for line in lines)
    assert "PX4 1: booted" in lines


def test_reset_is_refused_while_armed_and_restores_the_resting_pose() -> None:
    world = world_of()
    resting = world.plant.get_state()
    px4s = endpoints(world)
    run(world, 0.2)
    px4s[1].model.command(400, ARM, world.plant.time_s, px4s[1].airframe.state())
    with pytest.raises(WorldRefusedError, match="vehicle 2 is armed"):
        world.reset()
    px4s[1].model.command(400, DISARM, world.plant.time_s, px4s[1].airframe.state())
    px4s[0].model.set_mode(1, int(MainMode.OFFBOARD), 0, 0.2, px4s[0].airframe.state())
    world.plant.set_body("bar", position_m=np.array([1.0, 1.0, 0.5]))
    world.inject(MocapBodyLost("bar"))
    world.inject(LinkLost(2))
    cleared = world.reset()
    assert [c.fault.kind for c in cleared] == ["mocap_body_lost", "link_lost"]
    assert world.fault_views() == []
    np.testing.assert_allclose(world.plant.get_state(), resting)
    assert all(px4.model.intended == BOOT_MODE and not px4.armed for px4 in px4s)
    run(world, 0.3)  # and it stays at rest
    for name in ("bar", "uav1", "uav2"):
        start = world.plant.body(name)
        np.testing.assert_allclose(start.velocity_mps, 0.0, atol=0.01)


def test_the_world_publishes_what_the_faults_make_of_each_frame(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    world = world_of()
    published: list[dict[str, BodyPose]] = []
    monkeypatch.setattr(
        world.qtm, "publish", lambda poses, at_s=None: published.append(dict(poses))
    )
    run(world, 0.1)
    world.inject(MocapJump("uav1", (0.0, 0.0, 0.5), 0.1))
    world.inject(MocapBodyLost("uav2", 0.1))
    before = len(published)
    run(world, 0.05)
    during = published[before:]
    assert during and all(not frame["uav2"].tracked for frame in during)
    truth_z = world.plant.body("uav1").position_m[2]
    assert all(
        frame["uav1"].position_m[2] == pytest.approx(truth_z + 0.5, abs=0.01) for frame in during
    )
    run(world, 0.1)
    assert published[-1]["uav2"].tracked
    assert published[-1]["uav1"].position_m[2] == pytest.approx(truth_z, abs=0.01)


class Firmware:
    """A vehicle the world cannot reach into (as a real PX4 SITL process)."""

    armed = False

    async def start(self) -> None: ...

    async def close(self) -> None: ...

    def step(self, now_s: float) -> None: ...

    def describe(self) -> str:
        return "firmware"


@pytest.mark.parametrize(
    ("fault", "words"),
    [
        (LinkLost(2), "vehicle 2 is a real PX4 SITL process"),
        (Px4Reboot(1), "cannot reboot it faithfully"),
        (UdpLoss(0.1), "cannot drop its datagrams"),
    ],
)
def test_what_the_world_cannot_do_to_real_firmware_is_refused_with_the_reason(
    fault: Any, words: str
) -> None:
    config = load_config(CONFIGS / "sim.toml")
    world = SimulatedWorld(
        plant_params_from_config(config),
        mocap_params_from_config(config),
        lambda plant, uav: Firmware(),
        qtm_port=0,
    )
    with pytest.raises(WorldRefusedError, match=words):
        world.inject(fault)
    with pytest.raises(WorldRefusedError, match="cannot put its firmware back"):
        world.reset()
    assert world.fault_views() == []
    world.inject(MocapSilent(1.0))  # the mocap is the world's own
    assert [f["kind"] for f in world.fault_views()] == ["mocap_silent"]


# ---- the QTM stream on loopback, in real time -------------------------------------------------
async def test_mocap_silent_stops_both_clients_frames_then_they_resume_with_a_gap() -> None:
    async with running_world() as world, QtmClient("127.0.0.1", world.qtm.port) as ours:
        connection = await qtm_rt.connect("127.0.0.1", port=world.qtm.port, version="1.25")
        assert connection is not None
        try:
            sdk: list[Any] = []  # qtm-rt streams over its TCP connection
            await connection.stream_frames(components=["6d"], on_packet=sdk.append)
            async with asyncio.timeout(10.0):
                await ours.wait_frame()
                while not sdk:  # noqa: ASYNC110 - the SDK only offers a callback
                    await asyncio.sleep(0.01)
            # Long beside the 0.4 s looked at: this process (world and test in one) may
            # lose the CPU for a third of a second beside the suite's lanes, and the
            # silence is on the world's clock.
            world.inject(MocapSilent(2.0))
            await asyncio.sleep(0.1)  # frames already on their way
            ours.drain()
            sdk.clear()
            await asyncio.sleep(0.3)
            assert ours.drain() == [] and sdk == []
            async with asyncio.timeout(10.0):
                frame = await ours.wait_frame()
                while not sdk:  # noqa: ASYNC110
                    await asyncio.sleep(0.01)
            await connection.stream_frames_stop()
        finally:
            connection.disconnect()
    # QTM kept counting through the silence: the client sees the frames it missed.
    assert ours.stats().frames_missed >= 40
    assert frame.bodies["bar"].tracked


async def test_frozen_frames_keep_coming_with_new_numbers_and_the_same_poses() -> None:
    async with running_world() as world, QtmClient("127.0.0.1", world.qtm.port) as client:
        async with asyncio.timeout(10.0):
            await client.wait_frame()
        world.inject(MocapFreeze(1.0))
        await asyncio.sleep(0.1)
        client.drain()
        # 15 of the freeze's 100 frames, however long a busy machine stalls the world.
        frames: list[MocapFrame] = []
        async with asyncio.timeout(10.0):
            while len(frames) < 15:
                await asyncio.sleep(0.05)
                frames += client.drain()
    numbers = [f.frame_number for f in frames]
    assert numbers == sorted(set(numbers))
    first = frames[0].bodies
    for frame in frames[1:]:
        for name, pose in frame.bodies.items():
            np.testing.assert_array_equal(pose.position_m, first[name].position_m)
            np.testing.assert_array_equal(pose.quaternion, first[name].quaternion)


async def test_udp_loss_drops_that_share_of_the_mocap_datagrams() -> None:
    async with running_world() as world, QtmClient("127.0.0.1", world.qtm.port) as client:
        async with asyncio.timeout(10.0):
            await client.wait_frame()
        world.inject(UdpLoss(0.5))
        await asyncio.sleep(0.05)
        before = client.stats()
        await asyncio.sleep(1.0)
        after = client.stats()
    received = after.frames - before.frames
    lost = after.frames_missed - before.frames_missed
    assert received + lost >= 50
    assert 0.3 < lost / (received + lost) < 0.7
