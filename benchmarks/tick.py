"""Tick timing under API load: ``python -m benchmarks.tick [--duration S] [--json]``.

Starts ``uavbar-supervisor serve`` on the embedded simulator (a subprocess, free ports),
flies the paper's setpoint sequence over HTTP, and meanwhile loads the API with
``--rate`` requests per second (status reads and setpoint posts, half each) and
``--websockets`` telemetry clients. At the end it lands, and reads the tick timings of
every tick of the flight from the flight log: compute time, lateness, missed deadlines,
and the latency from receiving a mocap frame to sending the MAVLink setpoints computed
from it (reported by the flight process). The load generator shares the machine with the
service, so it uses aiohttp's client (less than half the CPU httpx took for the same
load) and reports its own CPU share (``load_generator_cpu_share``, of one core).

Targets on a 2-core machine: 0 missed deadlines, lateness p99 ≤ 1 ms, latency p99 ≤ 3 ms.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import aiohttp
import numpy as np
import websockets

from benchmarks.service import RunningService, in_mode, notices, running_service
from supervisor.flight.modes import Mode
from supervisor.logs.flight_log import read_flight_log
from supervisor.logs.report import summarize as summarize_flight

TOKEN = "benchmark-token"
PAPER_SETPOINTS: list[dict[str, Any]] = [
    {"bar_position": [0.0, 0.0, 1.0], "bar_yaw": math.pi / 2, "uav_yaw": [math.pi / 2, 0.0]},
    {"bar_position": [1.0, 0.0, 1.0], "bar_yaw": math.pi / 2, "uav_yaw": [math.pi, math.pi / 2]},
    {"bar_position": [0.0, 0.0, 1.0]},
    {"bar_position": [0.0, 0.0, 1.0], "theta_l": math.pi / 4},
    {"bar_position": [0.0, 0.0, 1.0]},
]


def paper_setpoints(n_vehicles: int) -> list[dict[str, Any]]:
    """The paper's sequence for ``n_vehicles`` under the payload: as flown with two; with
    more, the same payload poses and cable angle, each UAV keeping its yaw (the paper's UAV
    yaws are one per end of its bar)."""
    if n_vehicles == 2:
        return PAPER_SETPOINTS
    return [{k: v for k, v in s.items() if k != "uav_yaw"} for s in PAPER_SETPOINTS]


async def load(url: str, rate_hz: float, stop: asyncio.Event) -> int:
    """Status reads and setpoint posts at ``rate_hz`` in total; returns the request count."""
    count = 0
    period = 1.0 / rate_hz
    headers = {"Authorization": f"Bearer {TOKEN}"}
    # Outside the arena: validated (equilibrium and geofence) and refused with 409, so the
    # load exercises the setpoint path without changing the flight.
    post = {"bar_position": [0.0, 0.0, 2.9], "hold_s": 1.0}
    connector = aiohttp.TCPConnector(limit=20)
    timeout = aiohttp.ClientTimeout(total=5.0)
    async with aiohttp.ClientSession(url, connector=connector, timeout=timeout) as http:

        async def status() -> None:
            async with http.get("/api/status") as response:
                await response.read()

        async def refused_post() -> None:
            async with http.post("/api/setpoints", json=post, headers=headers) as response:
                await response.read()

        pending: set[asyncio.Task[Any]] = set()
        started = time.monotonic()
        while not stop.is_set():
            task = asyncio.ensure_future(status() if count % 2 == 0 else refused_post())
            pending.add(task)
            task.add_done_callback(pending.discard)
            count += 1
            await asyncio.sleep(max(0.0, started + count * period - time.monotonic()))
        await asyncio.gather(*pending, return_exceptions=True)
    return count


async def watch(url: str, stop: asyncio.Event) -> int:
    """One telemetry WebSocket client (reconnecting, as the dashboard does); returns the
    messages received."""
    received = 0
    while not stop.is_set():
        try:
            async with websockets.connect(url.replace("http", "ws") + "/api/telemetry") as ws:
                while not stop.is_set():
                    with contextlib.suppress(TimeoutError):
                        async with asyncio.timeout(0.5):
                            await ws.recv()
                            received += 1
        except (websockets.ConnectionClosed, OSError):
            await asyncio.sleep(0.5)
    return received


async def fly(service: RunningService, duration_s: float) -> str:
    """Arm, take off, fly the paper's setpoints until ``duration_s`` has passed, land.
    Returns the flight log's path."""
    async with service.client() as http:
        status = await service.take_off(http, again_after_world_stall=False)
        log = str(status.log)
        started = time.monotonic()
        while time.monotonic() - started < duration_s:
            for setpoint in paper_setpoints(len(status.uavs)):
                response = await http.post("/api/setpoints", json={**setpoint, "hold_s": 3.0})
                if response.status_code != 200:
                    raise RuntimeError(f"setpoint {setpoint} refused: {response.text}")
            await service.wait_for(
                http,
                lambda s: s.setpoints.active is None and not s.setpoints.queued,
                300.0,
                "the setpoints",
            )
        landing = await http.post("/api/land")
        if landing.status_code != 200:
            status = await service.status(http)
            raise RuntimeError(
                f"the flight did not last: {landing.text}; faults {status.faults};"
                f" notices {notices(status)}"
            )
        await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landing")
        return log


