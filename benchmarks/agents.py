"""The agents as processes against one flight process: ``python -m benchmarks.agents
[--config SETUP] [--duration S] [--delay-ms MS] [--json]``.

Starts ``serve`` on the embedded simulator (``--config``: sim, or sim_tri for three
agents under the plate) twice, one after the other on free ports: one
flight process flying the decentralized MPC, then ``agents.enabled`` (an agent process
per vehicle, over Zenoh: docs/agents.md). Each flies the paper's setpoint sequence over
HTTP (``benchmarks.tick.fly``). From the flight logs (for the agents, agent 1's, which
flies the same core): the bar's x error, tick lateness and compute; from the agents' logs
the one-way latency of their peers' ticks (by the wall clock: one computer); from the
status, sampled every 0.2 s, the ground station's Zenoh round trip to each agent. Then one
agent's MPC tick for 2, 3 and 4 vehicles (``benchmarks.scaling``: each agent solves only its
own problem, so its cost does not grow with the team).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import json
import math
import os
import re
import signal
import socket
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from benchmarks.delay_relay import delay_relay
from benchmarks.scaling import measure
from benchmarks.service import RunningService, running_service
from benchmarks.tick import TOKEN, fly
from supervisor.app.agent_spawn import agent_command
from supervisor.app.child_entries import Setup
from supervisor.app.config import TOKEN_ENV, load_config
from supervisor.app.config_files import CONFIG_DIR, setup_path
from supervisor.flight.status import Status
from supervisor.logs.flight_log import read_flight_log
from supervisor.logs.report import summarize

STATUS_PERIOD_S = 0.2


def _percentiles(values: list[float] | np.ndarray) -> dict[str, float]:
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if not len(finite):
        return {"p50": math.nan, "p99": math.nan, "n": 0}
    return {
        "p50": float(np.percentile(finite, 50)),
        "p99": float(np.percentile(finite, 99)),
        "n": len(finite),
    }


async def _sample_round_trips(service: RunningService, stop: asyncio.Event) -> list[float]:
    """The ground station's round trips to the agents, as the status shows them."""
    trips: list[float] = []
    async with service.client() as http:
        while not stop.is_set():
            response = await http.get("/api/status")
            if response.status_code == 200:  # 503 until the agents are first heard
                status = Status.model_validate_json(response.content)
                trips += [a.link_latency_ms for a in status.agents or [] if a.link_latency_ms]
            await asyncio.sleep(STATUS_PERIOD_S)
    return trips


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _world_addresses(output: list[str]) -> dict[str, Any]:
    """The embedded world's addresses as serve logs them."""
    line = next(line for line in output if "simulated world: QTM" in line)
    qtm, vehicles = re.search(r"QTM (\S+), PX4s (.+)$", line).groups()  # type: ignore[union-attr]
    return {"qtm": qtm, "vehicles": [v.strip() for v in vehicles.split(",")]}


def _scheme(setup: Setup) -> str:
    """The Zenoh endpoints' scheme: ``tls`` for a fleet with certificates (it refuses any
    other), else ``tcp``; the delaying relay carries either, byte for byte."""
    return "tls" if setup.load().agents.tls_folder else "tcp"


@contextlib.asynccontextmanager
async def delayed_agents(
    service: RunningService, ground_port: int, delay_s: float, setup: Setup
) -> AsyncIterator[None]:
    """Every agent started here, every Zenoh link between them and to the ground station
    through a relay that delays it ``delay_s`` each way (``benchmarks.delay_relay``)."""
    world = _world_addresses(service.output)
    vehicles = range(1, len(world["vehicles"]) + 1)
    listen = [_free_port() for _ in vehicles]
    scheme = _scheme(setup)
    async with contextlib.AsyncExitStack() as stack:
        ground = await stack.enter_async_context(delay_relay(("127.0.0.1", ground_port), delay_s))
        relays = [
            await stack.enter_async_context(delay_relay(("127.0.0.1", port), delay_s))
            for port in listen
        ]
        processes = []
        for vehicle in vehicles:
            own = f"{scheme}/127.0.0.1:{listen[vehicle - 1]}"
            peers = [f"{scheme}/127.0.0.1:{relays[j - 1]}" for j in vehicles if j != vehicle]
            connect = [f"{scheme}/127.0.0.1:{ground}", *peers]
            command = agent_command(setup, vehicle, own, connect, world)
            processes.append(
                await asyncio.create_subprocess_exec(
                    *command,
                    stdout=asyncio.subprocess.DEVNULL,
                    stderr=asyncio.subprocess.DEVNULL,
                    env={**os.environ, TOKEN_ENV: TOKEN},
                )
            )
        try:
            yield
        finally:
            for process in processes:
                if process.returncode is None:
                    process.send_signal(signal.SIGTERM)
            for process in processes:
                await process.wait()


async def fly_once(
    setup_name: str,
    agents: bool,
    duration_s: float,
    overrides: list[str],
    folder: Path,
    delay_s: float = 0.0,
) -> tuple[Path, list[float], float]:
    """One serve flying the paper's sequence: its flight log, the round trips the status
    showed, and how long the flight took [s]. With ``delay_s``, the agents' links are
    delayed that much each way."""
    enabled = ["agents.enabled=true"] if agents else []
    ground_port = _free_port()
    delayed = []  # after the caller's overrides: the ground station listens for the relay
    if delay_s:
        scheme = _scheme(Setup(setup_path(setup_name), tuple(overrides)))
        ground = f"{scheme}/127.0.0.1:{ground_port}"
        delayed = ["agents.spawn=false", f'agents.ground_endpoint="{ground}"']
    async with contextlib.AsyncExitStack() as stack:
        service = await stack.enter_async_context(
            running_service(TOKEN, folder, [*enabled, *overrides, *delayed], setup=setup_name)
        )
        if delay_s:
            setup = Setup(setup_path(setup_name), (f'log.folder="{folder}"', *overrides))
            await stack.enter_async_context(delayed_agents(service, ground_port, delay_s, setup))
        if not agents:
            async with service.client() as http:
                switched = await http.post("/api/mode", json={"controller": "decentralized"})
                switched.raise_for_status()
        stop = asyncio.Event()
        sampler = asyncio.create_task(_sample_round_trips(service, stop))
        started = time.monotonic()
        log_path = await fly(service, duration_s)
        stop.set()
        return Path(log_path), await sampler, time.monotonic() - started


