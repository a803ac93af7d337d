"""Abort through the API under load: ``python -m benchmarks.api_load [--rate N] [--json]``.

Starts ``uavbar-supervisor serve`` on the embedded simulator, takes off to a hover, and
meanwhile a load process (its own CPU, niced as the API process is) holds ``--websockets``
telemetry clients that never read a byte after their handshake and sends ``--rate``
requests per second, open loop: status reads, setpoint posts that do not fit their schema
(422), setpoints outside the arena (409) and posts without the token (401). Aborts are sent
every ``--abort-every`` seconds from this process on one keep-alive connection, as the
dashboard's would be: the first from the hover. Before the load, the same number of aborts
without load is the baseline of the same run.

An abort's latency is its round trip: sent, forwarded by the API on the urgent channel,
answered by the flight process, answer received. Lost: no 200 within 2 s.

Targets (issue 17): abort p99 ≤ 100 ms under 1000 requests/s and 50 clients that never
read, none lost.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import multiprocessing
import os
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import aiohttp
import httpx
import numpy as np

from benchmarks.service import RunningService, all_connected, all_disarmed, running_service
from supervisor.flight.status import Status

TOKEN = "api-load-benchmark-token"
ABORT_TIMEOUT_S = 2.0
LOAD_NICENESS = 5  # below the API: remote clients would not share its CPU at all
MAX_IN_FLIGHT = 400  # beyond this the generator counts requests as not sent
# What the load posts: nothing of it may change the flight.
NOT_A_SETPOINT = {"bar_position": [True, False, True]}  # 422: booleans are not metres
OUTSIDE_THE_ARENA = {"bar_position": [0.0, 0.0, 2.9], "hold_s": 1.0}  # 409


async def silent_websocket(host: str, port: int) -> asyncio.StreamWriter | None:
    """A telemetry WebSocket whose client reads nothing after the handshake's answer."""
    try:
        reader, writer = await asyncio.open_connection(host, port)
    except OSError:
        return None
    key = base64.b64encode(os.urandom(16)).decode()
    writer.write(
        (
            f"GET /api/telemetry HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
            "Sec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    answer = await reader.readuntil(b"\r\n\r\n")
    return writer if b" 101 " in answer.split(b"\r\n", 1)[0] else None


async def generate_load(
    url: str, rate_hz: float, n_websockets: int, stop: Any, report: Any
) -> None:
    host, port = url.rsplit("//", 1)[1].rsplit(":", 1)
    sockets = [await silent_websocket(host, int(port)) for _ in range(n_websockets)]
    statuses: Counter[str] = Counter()
    kinds: Counter[str] = Counter()
    auth = {"Authorization": f"Bearer {TOKEN}"}
    connector = aiohttp.TCPConnector(limit=MAX_IN_FLIGHT)
    timeout = aiohttp.ClientTimeout(total=10.0)
    async with aiohttp.ClientSession(url, connector=connector, timeout=timeout) as http:

        async def one(kind: str) -> None:
            try:
                if kind == "status":
                    request = http.get("/api/status")
                elif kind == "no token":
                    request = http.post("/api/setpoints", json=OUTSIDE_THE_ARENA)
                else:
                    body = NOT_A_SETPOINT if kind == "invalid" else OUTSIDE_THE_ARENA
                    request = http.post("/api/setpoints", json=body, headers=auth)
                async with request as response:
                    await response.read()
                    statuses[str(response.status)] += 1
            except (aiohttp.ClientError, TimeoutError):
                statuses["failed"] += 1

        mix = ["status"] * 5 + ["invalid"] * 2 + ["outside the arena"] * 2 + ["no token"]
        pending: set[asyncio.Task[None]] = set()
        sent = 0
        started = time.monotonic()
        while not stop.is_set():
            due = int((time.monotonic() - started) * rate_hz)
            while sent < due:
                kind = mix[sent % len(mix)]
                sent += 1
                if len(pending) >= MAX_IN_FLIGHT:
                    kinds["not sent"] += 1
                    continue
                kinds[kind] += 1
                task = asyncio.create_task(one(kind))
                pending.add(task)
                task.add_done_callback(pending.discard)
            await asyncio.sleep(0.005)
        elapsed = time.monotonic() - started
        await asyncio.gather(*pending, return_exceptions=True)
    for writer in sockets:
        if writer is not None:
            writer.close()
    report.put(
        {
            "load_s": elapsed,
            "sent_per_s": sum(v for k, v in kinds.items() if k != "not sent") / elapsed,
            "kinds": dict(kinds),
            "statuses": dict(statuses),
            "silent_websockets": sum(w is not None for w in sockets),
        }
    )


def load_process(url: str, rate_hz: float, n_websockets: int, stop: Any, report: Any) -> None:
    os.nice(LOAD_NICENESS)
    asyncio.run(generate_load(url, rate_hz, n_websockets, stop, report))


async def timed_abort(http: httpx.AsyncClient) -> float | None:
    """One abort's round trip [s], or None when it was lost."""
    started = time.perf_counter()
    try:
        response = await http.post("/api/abort", timeout=ABORT_TIMEOUT_S)
    except httpx.HTTPError:
        return None
    elapsed = time.perf_counter() - started
    return elapsed if response.status_code == 200 and elapsed <= ABORT_TIMEOUT_S else None


async def aborts(http: httpx.AsyncClient, count: int, every_s: float) -> list[float | None]:
    results = []
    for _ in range(count):
        results.append(await timed_abort(http))
        await asyncio.sleep(every_s)
    return results


def figures(latencies: list[float | None]) -> dict[str, Any]:
    done = np.array([t for t in latencies if t is not None]) * 1000.0
    return {
        "sent": len(latencies),
        "lost": len(latencies) - len(done),
        "median_ms": float(np.median(done)) if len(done) else None,
        "p99_ms": float(np.percentile(done, 99)) if len(done) else None,
        "max_ms": float(done.max()) if len(done) else None,
    }


async def run(
    rate_hz: float, n_websockets: int, n_aborts: int, every_s: float, overrides: list[str]
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as logs:
        async with running_service(TOKEN, Path(logs), overrides) as service:
            return await measure(service, rate_hz, n_websockets, n_aborts, every_s)


async def status_through_the_load(http: httpx.AsyncClient) -> Status:
    """The status, asked again after each 503 (the gate sheds everything but abort and kill
    under the flood) as its Retry-After says, for up to 30 s."""
    for _ in range(30):
        response = await http.get("/api/status")
        if response.status_code != 503:
            response.raise_for_status()
            return Status.model_validate_json(response.content)
        await asyncio.sleep(float(response.headers.get("retry-after", "1")))
    raise RuntimeError("the status was shed for 30 s")


async def measure(
    service: RunningService, rate_hz: float, n_websockets: int, n_aborts: int, every_s: float
) -> dict[str, Any]:
    async with service.client() as http:
        await service.wait_for(http, all_connected, 60.0, "healthy mocap and both links")
        await timed_abort(http)  # the connection open, as the dashboard's is
        baseline = await aborts(http, n_aborts, every_s)

        await service.take_off(http, again_after_world_stall=False)
        context = multiprocessing.get_context("spawn")
        stop, report = context.Event(), context.Queue()
        load = context.Process(
            target=load_process, args=(service.url, rate_hz, n_websockets, stop, report)
        )
        load.start()
        try:
            await asyncio.sleep(3.0)  # the load and the silent clients' buffers fill
            hover = await status_through_the_load(http)
            loaded = await aborts(http, n_aborts, every_s)
            at_the_end = await status_through_the_load(http)
        finally:
            stop.set()
            load_report = await asyncio.to_thread(report.get, True, 60.0)
            await asyncio.to_thread(load.join, 10.0)
        await service.wait_for(http, all_disarmed, 90.0, "disarmed")
    return {
        "baseline": figures(baseline),
        "under_load": figures(loaded),
        "first_abort_from": hover.mode.value,
        "mode_at_the_end": at_the_end.mode.value,
        "first_abort_ms": None if loaded[0] is None else loaded[0] * 1000.0,
        "slowest_under_load": sorted(
            ((round(t * 1000.0, 1), i) for i, t in enumerate(loaded) if t is not None),
            reverse=True,
        )[:5],
        "load": load_report,
    }


def print_result(result: dict[str, Any]) -> None:
    def line(name: str, f: dict[str, Any]) -> str:
        numbers = ", ".join(
            f"{k.removesuffix('_ms')} {f[k]:.1f} ms" for k in ("median_ms", "p99_ms", "max_ms")
        )
        return f"{name:12s} {f['sent']} aborts, lost {f['lost']}: {numbers}"

    load = result["load"]
    print(line("baseline", result["baseline"]))
    print(line("under load", result["under_load"]))
    print(
        f"first abort from {result['first_abort_from']}: {result['first_abort_ms']:.1f} ms, "
        f"{result['mode_at_the_end']} after the last"
    )
    print(
        f"load: {load['sent_per_s']:.0f} requests/s sent for {load['load_s']:.1f} s, "
        f"{load['silent_websockets']} WebSocket clients that never read"
    )
    print(f"      kinds {load['kinds']}")
    print(f"      answers {load['statuses']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rate", type=float, default=1000.0, help="API requests per second")
    parser.add_argument("--websockets", type=int, default=50)
    parser.add_argument("--aborts", type=int, default=200, help="aborts per phase")
    parser.add_argument("--abort-every", type=float, default=0.05, metavar="S")
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="serve's --set"
    )
    args = parser.parse_args(argv)
    result = asyncio.run(run(args.rate, args.websockets, args.aborts, args.abort_every, args.set))
    if args.json:
        print(json.dumps(result))
    else:
        print_result(result)
    under_load = result["under_load"]
    return 0 if under_load["lost"] == 0 and under_load["p99_ms"] <= 100.0 else 1


if __name__ == "__main__":
    with contextlib.suppress(KeyboardInterrupt):
        sys.exit(main())
