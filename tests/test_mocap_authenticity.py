"""Mocap authenticity and plausibility on loopback (issue 18): the simulated QTM server, the
real client, the fusion and the safety monitor, against a spoofer with a socket of its own
and against a jump in the server's own stream."""

from __future__ import annotations

import asyncio
import contextlib
import math
import re
import time
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from geometry import frames
from geometry.state import TH_B, payload_position
from mocap.client import QtmClient
from mocap.fusion import MocapFusion
from mocap.qtm_protocol import BodyPose, ComponentType, encode_packet, packet_from_poses
from sim.qtm_server import QtmServer
from supervisor.app.assembly import arena_from_config, body_names_from_config, fusion_from_config
from supervisor.app.config import load_config
from supervisor.app.relay_main import PlausibleSource
from supervisor.flight.estimation import Estimate, estimate_state
from supervisor.flight.modes import Mode
from supervisor.flight.safety import Fault, Response, SafetyLimits, SafetyMonitor
from tests.conftest import CONFIGS
from tests.mocap.test_client import udp_sender, wait_until

CONFIG = load_config(CONFIGS / "sim.toml")
PARAMS = CONFIG.system.to_params()
NAMES = tuple(CONFIG.mocap.bodies)
BAR, UAV1, _ = NAMES
LOCALHOST = "127.0.0.1"
HOVER = formation_equilibrium(PARAMS, FormationReference((0.0, 0.5, 1.0), 0.3, (0.0, 0.0))).x
LAYOUT = PARAMS.layout


def hover_poses(rng: np.random.Generator, jump: Mapping[str, float]) -> dict[str, BodyPose]:
    """The system hovering at its equilibrium, with the simulated mocap's noise (0.5 mm,
    0.1°); ``jump``: bodies whose reported height is raised [m]."""
    truth = {
        BAR: (payload_position(HOVER), frames.quaternion_from_euler_zyx(0.0, *HOVER[TH_B][1:])),
        **{
            name: (
                LAYOUT.uav_position(HOVER, i),
                frames.quaternion_from_euler_zyx(*LAYOUT.uav_euler(HOVER, i)),
            )
            for i, name in ((1, NAMES[1]), (2, NAMES[2]))
        },
    }
    poses = {}
    for name, (position, q) in truth.items():
        noisy_q = frames.quaternion_multiply(
            q, frames.quaternion_from_rotation_vector(rng.normal(0.0, math.radians(0.1), 3))
        )
        offset = np.array([0.0, 0.0, jump.get(name, 0.0)])
        poses[name] = BodyPose.from_quaternion(
            name, position + offset + rng.normal(0.0, 5e-4, 3), noisy_q
        )
    return poses


@dataclass
class Hover:
    """A hovering system streamed by the simulated server, read by a client, fused."""

    server: QtmServer
    client: QtmClient
    fusion: MocapFusion
    jump: dict[str, float]

    def estimate(self) -> Estimate:
        return estimate_state(self.fusion.states(time.monotonic()), body_names_from_config(CONFIG))

    def bar_error_m(self) -> float:
        return float(np.linalg.norm(payload_position(self.estimate().x) - payload_position(HOVER)))


@contextlib.asynccontextmanager
async def hovering(transport: Literal["udp", "tcp"] = "udp") -> AsyncIterator[Hover]:
    rng = np.random.default_rng(18)
    jump: dict[str, float] = {}
    fusion = fusion_from_config(CONFIG)
    async with (
        QtmServer(NAMES, lambda _t: hover_poses(rng, jump), port=0, rate_hz=100.0) as server,
        QtmClient(LOCALHOST, server.port, transport=transport) as client,
    ):

        def fuse() -> None:
            for frame in client.drain():
                fusion.update(frame)

        client.on_frame(fuse)
        await wait_until(lambda: client.stats().frames >= 30)
        yield Hover(server, client, fusion, jump)


def mocap_faults(hover: Hover, monitor: SafetyMonitor) -> list[Fault]:
    faults = monitor.check(time.monotonic(), hover.estimate(), Mode.HOVER, None, (True, True))
    return [f for f in faults if f.monitor == "mocap"]


