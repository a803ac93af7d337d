"""End to end: faults injected into ``serve``'s embedded world over HTTP (and the CLI as a
subprocess), seen by an independent QTM client (the official qtm-rt SDK) and by the
supervisor's own status; the world reset after a flight. What the supervisor *does* about
a fault is not tested here (docs/safety.md): only that each fault is there, and ends."""

from __future__ import annotations

import asyncio
import contextlib
import os
import re
import sys
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import httpx
import pytest
import qtm_rt

from benchmarks.service import RunningService, all_disarmed, position_m, running_service
from supervisor.flight.status import Status
from tests.test_service import TOKEN, ready

pytestmark = pytest.mark.slow


def qtm_address(service: RunningService) -> tuple[str, int]:
    """The world's QTM server, as serve logged it."""
    for line in service.output:
        match = re.search(r"simulated world: QTM (\S+):(\d+),", line)
        if match:
            return match.group(1), int(match.group(2))
    raise AssertionError("serve did not log the world's QTM address")


@contextlib.asynccontextmanager
async def qtm_stream(service: RunningService) -> AsyncIterator[list[Any]]:
    """The packets the official SDK receives (it streams over its TCP connection)."""
    host, port = qtm_address(service)
    connection = await qtm_rt.connect(host, port=port, version="1.25")
    assert connection is not None
    packets: list[Any] = []
    try:
        await connection.stream_frames(components=["6d"], on_packet=packets.append)
        yield packets
        await connection.stream_frames_stop()
    finally:
        connection.disconnect()


async def eventually(condition: Any, timeout_s: float, what: str) -> None:
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110 - the SDK only offers a callback
            await asyncio.sleep(0.05)


async def fault(http: httpx.AsyncClient, **body: Any) -> dict[str, Any]:
    response = await http.post("/api/sim/faults", json=body)
    assert response.status_code == 200, response.text
    answer: dict[str, Any] = response.json()
    return answer


def logged(service: RunningService, text: str) -> bool:
    return any(text in line for line in service.output)


async def test_mocap_faults_seen_by_the_sdk_and_the_supervisor(tmp_path: Path) -> None:
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        async with qtm_stream(service) as packets:
            await eventually(lambda: len(packets) > 10, 20.0, "frames before the fault")
            answer = await fault(http, kind="mocap_silent", duration_s=1.0)
            assert [f["kind"] for f in answer["faults"]] == ["mocap_silent"]
            await asyncio.sleep(0.2)  # what was on its way has arrived
            silent_from = len(packets)
            await asyncio.sleep(0.5)
            assert len(packets) == silent_from  # not one frame
            status = await service.status(http)
            assert not status.mocap.healthy
            await eventually(lambda: len(packets) > silent_from + 10, 20.0, "frames again")
            numbers = [p.framenumber for p in packets[silent_from - 1 : silent_from + 1]]
            assert numbers[1] - numbers[0] > 50  # QTM counted on through the silence
        await service.wait_for(http, lambda s: s.mocap.healthy, 20.0, "healthy again")
        assert logged(service, "fault started at") and logged(service, "mocap_silent for 1 s")
        assert logged(service, "(expired): mocap_silent")

        await fault(http, kind="mocap_body_lost", body="bar", duration_s=3.0)
        status = await service.wait_for(
            http, lambda s: "bar" in s.mocap.unhealthy, 20.0, "the bar untracked"
        )
        assert "uav1" not in status.mocap.unhealthy
        assert status.bar.position == [None, None, None] or not status.mocap.healthy
        await service.wait_for(http, lambda s: s.mocap.healthy, 30.0, "the bar back")
        assert (await http.get("/api/sim/faults")).json()["faults"] == []


