"""End to end: the terminal client, each command its own process, against ``serve`` on the
embedded simulator, found through ``serve``'s discovery file; awaited commands exit 0 only
once the system is there, and with the reason when it cannot get there; Ctrl-C with a
dashboard's WebSocket open lands, says so and stops without a traceback."""

from __future__ import annotations

import asyncio
import math
import os
import signal
import sys
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import httpx
import pytest
import websockets

from benchmarks.service import (
    CHILDREN,
    RunningService,
    all_connected,
    all_disarmed,
    notices,
    position_m,
    running_service,
)
from supervisor.flight.modes import Mode
from supervisor.flight.phases import Phase
from supervisor.flight.status import Status

TOKEN = "cli-e2e-token-0123456789"
ROOT = Path(__file__).resolve().parent.parent

PREFLIGHT_DISARM = "disarmed by itself before take-off"  # the notice of the auto-disarm


async def cli(*args: str) -> tuple[int, str, str]:
    """``uavbar-supervisor ARGS`` in a process of its own: exit status, stdout, stderr."""
    env = {**os.environ, "UAVBAR_TOKEN": TOKEN, "PYTHONPATH": str(ROOT)}
    env.pop("UAVBAR_URL", None)
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "supervisor.cli.main",
        *args,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
        env=env,
    )
    out, err = await process.communicate()
    assert process.returncode is not None
    return process.returncode, out.decode(), err.decode()


async def telemetry_messages(service: RunningService, opened: asyncio.Event) -> int:
    """A dashboard's WebSocket: the messages it got until the service closed it."""
    count = 0
    async with websockets.connect(service.url.replace("http", "ws") + "/api/telemetry") as ws:
        opened.set()
        async for _ in ws:
            count += 1
    return count


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


async def wait_for_line(service: RunningService, text: str, timeout_s: float = 30.0) -> None:
    for _ in range(int(timeout_s / 0.05)):
        if any(text in line for line in service.output):
            return
        await asyncio.sleep(0.05)
    raise TimeoutError(f"serve did not say {text!r} within {timeout_s} s")


async def arm_and_take_off(
    service: RunningService,
    http: httpx.AsyncClient,
    arm: Callable[[], Awaitable[tuple[int, str, str]]],
) -> asyncio.Task[tuple[int, str, str]]:
    """``arm()``, then ``takeoff --wait`` in a process of its own, returned once the take-off
    has begun. The simulated PX4 disarms itself 10 s after an arm that no take-off follows
    (COM_DISARM_PRFLT, as PX4 does): a take-off that a starved machine started later than
    that (19 s once, beside the other lane's browser) is tried once more, from a new arm."""
    takeoff, begun = await _arm_then_take_off(service, http, arm)
    if begun.mode is Mode.DISARMED:
        await takeoff  # refused: disarmed
        assert PREFLIGHT_DISARM in " ".join(notices(begun)), notices(begun)
        takeoff, _ = await _arm_then_take_off(service, http, arm)
    return takeoff


async def _arm_then_take_off(
    service: RunningService,
    http: httpx.AsyncClient,
    arm: Callable[[], Awaitable[tuple[int, str, str]]],
) -> tuple[asyncio.Task[tuple[int, str, str]], Status]:
    status, _, err = await arm()
    assert status == 0, err
    takeoff = asyncio.create_task(cli("takeoff", "--wait"))
    begun = await service.wait_for(
        http, lambda s: s.mode is not Mode.ARMED, 60.0, "the take-off or a disarm"
    )
    return takeoff, begun


def arm_with_the_cli() -> Awaitable[tuple[int, str, str]]:
    return cli("arm", "--wait")


async def reset_and_arm(service: RunningService, http: httpx.AsyncClient) -> tuple[int, str, str]:
    """``reset``, then ``arm --wait`` at once: the reset answers once the motion capture
    tracks the bodies at their resting pose, so nothing needs waiting for in between."""
    status, out, err = await cli("reset")
    assert status == 0, err
    assert "not ready to arm" not in out and "does not track" not in out, out
    await service.wait_for(http, all_connected, 60.0, "both links")
    return await cli("arm", "--wait")


