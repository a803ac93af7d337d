"""Real PX4 v1.15.4 SITL in the loop (``sim.vehicles = "px4_sitl"``): what only the real
firmware can show — its own failsafe when the supervisor dies, its own reasons."""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import re
import signal
import socket
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import pytest

from benchmarks.service import RunningService, all_disarmed, in_mode, notices, running_service
from benchmarks.tick import flight_truths, world_truth
from geometry.frames import rotation_from_quaternion
from mocap.client import QtmClient
from px4_mavlink.codec import MavlinkCodec
from px4_mavlink.events import EventCatalog
from sim.px4_firmware import OFFBOARD_LOCAL_PORT, resolve_px4_dir
from supervisor.flight.modes import Mode
from supervisor.flight.status import Status
from supervisor.mavlink.parameters import MAV_PARAM_TYPE_INT32, encode_param_value
from supervisor.mavlink.session import px4_mode_name
from tests.test_service import TOKEN, ready, require_px4

pytestmark = [pytest.mark.px4, pytest.mark.slow]

OFFBOARD_LOSS_TIMEOUT_S = 0.5  # vehicles.offboard_loss_timeout_s, written as COM_OF_LOSS_T
MAV_MODE_FLAG_SAFETY_ARMED = 128
GCS_PORT = 14550  # PX4 SITL's ground-station link, every instance
GCS_LOCAL_PORT = 18570  # PX4's end of that link: 18570 + instance


FAILSAFE_OVERRIDES = [
    'sim.vehicles="px4_sitl"',
    f"vehicles.offboard_loss_timeout_s={OFFBOARD_LOSS_TIMEOUT_S}",
]


def px4_event_catalog() -> EventCatalog:
    """The firmware's own event texts, to read its EVENT messages."""
    return EventCatalog.load(resolve_px4_dir(None) / "etc" / "extras" / "all_events.json.xz")


@dataclass
class Px4Watch:
    """What one PX4 says on its offboard link, with arrival times (monotonic)."""

    modes: list[tuple[float, str]] = field(default_factory=list)
    events: list[tuple[float, str]] = field(default_factory=list)
    armed_modes: list[tuple[float, str]] = field(default_factory=list)
    """The mode of each heartbeat sent while armed."""


async def watch_px4s(catalog: EventCatalog, watches: dict[int, Px4Watch], until: float) -> None:
    """Listen where every PX4 sends its ground-station link (UDP 14550; system id tells
    the vehicles apart); the offboard link's port is the dead flight process's, still held
    by the mocap relay."""
    codec = MavlinkCodec(255, 190)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", GCS_PORT))
    sock.setblocking(False)
    loop = asyncio.get_running_loop()
    try:
        while time.monotonic() < until:
            try:
                async with asyncio.timeout(0.2):
                    data = await loop.sock_recv(sock, 4096)
            except TimeoutError:
                continue
            now = time.monotonic()
            for message in codec.decode(data).messages:
                watch = watches.get(message.get_srcSystem())
                if watch is None or message.get_srcComponent() != 1:
                    continue
                kind = message.get_type()
                if kind in ("HEARTBEAT", "CURRENT_MODE"):
                    watch.modes.append((now, px4_mode_name(message.custom_mode)))
                if kind == "HEARTBEAT" and message.base_mode & MAV_MODE_FLAG_SAFETY_ARMED:
                    watch.armed_modes.append((now, px4_mode_name(message.custom_mode)))
                elif kind == "EVENT":
                    watch.events.append((now, catalog.text(message.id, bytes(message.arguments))))
    finally:
        sock.close()


async def freeze_flight_process(
    service: RunningService, http: httpx.AsyncClient, freeze_s: float
) -> Status:
    """SIGSTOP the flight process for ``freeze_s``, then: below PX4's offboard-loss timeout
    the hover goes on streaming (then a landing is asked for); beyond it the system is
    handed to PX4 and streams nothing. The status that showed it."""
    flight = service.child_pid("uavbar-flight")
    os.kill(flight, signal.SIGSTOP)
    await asyncio.sleep(freeze_s)
    os.kill(flight, signal.SIGCONT)
    if freeze_s < OFFBOARD_LOSS_TIMEOUT_S:
        await asyncio.sleep(3.0)
        status = await service.status(http)
        assert status.mode is Mode.HOVER and status.streaming, status.notices
        assert (await http.post("/api/land")).status_code == 200
        return status
    status = await service.wait_for(
        http, in_mode(Mode.PX4_LANDING, Mode.DISARMED), 5.0, "handed over"
    )
    assert not status.streaming
    return status


