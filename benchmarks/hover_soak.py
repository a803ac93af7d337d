"""Hovers on a busy computer: N one-minute hovers on the embedded simulator, one ``serve``
each, while the test suite runs alongside on the same cores — each must complete without
a spurious abort (or any other forced decision). Prints one line per hover (notices, missed
deadlines, the world's own stalls, the world's truth) and the count that passed.

    python -m benchmarks.hover_soak [--hovers 10] [--hover-s 60] [--no-load] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import os
import signal
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from benchmarks.service import in_mode, notices, running_service
from benchmarks.tick import world_truth
from supervisor.flight.modes import Mode
from supervisor.flight.status import Status

TOKEN = "hover-soak-token"
# The quick part of the suite, over and over: what a developer runs beside a flight.
LOAD = [
    sys.executable,
    "-m",
    "pytest",
    "-m",
    "not slow and not px4",
    "-q",
    "-p",
    "no:cacheprovider",
]


@contextlib.asynccontextmanager
async def test_suite_alongside(enabled: bool) -> AsyncIterator[list[int]]:
    """Run the suite in a loop for the duration; yields the list of its exit statuses."""
    runs: list[int] = []
    if not enabled:
        yield runs
        return
    stop = asyncio.Event()

    async def loop() -> None:
        while not stop.is_set():
            process = await asyncio.create_subprocess_exec(
                *LOAD,
                stdout=asyncio.subprocess.DEVNULL,
                stderr=asyncio.subprocess.DEVNULL,
                start_new_session=True,
            )
            waiter = asyncio.create_task(process.wait())
            stopper = asyncio.create_task(stop.wait())
            await asyncio.wait({waiter, stopper}, return_when=asyncio.FIRST_COMPLETED)
            if not waiter.done():
                os.killpg(process.pid, signal.SIGTERM)
                await waiter
            stopper.cancel()
            runs.append(waiter.result())

    task = asyncio.create_task(loop())
    try:
        yield runs
    finally:
        stop.set()
        await task


async def one_hover(hover_s: float) -> dict[str, Any]:
    """Take off, hover ``hover_s`` watching the mode once a second, land; what happened."""
    with tempfile.TemporaryDirectory() as scratch:
        async with running_service(TOKEN, Path(scratch)) as service, service.client() as http:
            started = time.monotonic()
            try:
                await service.take_off(http, again_after_world_stall=False)
            except (RuntimeError, TimeoutError) as error:
                status = await service.status(http)
                return {"ok": False, "failed": f"take-off: {error}", **_brief(status)}
            modes = set()
            end = time.monotonic() + hover_s
            while time.monotonic() < end:
                status = await service.status(http)
                modes.add(status.mode)
                await asyncio.sleep(1.0)
            hovering = modes == {Mode.HOVER}
            if hovering:
                (await http.post("/api/land")).raise_for_status()
            status = await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "on the ground")
            stalls = (await http.get("/api/sim/faults")).json().get("stalls", {})
            result = {
                "ok": hovering and not status.notices,
                "modes": sorted(mode.value for mode in modes),
                "wall_s": round(time.monotonic() - started, 1),
                **_brief(status),
                "world_stalls": stalls.get("count"),
                "worst_world_stall_ms": stalls.get("worst_ms"),
            }
        truth = world_truth(service.output)
    return {**result, **{k: truth.get(k) for k in ("max_uav_tilt_deg", "slack_events")}}


def _brief(status: Status) -> dict[str, Any]:
    return {
        "missed_deadlines": status.tick.missed_deadlines,
        "notices": " | ".join(notices(status)) or "-",
    }


async def run(hovers: int, hover_s: float, load: bool) -> dict[str, Any]:
    results = []
    async with test_suite_alongside(load) as suite_runs:
        for index in range(1, hovers + 1):
            print(f"# hover {index}/{hovers} …", file=sys.stderr, flush=True)
            result = await one_hover(hover_s)
            print("  ".join(f"{k}={v}" for k, v in result.items()), flush=True)
            results.append(result)
    passed = sum(1 for r in results if r["ok"])
    return {
        "hovers": hovers,
        "hover_s": hover_s,
        "test_suite_alongside": load,
        "suite_runs": len(suite_runs),
        "passed": passed,
        "missed_deadlines": sum(r["missed_deadlines"] for r in results),
        "world_stalls": sum(r.get("world_stalls") or 0 for r in results),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hovers", type=int, default=10)
    parser.add_argument("--hover-s", type=float, default=60.0)
    parser.add_argument("--no-load", action="store_true", help="without the suite alongside")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    summary = asyncio.run(run(args.hovers, args.hover_s, not args.no_load))
    if args.json:
        print(json.dumps(summary))
    else:
        print(
            f"{summary['passed']}/{summary['hovers']} hovers of {args.hover_s:g} s without a "
            f"forced decision (test suite alongside: {summary['test_suite_alongside']}, "
            f"{summary['suite_runs']} runs); missed deadlines {summary['missed_deadlines']}, "
            f"world stalls {summary['world_stalls']}"
        )
    return 0 if summary["passed"] == summary["hovers"] else 1


if __name__ == "__main__":
    sys.exit(main())