@pytest.mark.slow
async def test_awaited_commands_and_a_quiet_ctrl_c(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # only this serve is found
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        opened = asyncio.Event()
        dashboard = asyncio.create_task(telemetry_messages(service, opened))
        await opened.wait()
        await service.wait_for(http, all_connected, 60.0, "healthy mocap and both links")
        assert f"#token={TOKEN}" in "\n".join(service.output)  # the address to open

        status, out, err = await cli("setpoint", "0.3", "0", "1.1")
        assert status == 1 and "not allowed in mode 'disarmed'" in err and "arm first" in err
        status, out, err = await (await arm_and_take_off(service, http, arm_with_the_cli))
        assert status == 0 and "airborne, hover" in out, err
        assert (await service.status(http)).mode is Mode.HOVER
        status, out, err = await cli(
            "setpoint", "0.3", "0", "1.1", "--yaw-deg", "10", "--hold-s", "1", "--wait"
        )
        assert status == 0 and "reached and held" in out, err
        bar = (await service.status(http)).bar
        assert abs(position_m(bar.position)[0] - 0.3) < 0.1
        assert bar.yaw is not None and abs(bar.yaw - 0.1745) < 0.1
        status, out, err = await cli("land", "--wait")
        assert status == 0 and "landed and disarmed" in out, err
        assert all_disarmed(await service.status(http))

        # A take-off that an abort ends: exit 1 with the abort's reason. (The landing put
        # the UAVs down 0.3 m from the bar's ends: the world's reset puts them back.)
        takeoff = await arm_and_take_off(service, http, lambda: reset_and_arm(service, http))
        await service.wait_for(http, lambda s: s.phase is Phase.LIFT, 30.0, "lifting the bar")
        fault = {"kind": "link_lost", "vehicle": 1, "duration_s": 3.0}
        assert (await http.post("/api/sim/faults", json=fault)).status_code == 200
        status, out, err = await takeoff
        assert status == 1 and "take-off failed: land_other: vehicle 1 link lost" in err, (
            out,
            err,
        )
        await service.wait_for(http, all_disarmed, 90.0, "landed")

        status, out, err = await cli("takeoff", "--wait", "--timeout", "1")
        assert status == 1 and "refused (409)" in err  # disarmed: refused at once

        # Ctrl-C (to serve; its children leave SIGINT to it) with the dashboard connected.
        reset = await arm_and_take_off(service, http, lambda: reset_and_arm(service, http))
        assert (await reset)[0] == 0
        children = [service.child_pid(f"uavbar-{name}") for name in CHILDREN]
        service.process.send_signal(signal.SIGINT)
        # An impatient second Ctrl-C during the landing: said, and the landing goes on.
        await wait_for_line(service, "stopping: landing whatever is airborne")
        service.process.send_signal(signal.SIGINT)
        async with asyncio.timeout(120.0):
            assert await service.process.wait() == 0
        for _ in range(50):  # init reaps what serve stopped
            if not (left := [pid for pid in children if alive(pid)]):
                break
            await asyncio.sleep(0.1)
        assert not left, f"serve left {left} running"
        assert await dashboard > 0  # it ended when serve closed it
    said = "\n".join(service.output)
    assert "stopping: landing first (the system is in hover)" in said
    assert "landed: stopping" in said and said.rstrip().endswith("stopped")
    assert "already stopping: landing first" in said and "interrupted" not in said
    assert "Traceback" not in said and "ERROR" not in said, said[-3000:]


PATH: dict[str, Any] = {
    "waypoints": [
        {"bar_position": [0.6, 0.0, 1.1]},
        {"bar_position": [0.6, 0.6, 1.3], "bar_yaw": 0.4},
        {"bar_position": [0.0, 0.6, 1.1]},
    ],
    "speed_mps": 0.4,
    "accel_mps2": 0.5,
    "hold_s": 1.0,
}
BACK = """
speed_mps = 0.5
accel_mps2 = 0.5

[[waypoints]]
bar_position = [0.0, 0.0, 1.0]
bar_yaw = 0.0
"""


def path_begun_for(seconds: float) -> Callable[[Status], bool]:
    """The status shows a path begun at least ``seconds`` ago."""
    return lambda s: s.path is not None and (s.path.elapsed_s or 0.0) > seconds


@pytest.mark.slow
async def test_a_path_over_rest_and_from_the_terminal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """In a hover, ``POST /api/path``: without the token 401, through a waypoint outside the
    arena 409 with the reason, nothing queued; one that can be flown is taken, shown in the
    status (its waypoints and timing, its points from the hover to its end, the time since
    it began growing) and flown to its end. Then ``path FILE --wait`` flies the bar back
    and exits 0 once its end has been reached and held."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # only this serve is found
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        hover = position_m((await service.take_off(http)).bar.position)
        async with httpx.AsyncClient(base_url=service.url, timeout=10.0) as anonymous:
            assert (await anonymous.post("/api/path", json=PATH)).status_code == 401
        outside = {**PATH, "waypoints": [*PATH["waypoints"], {"bar_position": [0.0, 0.0, 3.5]}]}
        refused = await http.post("/api/path", json=outside)
        assert refused.status_code == 409, refused.text
        assert refused.json()["detail"].startswith(
            "waypoint 3: bar centre would be at (0.00, 0.00, 3.50) m, outside the arena"
        )
        before = await service.status(http)
        assert before.path is None and before.setpoints.active is None

        response = await http.post("/api/path", json=PATH)
        assert response.status_code == 200, response.text
        duration_s = response.json()["duration_s"]
        shown = (await service.wait_for(http, path_begun_for(1.0), 20.0, "the path")).path
        assert shown is not None and shown.duration_s == duration_s
        assert shown.waypoints == [point["bar_position"] for point in PATH["waypoints"]]
        assert len(shown.points) >= duration_s / 0.25
        assert math.dist(shown.points[0], hover) < 0.05 and shown.points[-1] == [0.0, 0.6, 1.1]
        later = (await service.wait_for(http, path_begun_for(2.0), 20.0, "a second more")).path
        assert later is not None and later.elapsed_s is not None
        assert shown.elapsed_s is not None and later.elapsed_s > shown.elapsed_s
        flown = await service.wait_for(http, lambda s: s.path is None, duration_s + 20, "its end")
        assert math.dist(position_m(flown.bar.position), [0.0, 0.6, 1.1]) < 0.1

        back = tmp_path / "back.toml"
        back.write_text(BACK)
        code, out, err = await cli("path", str(back), "--wait")
        assert code == 0 and "path flown, its end reached and held" in out, (out, err)
        bar = (await service.status(http)).bar
        assert math.dist(position_m(bar.position), [0.0, 0.0, 1.0]) < 0.1
        assert bar.yaw is not None and abs(bar.yaw) < 0.1
        landed = await http.post("/api/land?wait_s=90", timeout=100.0)
        assert landed.status_code == 200, landed.text