def tilt_deg(quaternion: np.ndarray) -> float:
    return math.degrees(
        math.acos(float(np.clip(rotation_from_quaternion(quaternion)[2, 2], -1, 1)))
    )


@pytest.mark.px4_flight
async def test_killed_flight_process_px4_lands_the_bar_itself(tmp_path: Path) -> None:
    """SIGKILL the flight process mid-hover: each PX4 leaves offboard within COM_OF_LOSS_T
    + 0.2 s (its failsafe event), lands (AUTO.LAND) with no UAV tilting beyond 30°, and the
    API stays up and says why; serve starts the flight process again."""
    require_px4()
    catalog = px4_event_catalog()
    async with (
        running_service(TOKEN, tmp_path, FAILSAFE_OVERRIDES) as service,
        service.client() as http,
    ):
        world = next(line for line in service.output if "simulated world: QTM" in line)
        qtm_host, qtm_port = re.search(r"QTM (\S+):(\d+)", world).groups()  # type: ignore[union-attr]
        await service.take_off(http)
        await asyncio.sleep(3.0)
        async with QtmClient(qtm_host, int(qtm_port)) as mocap:
            await mocap.wait_frame()
            watches = {1: Px4Watch(), 2: Px4Watch()}
            listener = asyncio.create_task(watch_px4s(catalog, watches, time.monotonic() + 27.0))
            await asyncio.sleep(1.0)
            os.kill(service.child_pid("uavbar-flight"), signal.SIGKILL)
            killed = time.monotonic()
            worst_tilt, worst_at, landed_at = 0.0, "", None
            while time.monotonic() < killed + 25.0:
                frame = await mocap.wait_frame()
                uavs = [frame.bodies[name] for name in ("uav1", "uav2")]
                if all(u.tracked for u in uavs):
                    for k, uav in enumerate(uavs, start=1):
                        tilt = tilt_deg(np.asarray(uav.quaternion))
                        if tilt > worst_tilt:
                            worst_tilt = tilt
                            worst_at = (
                                f"UAV {k} at {time.monotonic() - killed:.2f} s after the kill, "
                                f"{uav.position_m[2]:.2f} m high"
                            )
                    if landed_at is None and all(u.position_m[2] < 0.15 for u in uavs):
                        landed_at = time.monotonic()
            await listener
        status = await service.status(http)
    for i, watch in watches.items():
        failsafe = [
            t - killed for t, text in watch.events if "Failsafe activated" in text and t > killed
        ]
        assert failsafe, f"vehicle {i}: no failsafe event; events: {watch.events}"
        assert failsafe[0] <= OFFBOARD_LOSS_TIMEOUT_S + 0.2, (i, failsafe[0], watch.events)
        assert "AUTO.LAND" in {mode for _, mode in watch.modes}, (i, watch.modes)
    assert landed_at is not None, "the UAVs did not land within 25 s"
    assert worst_tilt < 30.0, (worst_tilt, worst_at, world_truth(service.output))
    assert status.processes["flight"].restarts == 1
    said = " ".join(notices(status))
    assert "the flight process died (killed by SIGKILL)" in said, said


