"""The simulated world of three UAVs and a plate (configs/sim_tri.toml): one simulated PX4
per UAV, each on its own MAVLink endpoint; the QTM server streaming the plate and the three
UAVs under their configured names; faults on any of its vehicles and bodies, and none on a
vehicle it does not have."""

from __future__ import annotations

import asyncio
import socket
import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
import pydantic
import pytest
import qtm_rt

from geometry import frames
from mocap.client import QtmClient
from mocap.qtm_protocol import BodyPose
from px4_mavlink.codec import MavlinkCodec, mavlink
from sim.faults import FaultError, LinkLost, MocapBodyLost, MocapJump, Push, Px4Reboot
from sim.world import SimulatedWorld
from supervisor.app.config import load_config
from supervisor.app.sim_assembly import mocap_params_from_config, plant_params_from_config
from supervisor.app.world_process import handle_world_request
from supervisor.flight.operator_requests import Outcome
from supervisor.ipc.world_messages import FaultSpec, ResetWorld, StartFault
from tests.conftest import CONFIGS
from tests.sim.test_world import assert_matches_plant, running_world
from tests.sim.test_world_faults import ARM, DISARM, Firmware, endpoints, run, world_of

SETUP = "sim_tri.toml"
BODIES = ("payload", "uav1", "uav2", "uav3")  # mocap.bodies: the plate's name, then the UAVs'
FAULT: pydantic.TypeAdapter[Any] = pydantic.TypeAdapter(FaultSpec)
CLIENT_SYSTEM = 245  # a companion computer's system id, as the supervisor's links use


def overriding_bodies(names: tuple[str, ...]) -> str:
    return f"mocap.bodies={list(names)!r}".replace("'", '"')


async def first_heartbeat(port: int) -> tuple[Any, tuple[str, int]]:
    """Talk to the simulated PX4 listening on ``port`` (a heartbeat makes us its partner);
    its first heartbeat back, and the address it came from."""
    codec = MavlinkCodec(system=CLIENT_SYSTEM, component=190)
    codec.messages.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4)
    loop = asyncio.get_running_loop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        for frame in codec.outgoing():
            await loop.sock_sendto(sock, frame, ("127.0.0.1", port))
        async with asyncio.timeout(10.0):  # PX4 beats at 1 Hz; a busy machine is slower
            while True:
                datagram, sender = await loop.sock_recvfrom(sock, 65535)
                for message in codec.decode(datagram).messages:
                    if message.get_type() == "HEARTBEAT":
                        return message, sender


# ---- on loopback, in real time ---------------------------------------------------------------
async def test_three_px4s_answer_heartbeats_each_on_its_own_port_with_its_system_id() -> None:
    async with running_world(("vehicles.system_ids=[7, 8, 9]",), setup=SETUP) as world:
        ports = [px4.local_port for px4 in endpoints(world)]
        assert len(set(ports)) == 3
        answers = [await first_heartbeat(port) for port in ports]
    assert [beat.get_srcSystem() for beat, _ in answers] == [7, 8, 9]
    assert [sender for _, sender in answers] == [("127.0.0.1", port) for port in ports]
    assert all(beat.type == mavlink.MAV_TYPE_QUADROTOR for beat, _ in answers)


async def test_qtm_rt_sdk_reads_the_plate_and_three_uavs_with_the_plants_poses() -> None:
    async with running_world(setup=SETUP) as world:
        connection = await qtm_rt.connect("127.0.0.1", port=world.qtm.port, version="1.25")
        assert connection is not None
        try:
            xml = await connection.get_parameters(parameters=["6d"])
            names = [e.text for e in ET.fromstring(xml).findall("*/Body/Name")]
            packets: list[Any] = []
            await connection.stream_frames(components=["6d"], on_packet=packets.append)
            async with asyncio.timeout(10.0):
                while len(packets) < 10:  # noqa: ASYNC110 - the SDK only offers a callback
                    await asyncio.sleep(0.01)
            await connection.stream_frames_stop()
        finally:
            connection.disconnect()
    assert names == list(BODIES)
    for packet in packets:
        info, bodies = packet.get_6d()
        assert info.body_count == 4
        for name, (position, rotation) in zip(BODIES, bodies, strict=True):
            position_m = frames.mm_to_m(np.array([position.x, position.y, position.z]))
            R = frames.rotation_from_qtm_matrix(rotation.matrix)
            assert_matches_plant(world, name, position_m, R)


async def test_a_lab_naming_the_four_bodies_gets_the_plants_poses_under_those_names() -> None:
    names = ("Plate", "Drone1", "Drone2", "Drone3")
    async with (
        running_world((overriding_bodies(names),), setup=SETUP) as world,
        QtmClient("127.0.0.1", world.qtm.port) as client,
    ):
        async with asyncio.timeout(10.0):
            frame = await client.wait_frame()
        assert client.stats().body_names == names
        for name, plant_name in zip(names, BODIES, strict=True):
            pose = frame.bodies[name]
            assert pose.tracked
            assert_matches_plant(world, plant_name, pose.position_m, pose.rotation())


