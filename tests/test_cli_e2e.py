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


# A path from the hover back to the start, flown with ``path FILE --wait``.
BACK = """
speed_mps = 1.0
accel_mps2 = 1.0

[[waypoints]]
bar_position = [0.0, 0.0, 1.0]
bar_yaw = 0.0
"""


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
        back = tmp_path / "back.toml"
        back.write_text(BACK)
        status, out, err = await cli("path", str(back), "--wait")
        assert status == 0 and "path flown, its end reached and held" in out, (out, err)
        bar = (await service.status(http)).bar
        assert math.dist(position_m(bar.position), [0.0, 0.0, 1.0]) < 0.1
        assert bar.yaw is not None and abs(bar.yaw) < 0.1
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
