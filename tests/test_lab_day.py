"""A lab's day on one ``serve`` of the embedded simulator, over HTTP: flights in a row with
nothing moved between them, an arm the moment nothing blocks it, and a log disk that fills
up in flight."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import subprocess
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from benchmarks.service import (
    CHILDREN,
    RunningService,
    in_mode,
    notices,
    position_m,
    running_service,
)
from supervisor.flight.modes import Mode
from supervisor.flight.status import Status
from supervisor.logs.flight_log import read_flight_log
from tests.test_service import hovers_within_5_cm

TOKEN = "lab-day-token-0123456789"
NEXT_ARM_WITHIN_S = 20.0
DISARMED_WITHIN_S = 90.0


async def arm_the_moment_nothing_blocks_it(http: httpx.AsyncClient) -> dict[str, Any]:
    """Poll the status fast and arm at the first answer whose ``arm_blocked_by`` is null:
    that arm must be taken."""
    deadline = time.monotonic() + NEXT_ARM_WITHIN_S
    status: dict[str, Any] = {}
    while time.monotonic() < deadline:
        response = await http.get("/api/status")  # 503 until the flight process speaks
        status = response.json() if response.status_code == 200 else {}
        if status and status["arm_blocked_by"] is None:
            armed = await http.post("/api/arm")
            assert armed.status_code == 200, (armed.text, status["mode"], status["uavs"])
            assert armed.json()["mode"] == "armed"
            return status
        await asyncio.sleep(0.02)
    raise AssertionError(f"arm still blocked after {NEXT_ARM_WITHIN_S} s: {status}")


async def take_off_at_once(http: httpx.AsyncClient) -> None:
    """Take-off sent right after the arm's answer, waiting for the hover: the status the
    wait reads is the one the arm left."""
    response = await http.post("/api/takeoff?wait_s=40", timeout=50.0)
    assert response.status_code == 200, response.text
    assert response.json()["outcome"]["reached"]


async def disarmed(service: RunningService, http: httpx.AsyncClient) -> Status:
    """Wait until landed and disarmed; no status on the way says disarmed while a vehicle
    says it is armed (landed, it says ``disarming`` until every vehicle is heard disarmed)."""

    def down(status: Status) -> bool:
        if status.mode is Mode.DISARMED:
            assert not any(status.armed), status.armed
        return status.mode is Mode.DISARMED

    return await service.wait_for(http, down, DISARMED_WITHIN_S, "landed and disarmed")


@pytest.mark.slow
async def test_land_abort_land_in_a_row_with_nothing_moved(tmp_path: Path) -> None:
    """From serve's start: arm the moment nothing blocks it, take off at once; land, then
    the same with an abort from tracking, then again a landing. No reset, nothing moved.
    The simulated PX4s arm only on fresh external vision (so the mocap is forwarded), and
    in the first hover the bar keeps within 5 cm for 5 s (the rates command mode). Then
    every process of serve is sent SIGTERM at once (systemd's stop): a quiet exit 0."""
    overrides = ["sim.px4_require_vision=true"]
    async with running_service(TOKEN, tmp_path, overrides) as service, service.client() as http:
        for flight, ending in enumerate(("land", "abort", "land")):
            ready = await arm_the_moment_nothing_blocks_it(http)
            assert ready["mode"] == "disarmed"
            await take_off_at_once(http)
            status = await service.status(http)
            assert status.mode is Mode.HOVER, notices(status)[-1:]
            if flight == 0:
                await hovers_within_5_cm(service, http)
            if ending == "abort":
                away = {"bar_position": [1.0, 0.0, 1.2], "hold_s": 5.0}
                assert (await http.post("/api/setpoints", json=away)).status_code == 200
                await service.wait_for(http, in_mode(Mode.TRACKING), 10.0, "tracking")
            answer = await http.post(f"/api/{ending}")
            assert answer.status_code == 200 and answer.json()["mode"] in ("landing", "abort")
            status = await disarmed(service, http)
            assert position_m(status.bar.position)[2] < 0.05
            assert all(position_m(uav.position)[2] < 0.15 for uav in status.uavs)
            assert status.setpoints.active is None and not status.setpoints.queued
        await stop_as_systemd_does(service)
    said = "\n".join(service.output)
    assert said.rstrip().endswith("stopped")
    assert "Traceback" not in said and "ERROR" not in said, said[-3000:]
    flown = flights_flown(tmp_path)
    assert [("abort" in modes, "landing" in modes) for modes in flown] == [
        (False, True),
        (True, False),
        (False, True),
    ], flown


async def stop_as_systemd_does(service: RunningService) -> None:
    """SIGTERM to serve and to every child at once; serve must exit 0."""
    children = [service.child_pid(f"uavbar-{name}") for name in CHILDREN]
    service.process.send_signal(signal.SIGTERM)
    for pid in children:
        # A process already gone (serve stopping its children first) has stopped as asked.
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    async with asyncio.timeout(60.0):
        assert await service.process.wait() == 0


def flights_flown(folder: Path) -> list[set[str]]:
    """The modes of each flight log in ``folder``, oldest first."""
    return [set(read_flight_log(path).modes) for path in sorted(folder.glob("flight-*.mcap"))]


@pytest.fixture
def tiny_log_disk(tmp_path: Path) -> Iterator[Path]:
    """A 1 MiB tmpfs, nearly full (what is left fills within seconds of flight)."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root (CI runs as root)")
    folder = tmp_path / f"tiny-{uuid.uuid4().hex[:8]}"
    folder.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=1M", "tmpfs", str(folder)],
        capture_output=True,
        text=True,
        check=False,
    )
    if mounted.returncode != 0:
        pytest.skip(f"this machine refuses a tmpfs mount: {mounted.stderr.strip()}")
    try:
        free_bytes = os.statvfs(folder).f_bavail * os.statvfs(folder).f_frsize
        (folder / "filler").write_bytes(b"\0" * (free_bytes - 160_000))
        yield folder
    finally:
        subprocess.run(["umount", "-l", str(folder)], check=False)


@pytest.mark.slow
async def test_a_log_disk_that_fills_in_flight_stops_the_log_not_the_flight(
    tiny_log_disk: Path,
) -> None:
    overrides = ["log.min_free_mb=0.1"]
    async with (
        running_service(TOKEN, tiny_log_disk, overrides) as service,
        service.client() as http,
    ):
        await service.take_off(http)
        pids = {name: p.pid for name, p in (await service.status(http)).processes.items()}
        status = await service.wait_for(
            http, lambda s: s.log_stopped is not None, 60.0, "the log to stop"
        )
        assert str(status.log_stopped).startswith("log disk full"), status.log_stopped
        assert status.log is None
        assert any(said.startswith("log: log disk full") for said in notices(status))
        await asyncio.sleep(3.0)  # the hover goes on without its log
        status = await service.status(http)
        assert status.mode is Mode.HOVER and status.mocap.healthy, notices(status)
        after = {name: p.pid for name, p in status.processes.items()}
        assert after == pids  # no process died or restarted
        landed = await http.post("/api/land?wait_s=90", timeout=100.0)
        assert landed.status_code == 200, landed.text
        blocked = await service.wait_for(
            http, lambda s: "MB free" in (s.arm_blocked_by or ""), 10.0, "arming blocked"
        )
        assert "MB free (at least 0.1 MB" in str(blocked.arm_blocked_by)
        refused = await http.post("/api/arm")
        assert refused.status_code == 409 and "MB free" in refused.text
    said = "\n".join(service.output)
    assert "Traceback" not in said, said[-3000:]
