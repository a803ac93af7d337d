"""``uavbar-supervisor serve`` as a subprocess on free ports, driven over HTTP only
(used by the tick benchmark and the end-to-end tests)."""

from __future__ import annotations

import asyncio
import contextlib
import math
import os
import re
import signal
import sys
import time
from collections.abc import AsyncIterator, Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from supervisor.flight.modes import Mode
from supervisor.flight.status import Status

START_TIMEOUT_S = 120.0
CLIENT_KEEPALIVE_S = 2.0
BRIEF = {"mode", "phase", "bar", "setpoints", "faults", "notices"}  # of a status, timed out
CHILDREN = ("world", "relay", "flight", "api")  # serve's processes, uavbar-NAME


ENDS = frozenset({Mode.HOVER, Mode.ABORT, Mode.PX4_LANDING, Mode.KILLED, Mode.DISARMED})


def world_stalls(status: Status) -> int:
    """How many stalls of its own the embedded world has reported (0 without one)."""
    stalls = status.world.stalls
    return stalls.count if stalls is not None else 0


def all_connected(status: Status) -> bool:
    """Healthy mocap and every vehicle link with its mode known (a heartbeat heard: arming
    is refused before), as the status shows them, and the system out of the ``px4_landing``
    a flight process starts in until it has heard every vehicle."""
    return (
        status.mocap.healthy
        and status.mode is not Mode.PX4_LANDING
        and all(u.connected and u.px4_mode != "unknown" for u in status.uavs)
    )


def ready_to_arm(status: Status) -> bool:
    """Nothing would refuse an arm now (``arm_blocked_by`` null)."""
    return status.arm_blocked_by is None


def in_mode(*modes: Mode) -> Callable[[Status], bool]:
    """Whether the status's mode is one of ``modes``."""
    return lambda status: status.mode in modes


def all_disarmed(status: Status) -> bool:
    """Every vehicle says it is disarmed."""
    return not any(status.armed)


def position_m(position: Sequence[float | None]) -> list[float]:
    """An estimated position (x, y, z) [m] as numbers: NaN where it is not known."""
    return [math.nan if v is None else v for v in position]


def notices(status: Status) -> list[str]:
    """The status's notices, oldest first."""
    return [notice.message for notice in status.notices]


@dataclass
class RunningService:
    """A started ``serve``: its base URL, token, and the process."""

    url: str
    token: str
    process: asyncio.subprocess.Process
    output: list[str]

    def client(self, **options: Any) -> httpx.AsyncClient:
        """An HTTP client with the token set. It lets go of a connection idle for
        ``CLIENT_KEEPALIVE_S``, well before the server's keep-alive timeout (uvicorn's 5 s,
        httpx's own default too): reused just as the server closed it, a request was
        answered "Server disconnected without sending a response"."""
        headers = {"Authorization": f"Bearer {self.token}"}
        options.setdefault("limits", httpx.Limits(keepalive_expiry=CLIENT_KEEPALIVE_S))
        return httpx.AsyncClient(base_url=self.url, headers=headers, timeout=10.0, **options)

    def child_pid(self, name: str) -> int:
        """The child of ``serve`` that named itself ``name`` (``uavbar-flight``, ...:
        ``supervisor.runtime.cpu.name_process``)."""
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
                comm = (stat.parent / "comm").read_text().strip()
            except OSError:
                continue
            if parent == self.process.pid and comm == name:
                return int(stat.parent.name)
        raise LookupError(f"serve has no child process named {name}")

    async def take_off(
        self, http: httpx.AsyncClient, *, again_after_world_stall: bool = True
    ) -> Status:
        """Wait for healthy mocap and both links, arm, take off; the status once hovering.

        A take-off that ends otherwise while the simulated world reported stalls of its own
        (this computer took the CPU from it: its mocap paused, which the supervisor rightly
        answers as a mocap gap) is flown once more from the resting pose, unless
        ``again_after_world_stall`` is off (benchmarks that count such failures); any other
        failure, or a second one, is raised with the supervisor's notice."""
        retries_left = 1 if again_after_world_stall else 0
        while True:
            await self.wait_for(http, ready_to_arm, 60.0, "nothing to block an arm")
            stalls_before = world_stalls(await self.status(http))
            for step in ("arm", "takeoff"):
                response = await http.post(f"/api/{step}")
                if response.status_code != 200:
                    raise RuntimeError(f"{step} refused: {response.text}")
            status = await self.wait_for(http, in_mode(*ENDS), 60.0, "hover")
            if status.mode is Mode.HOVER:
                return status
            said, mode = notices(status)[-1:], status.mode.value
            if not retries_left or world_stalls(status) == stalls_before:
                raise RuntimeError(f"take-off ended in {mode}: {said}")
            retries_left -= 1
            print(f"take-off ended in {mode} while the world stalled: {said}")
            await self.wait_for(http, all_disarmed, 90.0, "disarmed")
            (await http.post("/api/sim/reset")).raise_for_status()

    async def status(self, http: httpx.AsyncClient) -> Status:
        response = await http.get("/api/status")
        response.raise_for_status()
        return Status.model_validate_json(response.content)

    async def wait_for(
        self,
        http: httpx.AsyncClient,
        condition: Callable[[Status], bool],
        timeout_s: float,
        what: str,
    ) -> Status:
        """Poll ``/api/status`` until ``condition(status)``; raises ``TimeoutError``."""
        deadline = time.monotonic() + timeout_s
        last: Status | None = None
        while time.monotonic() < deadline:
            response = await http.get("/api/status")
            if response.status_code == 200:
                last = Status.model_validate_json(response.content)
                if condition(last):
                    return last
            await asyncio.sleep(0.1)
        brief = last.model_dump_json(include=BRIEF) if last is not None else "no status"
        raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}; last: {brief}")