def summarize(log_path: str, requests: int, duration_s: float) -> dict[str, Any]:
    """Figures over every tick of the flight, from its log."""
    log = read_flight_log(Path(log_path))
    flight = summarize_flight(log)

    def column(name: str) -> np.ndarray:
        return np.array([r.get(name, math.nan) for r in log.extra], dtype=float)

    compute, latency, wait = (
        column("compute_total_ms"),
        column("latency_ms"),
        column("mocap_wait_ms"),
    )
    lateness = np.asarray(log.lateness_ms, dtype=float)
    late = int(np.sum(lateness + compute >= 20.0))
    return {
        "duration_s": duration_s,
        "api_requests_per_s": requests / duration_s,
        "ticks": len(log.t_s),
        "missed_deadlines": late + int(np.nansum(column("skipped"))),
        "compute_ms_p50": float(np.nanpercentile(compute, 50)),
        "compute_ms_p99": float(np.nanpercentile(compute, 99)),
        "lateness_ms_p99": float(np.percentile(lateness, 99)),
        "latency_ms_p50": float(np.nanpercentile(latency, 50)),
        "latency_ms_p99": float(np.nanpercentile(latency, 99)),
        # Where the latency goes: the newest frame's wait for its tick, then the tick.
        "mocap_wait_ms_p50": float(np.nanpercentile(wait, 50)),
        "mocap_wait_ms_p99": float(np.nanpercentile(wait, 99)),
        "compute_ms_max": float(np.nanmax(compute)),
        # Inside the tick: the tick core (mode logic, MPC, safety), and its QP solve.
        "core_ms_p50": float(np.nanpercentile(log.compute_ms, 50)),
        "core_ms_p99": float(np.nanpercentile(log.compute_ms, 99)),
        "solve_ms_p50": float(np.nanpercentile(log.solve_ms, 50)),
        "solve_ms_p99": float(np.nanpercentile(log.solve_ms, 99)),
        # The share of MPC ticks that used the model prepared after the tick before.
        "mpc_prepared_share": float(np.nanmean(column("mpc_prepared"))),
        # How the bar flew the paper's sequence (simulate's Table III figures).
        **{
            key: flight[key]
            for key in ("bar_x_error_mean_m", "bar_x_error_std_m", "bar_yaw_rms_deg")
        },
    }


def process_tree_cpu_s(root: int) -> dict[str, float]:
    """CPU time [s] (user + system) of ``root`` and its descendants, summed by process name
    (``serve`` names its children: uavbar-flight, uavbar-world, uavbar-relay; PX4 is px4)."""
    ticks = os.sysconf("SC_CLK_TCK")
    parents: dict[int, int] = {}
    names: dict[int, str] = {}
    cpu: dict[int, float] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        pid = int(stat.parent.name)
        fields = text.rsplit(")", 1)[1].split()
        names[pid] = text[text.index("(") + 1 : text.rindex(")")]
        parents[pid] = int(fields[1])
        cpu[pid] = (int(fields[11]) + int(fields[12])) / ticks
    tree, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        children = [pid for pid, ppid in parents.items() if ppid == parent]
        tree.update(children)
        frontier.extend(children)
    totals: dict[str, float] = {}
    for pid in tree & cpu.keys():
        name = "api (serve)" if pid == root else names[pid]
        totals[name] = totals.get(name, 0.0) + cpu[pid]
    return totals


