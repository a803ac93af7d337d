"""What the live Foxglove view and the MCAP log cost the ticks of a real flight, in one run:
``python -m benchmarks.foxglove_view [--duration S] [--rate N] [--websockets N] [--json]``.

Three flights of ``benchmarks.tick`` (``serve`` on the embedded simulator, the paper's
setpoints, by default 200 API requests/s and 10 telemetry WebSocket clients), one after
the other:
the view off with a JSON Lines log (the baseline), the view off with an MCAP log, and the
view on with an MCAP log and a Foxglove client subscribed to every channel throughout. For
each: the tick figures from the flight log (compute p50/p99, lateness p99, missed
deadlines) and, for the third, how many messages the client received.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import websockets

from benchmarks.service import RunningService, running_service
from benchmarks.tick import TOKEN, fly, load, summarize, watch

RUNS = {
    "view off, JSON Lines log": ['log.format="jsonl"', "foxglove.enabled=false"],
    "view off, MCAP log": ['log.format="mcap"', "foxglove.enabled=false"],
    "view on + 1 client, MCAP log": [
        'log.format="mcap"',
        "foxglove.enabled=true",
        "foxglove.port=0",
    ],
}
FIGURES = ("ticks", "missed_deadlines", "compute_ms_p50", "compute_ms_p99", "lateness_ms_p99")


def _view_port(service: RunningService) -> int | None:
    pattern = re.compile(r"Foxglove view: ws://\S+:(\d+)")
    found = [match for line in service.output if (match := pattern.search(line))]
    return int(found[-1].group(1)) if found else None


async def subscriber(service: RunningService, stop: asyncio.Event) -> int:
    """A Foxglove client subscribed to every advertised channel, from when ``serve`` has
    said the view's port; the messages it got."""
    while (port := _view_port(service)) is None:  # noqa: ASYNC110 - serve's output, a list
        await asyncio.sleep(0.1)
    received = 0
    protocol = websockets.Subprotocol("foxglove.sdk.v1")
    url = f"ws://127.0.0.1:{port}/?token={service.token}"
    async with websockets.connect(url, subprotocols=[protocol]) as socket:
        while not stop.is_set():
            try:
                message = await asyncio.wait_for(socket.recv(), 0.5)
            except TimeoutError:
                continue
            if isinstance(message, bytes):
                received += message[0] == 0x01
                continue
            decoded = json.loads(message)
            if decoded["op"] == "advertise":
                subscriptions = [
                    {"id": channel["id"], "channelId": channel["id"]}
                    for channel in decoded["channels"]
                ]
                await socket.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
    return received


async def flight(
    duration_s: float, overrides: list[str], rate_hz: float, n_websockets: int
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as scratch:
        async with running_service(TOKEN, Path(scratch), overrides) as service:
            stop = asyncio.Event()
            started = time.monotonic()
            tasks = [asyncio.create_task(load(service.url, rate_hz, stop))]
            tasks += [asyncio.create_task(watch(service.url, stop)) for _ in range(n_websockets)]
            viewing = "foxglove.port=0" in overrides
            viewer = asyncio.create_task(subscriber(service, stop)) if viewing else None
            log_path = await fly(service, duration_s)
            stop.set()
            elapsed = time.monotonic() - started
            requests = (await asyncio.gather(*tasks))[0]
            result = {name: summarize(log_path, requests, elapsed)[name] for name in FIGURES}
            if viewer is not None:
                result["view_messages_received"] = await viewer
            return result


async def run(duration_s: float, rate_hz: float, n_websockets: int) -> dict[str, dict[str, Any]]:
    return {
        name: await flight(duration_s, overrides, rate_hz, n_websockets)
        for name, overrides in RUNS.items()
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=30.0, metavar="S")
    parser.add_argument("--rate", type=float, default=200.0, help="API requests per second")
    parser.add_argument("--websockets", type=int, default=10, help="telemetry clients")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    result = asyncio.run(run(args.duration, args.rate, args.websockets))
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"{'flight':30s} {'ticks':>6s} {'missed':>6s} {'compute p50/p99 [ms]':>21s} "
        f"{'lateness p99':>12s} {'view msgs':>9s}"
    )
    for name, r in result.items():
        print(
            f"{name:30s} {r['ticks']:6d} {r['missed_deadlines']:6d} "
            f"{r['compute_ms_p50']:10.2f} / {r['compute_ms_p99']:5.2f}    "
            f"{r['lateness_ms_p99']:9.2f} ms {r.get('view_messages_received', '-')!s:>9s}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