@pytest.mark.px4_flight
@pytest.mark.parametrize("freeze_s", [0.3, 1.0, 5.0])  # issue 17's durations
async def test_a_frozen_flight_process_on_real_px4_never_flips_a_uav(
    tmp_path: Path, freeze_s: float
) -> None:
    """SIGSTOP the flight process mid-hover. Below COM_OF_LOSS_T PX4 keeps flying the held
    rate setpoint and the hover goes on; beyond it each PX4's failsafe lands (its event,
    AUTO.LAND), never goes back to offboard, and the resumed supervisor hands over and
    follows the landing. No UAV tilts beyond 30°, nothing falls faster than 1 m/s (truth)."""
    require_px4()
    catalog = px4_event_catalog()
    async with (
        running_service(TOKEN, tmp_path, FAILSAFE_OVERRIDES) as service,
        service.client() as http,
    ):
        await service.take_off(http)
        await asyncio.sleep(3.0)
        watches = {1: Px4Watch(), 2: Px4Watch()}
        listener = asyncio.create_task(watch_px4s(catalog, watches, time.monotonic() + 30.0))
        await asyncio.sleep(1.0)
        stopped = time.monotonic()
        await freeze_flight_process(service, http, freeze_s)
        await service.wait_for(http, in_mode(Mode.DISARMED), 60.0, "landed")
        listener.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await listener
    for i, watch in watches.items():
        failsafe = [t - stopped for t, text in watch.events if "Failsafe activated" in text]
        # Disarmed on the ground, PX4 shows the mode it was asked for again: not flown.
        after = [mode for t, mode in watch.armed_modes if t > stopped]
        if freeze_s < OFFBOARD_LOSS_TIMEOUT_S:
            assert not failsafe, (i, watch.events)
            continue
        assert failsafe and failsafe[0] <= OFFBOARD_LOSS_TIMEOUT_S + 0.2, (i, watch.events)
        assert "AUTO.LAND" in after, (i, watch.modes)
        landing = after.index("AUTO.LAND")
        assert "OFFBOARD" not in after[landing:], (i, after)  # nothing took it back
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth


def _param_set(name: str, value: int) -> list[bytes]:
    codec = MavlinkCodec(255, 190)
    for system in (1, 2):
        codec.messages.param_set_send(
            system,
            1,
            name.encode(),
            encode_param_value(value, MAV_PARAM_TYPE_INT32),
            MAV_PARAM_TYPE_INT32,
        )
    return codec.outgoing()


@pytest.mark.px4_flight
async def test_a_killed_agents_px4_lands_blind_and_its_peer_sets_its_end_down(
    tmp_path: Path,
) -> None:
    """SIGKILL agent 2 of 2 in hover on real PX4: its vehicle loses both its setpoints and
    its vision. Its PX4 must land blind on its barometer, not end in flight termination
    (with the mocap as its only height, it did: UAV 2 fell, tilted 180°). Agent 1 lowers its
    bar end at most 0.5 m/s; nothing tilts 30° (the world's truth)."""
    require_px4()
    overrides = ["agents.enabled=true", *FAILSAFE_OVERRIDES]
    async with running_service(TOKEN, tmp_path, overrides) as service, service.client() as http:
        status = await service.wait_for(
            http,
            lambda s: s.agents is not None and all(a.alive for a in s.agents),
            60.0,
            "both agents heard",
        )
        assert status.agents is not None and status.agents[1].pid is not None
        await service.take_off(http)
        await asyncio.sleep(2.0)
        os.kill(status.agents[1].pid, signal.SIGKILL)
        await service.wait_for(http, in_mode(Mode.DISARMING, Mode.DISARMED), 60.0, "UAV 1 down")
        await asyncio.sleep(1.0)  # the world's truth of the flight, said as it ends
    px4_said = (tmp_path / "px4" / "uav2" / "px4.log").read_text(errors="replace")
    assert "Flight termination" not in px4_said, px4_said[-2000:]
    assert "Landing detected" in px4_said, px4_said[-2000:]
    killed = flight_truths(service.output)[0]
    assert killed["max_uav_tilt_deg"] < 30.0, killed
    assert killed["max_descent_uav1_mps"] <= 0.5, killed  # what agent 1 flies


async def test_a_refused_arm_carries_px4s_own_reason(tmp_path: Path) -> None:
    """PX4 told to require GPS (COM_ARM_WO_GPS 0, over its ground-station link) refuses to
    arm in a mocap arena: the API's refusal, the status notices and the vehicle's text give
    PX4's own words, decoded from its EVENTs."""
    require_px4()
    overrides = ['sim.vehicles="px4_sitl"']
    async with running_service(TOKEN, tmp_path, overrides) as service, service.client() as http:
        await ready(service, http)
        await require_gps_for_arming(service)
        response = await http.post("/api/arm")
        status = await service.wait_for(http, lambda s: bool(s.notices), 5.0, "a notice")
    assert response.status_code == 409, response.text
    reason = response.json()["detail"]
    assert PX4_REFUSAL.search(reason), reason
    said = " ".join(notices(status))
    assert "arming refused" in said and PX4_REFUSAL.search(said), said
    assert all_disarmed(status)