# ---- the world, advanced by hand ------------------------------------------------------------
def hanging_world() -> SimulatedWorld:
    """The tri world with the plate hanging under its three UAVs at 2 m, each PX4 armed and
    holding the hover where it is (AUTO.LOITER, its boot mode)."""
    world = world_of(setup=SETUP)
    corners = world.plant.params.payload_body().attachments_body_m
    world.plant.place_hanging([np.array([c[0], c[1], 2.0]) for c in corners])
    for px4 in endpoints(world):
        px4.model.command(400, ARM, 0.0, px4.airframe.state())
    run(world, 0.5)
    return world


def test_vehicle_3_reboots_in_the_air_and_falls_while_the_others_fly_on() -> None:
    world = hanging_world()
    plant = world.plant
    heights_m = [plant.body(f"uav{i}").position_m[2] for i in (1, 2, 3)]
    assert heights_m == pytest.approx([2.0, 2.0, 2.0], abs=0.1)
    world.inject(Px4Reboot(3, 1.0))
    px4s = endpoints(world)
    assert [px4.powered for px4 in px4s] == [True, True, False]
    run(world, 0.6)
    assert plant.commanded(3)[0] == 0.0
    assert plant.body("uav3").position_m[2] < heights_m[2] - 0.5  # falling
    assert plant.body("uav1").position_m[2] > 1.5 and plant.body("uav2").position_m[2] > 1.5
    # The world's truth covers every body: the one that fell, the fastest.
    descents = world.truth.descent_by_body_mps
    assert set(descents) == set(BODIES)
    assert max(descents, key=descents.__getitem__) == "uav3"
    assert "uav3" in world.truth.describe()


def test_a_fault_on_vehicle_4_of_three_is_refused_naming_the_vehicle() -> None:
    world = world_of(setup=SETUP)
    with pytest.raises(FaultError, match=r"vehicle: 4 is not a vehicle of this world \(its"):
        world.inject(LinkLost(4))
    refused = handle_world_request(
        world, StartFault(fault=FAULT.validate_python({"kind": "px4_reboot", "vehicle": 4}))
    )
    assert refused.outcome is Outcome.INVALID
    assert refused.reason == "vehicle: 4 is not a vehicle of this world (its vehicles: 1 to 3)"
    assert world.fault_views() == []
    accepted = handle_world_request(
        world, StartFault(fault=FAULT.validate_python({"kind": "link_lost", "vehicle": 3}))
    )
    assert accepted.outcome is Outcome.OK
    assert accepted.data["fault"]["params"] == {"vehicle": 3}
    link = endpoints(world)[2].datagram_filter
    assert link is not None and not link(True) and not link(False)


def test_the_world_publishes_what_faults_on_the_plate_and_uav3_make_of_each_frame(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    world = world_of(setup=SETUP)
    published: list[dict[str, BodyPose]] = []
    monkeypatch.setattr(
        world.qtm, "publish", lambda poses, at_s=None: published.append(dict(poses))
    )
    run(world, 0.1)
    assert set(published[-1]) == set(BODIES)
    world.inject(MocapBodyLost("uav3", 0.1))
    world.inject(MocapJump("payload", (0.0, 0.0, 0.5), 0.1))
    before = len(published)
    run(world, 0.05)
    during = published[before:]
    truth_z_m = world.plant.body("payload").position_m[2]
    assert during and all(not frame["uav3"].tracked for frame in during)
    assert all(frame["uav2"].tracked for frame in during)
    assert all(
        frame["payload"].position_m[2] == pytest.approx(truth_z_m + 0.5, abs=0.01)
        for frame in during
    )


def test_a_push_on_uav3_is_a_load_on_the_plants_uav3() -> None:
    world = world_of(overriding_bodies(("Plate", "D1", "D2", "D3")), setup=SETUP)
    world.inject(Push("D3", (0.0, 0.0, 5.0), 1.0))
    [load] = world.plant.loads
    assert load.body == "uav3" and load.force_n == (0.0, 0.0, 5.0)


def test_reset_puts_all_four_bodies_back_and_stops_every_motor() -> None:
    world = hanging_world()
    for px4 in endpoints(world):  # disarmed where they are: the reset moves the vehicles
        px4.model.command(400, DISARM, world.plant.time_s, px4.airframe.state())
    world.inject(Px4Reboot(3))
    reply = handle_world_request(world, ResetWorld())
    assert reply.outcome is Outcome.OK, reply.reason
    positions = reply.data["resting_positions"]
    assert tuple(positions) == BODIES
    for name, position in positions.items():
        assert position[2] < 0.3, name  # on the ground
    assert [world.plant.commanded(uav)[0] for uav in (1, 2, 3)] == [0.0, 0.0, 0.0]
    assert world.fault_views() == []


def test_a_world_given_the_bars_three_body_names_for_four_bodies_is_refused() -> None:
    config = load_config(CONFIGS / SETUP)
    with pytest.raises(ValueError, match=r"one per UAV \(4 names\), got \['bar', 'uav1', 'uav2'\]"):
        SimulatedWorld(
            plant_params_from_config(config),
            mocap_params_from_config(config),
            lambda plant, uav: Firmware(),
            body_names=("bar", "uav1", "uav2"),
        )
