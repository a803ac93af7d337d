"""``uavbar-supervisor serve`` as a subprocess on free ports, driven over HTTP only
(used by the tick benchmark and the end-to-end tests)."""

from __future__ import annotations

import asyncio
import contextlib
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

START_TIMEOUT_S = 120.0
CHILDREN = ("world", "relay", "flight", "api")  # serve's processes, uavbar-NAME


ENDS = frozenset({"hover", "abort", "px4_landing", "killed", "disarmed"})  # of a take-off


def world_stalls(status: dict[str, Any]) -> int:
    """How many stalls of its own the embedded world has reported (0 without one)."""
    return int(status.get("world", {}).get("stalls", {}).get("count", 0))


def all_connected(status: dict[str, Any]) -> bool:
    """Healthy mocap and both vehicle links with their modes known (a heartbeat heard: arming
    is refused before), as the status shows them, and the system out of the ``px4_landing``
    a flight process starts in until it has heard both vehicles."""
    return (
        bool(status["mocap"]["healthy"])
        and status["mode"] != "px4_landing"
        and all(u["connected"] and u["px4_mode"] != "unknown" for u in status["uavs"])
    )


def ready_to_arm(status: dict[str, Any]) -> bool:
    """Nothing would refuse an arm now (``arm_blocked_by`` null)."""
    return status["arm_blocked_by"] is None


@dataclass
class RunningService:
    """A started ``serve``: its base URL, token, and the process."""

    url: str
    token: str
    process: asyncio.subprocess.Process
    output: list[str]

    def client(self, **options: Any) -> httpx.AsyncClient:
        """An HTTP client with the token set."""
        headers = {"Authorization": f"Bearer {self.token}"}
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
    ) -> dict[str, Any]:
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
            status = await self.wait_for(http, lambda s: s["mode"] in ENDS, 60.0, "hover")
            if status["mode"] == "hover":
                return status
            notices = [n["message"] for n in status["notices"]]
            if not retries_left or world_stalls(status) == stalls_before:
                raise RuntimeError(f"take-off ended in {status['mode']}: {notices[-1:]}")
            retries_left -= 1
            print(f"take-off ended in {status['mode']} while the world stalled: {notices[-1:]}")
            await self.wait_for(http, lambda s: s["armed"] == [False, False], 90.0, "disarmed")
            (await http.post("/api/sim/reset")).raise_for_status()

    async def status(self, http: httpx.AsyncClient) -> dict[str, Any]:
        response = await http.get("/api/status")
        response.raise_for_status()
        result: dict[str, Any] = response.json()
        return result

    async def wait_for(
        self,
        http: httpx.AsyncClient,
        condition: Callable[[dict[str, Any]], bool],
        timeout_s: float,
        what: str,
    ) -> dict[str, Any]:
        """Poll ``/api/status`` until ``condition(status)``; raises ``TimeoutError``."""
        deadline = time.monotonic() + timeout_s
        last: dict[str, Any] = {}
        while time.monotonic() < deadline:
            response = await http.get("/api/status")
            if response.status_code == 200:
                last = response.json()
                if condition(last):
                    return last
            await asyncio.sleep(0.1)
        brief = {k: last.get(k) for k in ("mode", "phase", "bar", "setpoints", "faults", "notices")}
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
) -> AsyncIterator[RunningService]:
    """Start ``serve`` (embedded simulator, API on a free port), stop it with SIGINT.
    ``program`` runs the CLI (an installed ``uavbar-supervisor``, say) in ``cwd``."""
    arguments = [*program[1:], "serve", "--set", "api.port=0"]
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