async def _read_output(stream: asyncio.StreamReader, lines: list[str]) -> None:
    while line := await stream.readline():
        lines.append(line.decode(errors="replace").rstrip())


@contextlib.asynccontextmanager
async def running_service(
    token: str,
    log_folder: Path,
    overrides: Sequence[str] = (),
    *,
    program: Sequence[str] = (sys.executable, "-m", "supervisor.cli.main"),
    cwd: Path | None = None,
    setup: str | None = None,
) -> AsyncIterator[RunningService]:
    """Start ``serve`` (embedded simulator, API on a free port), stop it with SIGINT.
    ``program`` runs the CLI (an installed ``uavbar-supervisor``, say) in ``cwd``;
    ``setup`` names the setup (``--config``; serve's default without)."""
    arguments = [*program[1:], "serve", "--set", "api.port=0"]
    if setup is not None:
        arguments += ["--config", setup]
    arguments += ["--set", f'log.folder="{log_folder}"']
    for override in overrides:
        arguments += ["--set", override]
    env = {**os.environ, "UAVBAR_TOKEN": token, "PYTHONUNBUFFERED": "1"}
    process = await asyncio.create_subprocess_exec(
        program[0],
        *arguments,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
        env=env,
        cwd=cwd,
    )
    assert process.stdout is not None
    output: list[str] = []
    url = None
    try:
        async with asyncio.timeout(START_TIMEOUT_S):
            while url is None:
                line = await process.stdout.readline()
                if not line:
                    raise RuntimeError("serve exited:\n" + "\n".join(output))
                output.append(line.decode(errors="replace").rstrip())
                match = re.search(r"serving (http://\S+?)/? ", output[-1])
                url = match.group(1).rstrip("/") if match else None
        reader = asyncio.create_task(_read_output(process.stdout, output))
        try:
            yield RunningService(url, token, process, output)
        except BaseException:
            # What serve said, for whoever reads the failure (pytest shows captured output).
            print("\n".join(["--- serve's output ---", *output[-200:]]))
            raise
        finally:
            if process.returncode is None:
                process.send_signal(signal.SIGINT)
            try:
                async with asyncio.timeout(150.0):
                    await process.wait()
            except TimeoutError:
                process.kill()
                await process.wait()
            await reader
    finally:
        if process.returncode is None:
            process.kill()
            await process.wait()