async def run(
    duration_s: float, rate_hz: float, n_websockets: int, overrides: list[str]
) -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as scratch:
        async with running_service(TOKEN, Path(scratch), overrides) as service:
            stop = asyncio.Event()
            started = time.monotonic()
            cpu_started = time.process_time()
            processes_started = process_tree_cpu_s(service.process.pid)
            loaders = [asyncio.create_task(load(service.url, rate_hz, stop))]
            loaders += [asyncio.create_task(watch(service.url, stop)) for _ in range(n_websockets)]
            log_path = await fly(service, duration_s)
            stop.set()
            elapsed = time.monotonic() - started
            requests = (await asyncio.gather(*loaders))[0]
            result = summarize(log_path, requests, elapsed)
            result["load_generator_cpu_share"] = (time.process_time() - cpu_started) / elapsed
            # The share of one core each process took over the flight (px4: both summed).
            for name, cpu_s in process_tree_cpu_s(service.process.pid).items():
                if name.startswith(("uavbar", "px4", "api")):
                    share = (cpu_s - processes_started.get(name, 0.0)) / elapsed
                    result[f"cpu_share_{name.replace(' ', '_')}"] = share
        # The world's last word on the cables (sim/truth.py), logged as it closed.
        return {**result, **world_truth(service.output)}


TRUTH_FIGURES = (
    r"(\w+) hanging ([\d.]+) s, min cable tension (-?[\d.]+) N, slack events (\d+), "
    r"max UAV tilt ([\d.]+) deg, max descent ([\d.]+) m/s above [\d.]+ m \(([^)]*)\)"
)
TRUTH_LINE = re.compile("truth: " + TRUTH_FIGURES)
FLIGHT_TRUTH_LINE = re.compile(r"truth of flight \d+: " + TRUTH_FIGURES)
DESCENT_OF_A_BODY = re.compile(r"(\w+) ([\d.]+)")


def world_truth(output: list[str]) -> dict[str, float]:
    """The simulated world's figures from its last truth line (empty without one): the
    payload's hanging time (``bar_hanging_s``, or ``payload_hanging_s`` for another
    payload) and each body's fastest descent (``max_descent_uav1_mps``, ...)."""
    matches = [match for line in output if (match := TRUTH_LINE.search(line))]
    return truth_figures(matches[-1]) if matches else {}


def flight_truths(output: list[str]) -> list[dict[str, float]]:
    """The same figures for each flight the world saw end, in order (an empty dict for a
    flight in which the payload never hung)."""
    flights = [line for line in output if "truth of flight " in line]
    return [
        truth_figures(match) if (match := FLIGHT_TRUTH_LINE.search(line)) else {}
        for line in flights
    ]


def truth_figures(line: re.Match[str]) -> dict[str, float]:
    payload, hanging, tension, slack, tilt, descent, by_body = line.groups()
    figures = {
        f"{payload}_hanging_s": float(hanging),
        "min_tension_hanging_n": float(tension),
        "slack_events": int(slack),
        "max_uav_tilt_deg": float(tilt),
        "max_descent_mps": float(descent),
    }
    for name, body_descent in DESCENT_OF_A_BODY.findall(by_body):
        figures[f"max_descent_{name}_mps"] = float(body_descent)
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, metavar="S")
    parser.add_argument("--rate", type=float, default=200.0, help="API requests per second")
    parser.add_argument("--websockets", type=int, default=10)
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="serve's --set"
    )
    args = parser.parse_args(argv)
    result = asyncio.run(run(args.duration, args.rate, args.websockets, args.set))
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:22s} {value:.3f}" if isinstance(value, float) else f"{key:22s} {value}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