async def test_spoofed_frames_from_another_port_never_move_the_estimate_and_are_counted() -> None:
    """Well-formed 6D frames from a socket of its own, the bar 1 m higher and the frame
    numbers 50 ahead, twice the stream's rate for 0.5 s: the estimate stays within 1 cm,
    the real stream is never taken as out of order, every spoofed frame is counted."""
    async with hovering() as hover, udp_sender() as spoofer:
        client = hover.client
        target = (LOCALHOST, client.udp_port)
        before = client.stats()
        worst_m = 0.0
        sent = 0
        spoof = {BAR: 1.0}
        rng = np.random.default_rng(50)
        for _ in range(100):
            number = hover.server.frame_number + 50
            poses = hover_poses(rng, spoof)
            packet = packet_from_poses(number, number * 10_000, NAMES, poses, [ComponentType.SIX_D])
            spoofer.sendto(encode_packet(packet), target)
            sent += 1
            await asyncio.sleep(0.005)
            worst_m = max(worst_m, hover.bar_error_m())
        await wait_until(lambda: client.stats().foreign_port_datagrams == sent)
        after = client.stats()
        assert after.server_udp_port == hover.server.udp_port
    assert worst_m < 0.01
    assert after.frames - before.frames >= 40  # the real stream went on (0.5 s at 100 Hz)
    assert after.out_of_order == after.frame_number_jumps == 0
    assert after.refused() == {"foreign_port": sent}
    assert hover.fusion.refused() == {"position": 0, "attitude": 0, "repeated": 0}


async def test_a_jump_from_the_servers_own_stream_is_refused_and_if_it_persists_is_a_fault() -> (
    None
):
    monitor = SafetyMonitor(PARAMS, arena_from_config(CONFIG), SafetyLimits())
    limit = SafetyLimits().max_refused_poses
    async with hovering() as hover:
        assert mocap_faults(hover, monitor) == []
        # A blip of 3 frames: refused, never fused, no fault.
        hover.jump[UAV1] = 1.0
        await wait_until(lambda: hover.fusion.refused()["position"] >= 3)
        hover.jump.clear()
        await wait_until(lambda: hover.estimate().refused == ())
        assert mocap_faults(hover, monitor) == []
        # 1 m for good: refused, the estimate stays, and after the limit the fault.
        refused_before = hover.fusion.refused()["position"]
        hover.jump[UAV1] = 1.0
        worst_m = 0.0
        faults: list[Fault] = []
        async with asyncio.timeout(2.0):
            while not faults:
                await asyncio.sleep(0.002)
                estimate = hover.estimate()
                error = LAYOUT.uav_position(estimate.x, 1) - LAYOUT.uav_position(HOVER, 1)
                worst_m = max(worst_m, float(np.linalg.norm(error)))
                faults = [f for f in mocap_faults(hover, monitor) if "refused" in f.message]
        refused = hover.fusion.refused()["position"] - refused_before
    assert worst_m < 0.01
    [fault] = faults
    assert fault.response is Response.PX4_LAND
    refusal = rf"{UAV1}: (\d+) poses in a row refused \((0\.9|1\.0)\d\d m from"
    match = re.match(refusal, fault.message)
    assert match is not None, fault.message
    assert limit <= int(match.group(1)) == refused
    assert hover.client.stats().frame_number_jumps == 0


async def test_frames_over_the_tcp_command_connection() -> None:
    async with hovering("tcp") as hover:
        stats = hover.client.stats()
        await wait_until(lambda: hover.client.stats().frames >= stats.frames + 20)
        error_m = hover.bar_error_m()
    assert hover.server.commands[2] == "StreamFrames AllFrames 6D"
    assert stats.transport == "tcp" and stats.udp_port is None
    assert stats.out_of_order == stats.duplicates == stats.malformed == 0
    assert error_m < 0.005


async def test_the_relay_passes_on_only_poses_the_gate_takes() -> None:
    """What the mocap relay sends each PX4's estimator (``PlausibleSource``): a jumped pose
    goes out as untracked, the other bodies as they came."""
    rng = np.random.default_rng(19)
    jump: dict[str, float] = {}
    async with (
        QtmServer(NAMES, lambda _t: hover_poses(rng, jump), port=0, rate_hz=100.0) as server,
        QtmClient(LOCALHOST, server.port) as client,
    ):
        gated = PlausibleSource(client, fusion_from_config(CONFIG))

        def read_as_the_relay_does() -> None:  # the newest frame, as each one arrives
            gated.latest()

        gated.on_frame(read_as_the_relay_does)
        await wait_until(lambda: client.stats().frames >= 20)
        before = gated.drain()
        assert before and all(p.tracked for p in before[-1].bodies.values())
        jump[UAV1] = 1.0
        await wait_until(lambda: gated.fusion.refused()["position"] >= 5)
        jumped = gated.drain()
        jump.clear()
        await asyncio.sleep(0.05)
        after = gated.drain()
    untracked = [f for f in jumped if not f.bodies[UAV1].tracked]
    assert len(untracked) >= 5 and all(f.bodies[BAR].tracked for f in jumped)
    for frame in jumped:  # whatever got through is where the body is
        pose = frame.bodies[UAV1]
        if pose.tracked:
            assert np.linalg.norm(pose.position_m - LAYOUT.uav_position(HOVER, 1)) < 0.01
    assert after and all(f.bodies[UAV1].tracked for f in after[1:])