async def test_link_lost_and_px4_reboot_seen_by_the_supervisor(tmp_path: Path) -> None:
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        await fault(http, kind="link_lost", vehicle=1, duration_s=5.0)
        # Within the link timeout (vehicles.link_loss_s, 1.5 s) and a busy machine's slack.
        status = await service.wait_for(
            http, lambda s: not s.uavs[0].connected, 10.0, "vehicle 1 disconnected"
        )
        assert status.uavs[1].connected
        await service.wait_for(http, lambda s: s.uavs[0].connected, 30.0, "vehicle 1 reconnected")

        await fault(http, kind="px4_reboot", vehicle=2, duration_s=3.0)
        await service.wait_for(http, lambda s: not s.uavs[1].connected, 10.0, "vehicle 2 rebooting")
        status = await service.wait_for(
            http,
            lambda s: s.uavs[1].connected and s.uavs[1].px4_mode != "unknown",
            30.0,
            "vehicle 2 booted",
        )
        assert all_disarmed(status)
        assert logged(service, "PX4 2: power off (rebooting)") and logged(service, "PX4 2: booted")


async def test_reset_refused_while_armed_then_the_resting_pose_is_back(tmp_path: Path) -> None:
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        resting = position_m((await service.status(http)).bar.position)
        await service.take_off(http)
        response = await http.post("/api/setpoints", json={"bar_position": [0.6, 0.3, 1.0]})
        assert response.status_code == 200
        await service.wait_for(
            http, lambda s: abs(position_m(s.bar.position)[0] - 0.6) < 0.1, 40.0, "the bar moved"
        )
        refused = await http.post("/api/sim/reset")
        assert refused.status_code == 409 and "armed" in refused.json()["detail"]
        assert (await http.post("/api/abort")).status_code == 200
        await service.wait_for(http, all_disarmed, 90.0, "landed and disarmed")
        landed = position_m((await service.status(http)).bar.position)
        assert abs(landed[0] - resting[0]) > 0.3  # somewhere else than it started
        response = await http.post("/api/sim/reset")
        assert response.status_code == 200, response.text
        assert response.json()["reset"] and response.json()["faults"] == []

        def back(status: Status) -> bool:
            position = position_m(status.bar.position)
            return all(abs(a - b) < 0.05 for a, b in zip(position, resting, strict=True))

        await service.wait_for(http, back, 20.0, "the bar back in its resting pose")
        assert logged(service, "world reset at")


async def cli(service: RunningService, *args: str) -> tuple[int, str, str]:
    """``uavbar-supervisor ARGS`` as its own process against the service."""
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "supervisor.cli.main",
        *args,
        "--url",
        service.url,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env={**os.environ, "UAVBAR_TOKEN": service.token},
    )
    async with asyncio.timeout(60.0):
        out, err = await process.communicate()
    assert process.returncode is not None
    return process.returncode, out.decode(), err.decode()


async def test_the_fault_and_reset_commands_and_the_token(tmp_path: Path) -> None:
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        async with httpx.AsyncClient(base_url=service.url, timeout=10.0) as anonymous:
            for method, path in (("POST", "/api/sim/faults"), ("DELETE", "/api/sim/faults")):
                body = {"kind": "mocap_silent"} if method == "POST" else None
                assert (await anonymous.request(method, path, json=body)).status_code == 401
            assert (await anonymous.post("/api/sim/reset")).status_code == 401
            listed = (await anonymous.get("/api/sim/faults")).json()  # reading is open
            assert listed["embedded"] is True and listed["faults"] == []
        status, out, _ = await cli(service, "fault", "udp_loss", "--fraction", "0.2")
        assert status == 0 and "in effect: udp_loss fraction 0.2 (until cleared)" in out
        status, _, err = await cli(service, "fault", "link_lost", "--vehicle", "5")
        assert status == 1 and "(409): vehicle: 5 is not a vehicle of this world" in err
        status, out, _ = await cli(service, "fault", "--clear")
        assert status == 0 and "ended: udp_loss" in out
        status, out, _ = await cli(service, "reset")
        assert status == 0 and "world reset" in out
        assert (await http.get("/api/sim/faults")).json()["faults"] == []