# "Arming denied: …" (its EVENT) and "Preflight Fail: …" (its text) are PX4's words, never
# the supervisor's; which of them comes first varies from run to run.
PX4_REFUSAL = re.compile(r"command 400 temporarily rejected \((Arming denied|Preflight Fail)")


async def require_gps_for_arming(service: RunningService) -> None:
    """Tell both PX4s, over their ground-station links, to require GPS to arm
    (COM_ARM_WO_GPS 0): in a mocap arena they will refuse."""
    world = next(line for line in service.output if "simulated world: QTM" in line)
    ports = [int(p) for p in re.findall(r":(\d+)", world.split("PX4s")[1])]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for port in ports:  # PX4's ground-station link listens on 18570 + instance
            for frame in _param_set("COM_ARM_WO_GPS", 0):
                sock.sendto(frame, ("127.0.0.1", port - OFFBOARD_LOCAL_PORT + GCS_LOCAL_PORT))
    await asyncio.sleep(1.0)


async def test_sitl_runs_two_real_px4s_and_a_qtm_server_until_interrupted(tmp_path: Path) -> None:
    """``uavbar-supervisor sitl`` with real PX4: the QTM server streams the resting bodies,
    each PX4 answers a ground station's heartbeat on the address printed, and Ctrl-C stops
    the world and both firmware processes."""
    require_px4()
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        qtm_port = probe.getsockname()[1]
    arguments = ["sitl", "--set", 'sim.vehicles="px4_sitl"', "--set", f"mocap.port={qtm_port}"]
    arguments += ["--set", f'log.folder="{tmp_path}"']
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "supervisor.cli.main",
        *arguments,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
    )
    assert process.stdout is not None
    output: list[str] = []
    try:
        async with asyncio.timeout(90.0):
            while not output or "running in real time" not in output[-1]:
                line = await process.stdout.readline()
                assert line, "sitl exited:\n" + "\n".join(output)
                output.append(line.decode(errors="replace").rstrip())
        text = "\n".join(output)
        assert f"QTM RT server   tcp 127.0.0.1:{qtm_port}" in text, text
        vehicles = re.findall(r"PX4 vehicle (\d)\s+udp (\S+):(\d+) ->", text)
        assert [v[0] for v in vehicles] == ["1", "2"], text
        async with QtmClient("127.0.0.1", qtm_port) as mocap:
            frame = await mocap.wait_frame()
            assert all(frame.bodies[name].tracked for name in ("bar", "uav1", "uav2"))
        for number, host, port in vehicles:
            assert await heartbeat_answered(host, int(port)) == int(number)
        process.send_signal(signal.SIGINT)
        async with asyncio.timeout(30.0):
            await process.stdout.read()
            assert await process.wait() == 0
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
    assert not px4_processes_under(tmp_path)


async def heartbeat_answered(host: str, port: int) -> int:
    """Send a ground station's heartbeat to a PX4 link; the system id of the PX4 that
    answers with its own heartbeat."""
    codec = MavlinkCodec(255, 190)
    loop = asyncio.get_running_loop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.setblocking(False)
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            codec.messages.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            for frame in codec.outgoing():
                sock.sendto(frame, (host, port))
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(1.0):
                    while True:
                        data = await loop.sock_recv(sock, 2048)
                        for message in codec.messages.parse_buffer(data) or []:
                            if message.get_type() == "HEARTBEAT" and message.type == 2:
                                return int(message.get_srcSystem())
    raise AssertionError(f"no PX4 heartbeat from {host}:{port}")


def px4_processes_under(folder: Path) -> list[int]:
    """PIDs of PX4 processes whose working directory is inside ``folder``."""
    found = []
    for cwd in Path("/proc").glob("[0-9]*/cwd"):
        with contextlib.suppress(OSError):
            if cwd.resolve().is_relative_to(folder.resolve()):
                found.append(int(cwd.parent.name))
    return found