def flight(
    setup_name: str, agents: bool, duration_s: float, overrides: list[str], delay_s: float = 0.0
) -> dict[str, Any]:
    """The figures of one serve flying the paper's sequence."""
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        flown = fly_once(setup_name, agents, duration_s, overrides, folder, delay_s)
        try:
            log_path, trips, elapsed = asyncio.run(flown)
        except Exception as error:  # the agents' own logs say why; the folder goes with us
            said = [f"--- {p.name} ---\n{p.read_text()[-4000:]}" for p in folder.glob("agent*.log")]
            raise RuntimeError("\n".join([str(error), *said])) from error
        log = read_flight_log(log_path)
        figures = summarize(log)
        compute = np.array([r.get("compute_total_ms", math.nan) for r in log.extra], dtype=float)
        result: dict[str, Any] = {
            "flight_s": elapsed,
            "bar_x_error_std_m": figures["bar_x_error_std_m"],
            "bar_x_error_mean_m": figures["bar_x_error_mean_m"],
            "lateness_ms": _percentiles(log.lateness_ms),
            "compute_ms": _percentiles(compute),
        }
        if agents:
            peers = []
            for path in sorted(folder.glob("**/agent*/flight-*.mcap")):
                agent_log = read_flight_log(path)
                peers += [r.get("peer_latency_ms", math.nan) for r in agent_log.extra]
            result["agent_to_agent_one_way_ms"] = _percentiles(peers)
            result["agent_to_ground_round_trip_ms"] = _percentiles(trips)
        return result


def per_agent_solve(ticks: int) -> list[dict[str, Any]]:
    """One agent's MPC tick for 2, 3 and 4 vehicles (``benchmarks.scaling``)."""
    config = load_config(CONFIG_DIR / "sim.toml")
    with threadpool_limits(limits=1):
        return [measure(config, n, ticks, "hpipm")["decentralized_agent"] for n in (2, 3, 4)]


def _ms(figures: dict[str, float]) -> str:
    return f"{figures['p50']:7.3f} / {figures['p99']:7.3f}"


def print_result(result: dict[str, Any]) -> None:
    one, fleet = result["one_process"], result["agents"]
    print(
        f"The paper's sequence over HTTP on {result['setup']} "
        "(one flight process, decentralized | agents):"
    )
    for key in ("bar_x_error_std_m", "bar_x_error_mean_m"):
        print(f"  {key:34s} {one[key] * 1e3:8.1f} mm | {fleet[key] * 1e3:8.1f} mm")
    print(f"  {'ratio of bar x error std (agents / one)':34s} {result['std_ratio']:8.2f}")
    for key in ("lateness_ms", "compute_ms"):
        print(f"  {key + ' p50 / p99':34s} {_ms(one[key])} | {_ms(fleet[key])}")
    print(f"  {'agent → agent tick, one way ms':34s} {_ms(fleet['agent_to_agent_one_way_ms'])}")
    trip = fleet["agent_to_ground_round_trip_ms"]
    print(f"  {'ground ⇄ agent round trip ms':34s} {_ms(trip)}")
    delayed = result["agents_delayed"]
    if delayed is not None:
        print(f"Agents with {result['delay_ms']:g} ms added on every Zenoh link, each way:")
        for key in ("bar_x_error_std_m", "bar_x_error_mean_m"):
            print(f"  {key:34s} {delayed[key] * 1e3:8.1f} mm")
        print(
            f"  {'agent → agent tick, one way ms':34s} {_ms(delayed['agent_to_agent_one_way_ms'])}"
        )
    print("One agent's MPC tick (hpipm):")
    for n, row in zip((2, 3, 4), result["per_agent_solve"], strict=True):
        print(f"  N = {n}: p50 / p99 {row['p50_ms']:.3f} / {row['p99_ms']:.3f} ms")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="sim", metavar="SETUP", help="sim or sim_tri")
    parser.add_argument("--duration", type=float, default=30.0, metavar="S")
    parser.add_argument("--ticks", type=int, default=300, help="ticks of the solve figures")
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--delay-ms",
        type=float,
        default=0.0,
        help="also fly the agents with this delay added on their links, each way",
    )
    parser.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="both serves' --set"
    )
    args = parser.parse_args(argv)
    print("one flight process …", file=sys.stderr, flush=True)
    one = flight(args.config, False, args.duration, args.set)
    print("agents …", file=sys.stderr, flush=True)
    fleet = flight(args.config, True, args.duration, args.set)
    delayed = None
    if args.delay_ms:
        print(f"agents, {args.delay_ms:g} ms added …", file=sys.stderr, flush=True)
        delayed = flight(args.config, True, args.duration, args.set, args.delay_ms / 1e3)
    print("one agent's solve for 2, 3, 4 vehicles …", file=sys.stderr, flush=True)
    result = {
        "setup": args.config,
        "agents_delayed": delayed,
        "delay_ms": args.delay_ms,
        "one_process": one,
        "agents": fleet,
        "std_ratio": fleet["bar_x_error_std_m"] / one["bar_x_error_std_m"],
        "per_agent_solve": per_agent_solve(args.ticks),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print_result(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
