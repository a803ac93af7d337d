"""Arm the moment nothing blocks it: N starts of ``serve`` on the embedded simulator, each
polled until ``arm_blocked_by`` turns null and armed at once (then take-off with
``?wait_s`` right after the arm's answer, land and stop). Every arm must be taken and
every take-off reach hover. Prints one line per start and the figures: refusals, the time
from start to the first null ``arm_blocked_by`` (median, worst).

    python -m benchmarks.arm_at_start [--starts 20] [--no-flight] [--json]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import statistics
import tempfile
import time
from pathlib import Path
from typing import Any

import httpx

from benchmarks.service import running_service
from supervisor.flight.status import Status

TOKEN = "arm-at-start-token"
POLL_S = 0.02
READY_WITHIN_S = 60.0


async def first_null_blocker(http: httpx.AsyncClient) -> tuple[Status, list[str]]:
    """Poll the status until ``arm_blocked_by`` is null; that status and every distinct
    blocker seen on the way (oldest first)."""
    seen: list[str] = []
    deadline = time.monotonic() + READY_WITHIN_S
    while time.monotonic() < deadline:
        response = await http.get("/api/status")
        if response.status_code == 200:
            status = Status.model_validate_json(response.content)
            blocker = status.arm_blocked_by
            if blocker is None:
                return status, seen
            if not seen or seen[-1] != blocker:
                seen.append(blocker)
        await asyncio.sleep(POLL_S)
    raise TimeoutError(f"arm still blocked after {READY_WITHIN_S} s: {seen[-1:]}")


async def one_start(index: int, fly: bool) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as scratch:
        started = time.monotonic()
        async with running_service(TOKEN, Path(scratch)) as service, service.client() as http:
            status, blockers = await first_null_blocker(http)
            ready_s = time.monotonic() - started
            armed = await http.post("/api/arm")
            result: dict[str, Any] = {
                "start": index,
                "ready_s": ready_s,
                "mode_when_ready": status.mode.value,
                "arm": armed.status_code,
                "arm_refusal": None if armed.status_code == 200 else armed.text,
                "blockers_seen": len(blockers),
            }
            if fly and armed.status_code == 200:
                takeoff = await http.post("/api/takeoff?wait_s=40", timeout=50.0)
                result["takeoff"] = takeoff.status_code
                landed = await http.post("/api/land?wait_s=90", timeout=100.0)
                result["land"] = landed.status_code
            elif armed.status_code == 200:
                await http.post("/api/disarm")
    return result


async def run(starts: int, fly: bool, as_json: bool) -> int:
    results = []
    for index in range(1, starts + 1):
        result = await one_start(index, fly)
        results.append(result)
        if not as_json:
            print(
                f"start {index:2d}: arm {result['arm']} {result['ready_s']:.1f} s after start "
                f"(mode {result['mode_when_ready']}, {result['blockers_seen']} blockers on the "
                f"way)"
                + (f", takeoff {result['takeoff']}, land {result['land']}" if fly else "")
                + (f" REFUSED: {result['arm_refusal']}" if result["arm_refusal"] else "")
            )
    ready = [r["ready_s"] for r in results]
    refused = sum(r["arm"] != 200 for r in results)
    failed_flights = sum(r.get("takeoff", 200) != 200 or r.get("land", 200) != 200 for r in results)
    summary = {
        "starts": starts,
        "arms_refused": refused,
        "flights_failed": failed_flights if fly else None,
        "ready_s_median": statistics.median(ready),
        "ready_s_worst": max(ready),
    }
    if as_json:
        print(json.dumps({"summary": summary, "starts": results}))
    else:
        print(
            f"{starts} starts: {refused} arms refused"
            + (f", {failed_flights} take-off/landing failed" if fly else "")
            + f"; arm_blocked_by null {summary['ready_s_median']:.1f} s after start (median), "
            f"{summary['ready_s_worst']:.1f} s (worst)"
        )
    return 1 if refused or (fly and failed_flights) else 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--starts", type=int, default=20)
    parser.add_argument("--no-flight", action="store_true", help="arm and disarm only")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    return asyncio.run(run(args.starts, not args.no_flight, args.json))


if __name__ == "__main__":
    raise SystemExit(main())
