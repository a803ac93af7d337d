"""What writing the flight log costs a tick: JSON Lines, MCAP through the ``mcap`` package,
MCAP through ``foxglove-sdk``, in one run.

Each tick's record (the bar hovering with noise, as the flight process logs it: the
states, inputs, timings and the extra figures) is appended to all three writers in
turn, the order rotating every tick so that all three see the same load; the time of each
``append`` is taken, wall and the thread's CPU time (the wall time of a shared machine is
mostly other processes' preemption), the once-a-second chunk flush (MCAP) and the fsync
request included. Prints the median, p99 and max per tick, the CPU of the ticks that flush,
and the file's size.

Run: ``python -m benchmarks.flight_log [--ticks N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from supervisor.app.config import load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import FlightLogSink, FlightLogWriter
from supervisor.logs.mcap_log import McapFlightLogWriter

TICK_S = 0.02


def _records(ticks: int, seed: int = 0) -> list[TickRecord]:
    params = load_config(DEFAULT_SETUP).system.to_params()
    ref = formation_equilibrium(
        params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0,) * params.n_vehicles)
    ).x
    rng = np.random.default_rng(seed)
    records = []
    for k in range(ticks):
        state = ref + rng.normal(0.0, 0.01, ref.shape)
        hover = np.array([14.0, 0.01, -0.01, 0.0, 13.5, 0.0, 0.01, 0.0])  # the lab's two UAVs
        inputs = hover + rng.normal(0, 0.1, hover.size)
        records.append(
            TickRecord(
                k / round(1.0 / TICK_S),  # exact at whole seconds, where the writers flush
                "tracking",
                "centralized",
                state.tolist(),
                ref.tolist(),
                inputs.tolist(),
                "optimal",
                0.3,
                0.5,
                0.05,
                4.0,
                {
                    "compute_total_ms": 0.9,
                    "latency_ms": 3.1,
                    "mocap_wait_ms": 1.2,
                    "skipped": 0,
                    "mpc_prepared": True,
                },
            )
        )
    return records


def _figures(wall_s: list[float], cpu_s: list[float]) -> dict[str, float]:
    wall, cpu = np.array(wall_s) * 1e3, np.array(cpu_s) * 1e3
    flushing = np.arange(len(cpu)) % round(1.0 / TICK_S) == 0  # the writers' once a second
    return {
        "wall_median_ms": float(np.median(wall)),
        "wall_p99_ms": float(np.percentile(wall, 99)),
        "wall_max_ms": float(wall.max()),
        "cpu_median_ms": float(np.median(cpu)),
        "cpu_p99_ms": float(np.percentile(cpu, 99)),
        "cpu_flush_tick_median_ms": float(np.median(cpu[flushing])),
    }


def run(ticks: int) -> dict[str, dict[str, float]]:
    """Per-tick append cost of the three writers over ``ticks`` interleaved ticks."""
    records = _records(ticks)
    header = {"setup": "benchmark", "controller": "centralized", "arms_m": [0.705, 0.765]}
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder)
        factories: dict[str, Callable[[], FlightLogSink]] = {
            "jsonl": lambda: FlightLogWriter(out / "f.jsonl", header),
            "mcap (mcap package)": lambda: McapFlightLogWriter(out / "m.mcap", header),
            "mcap (foxglove-sdk)": lambda: McapFlightLogWriter(
                out / "f.mcap", header, library="foxglove"
            ),
        }
        writers = {name: make() for name, make in factories.items()}
        names = list(writers)
        wall: dict[str, list[float]] = {name: [] for name in names}
        cpu: dict[str, list[float]] = {name: [] for name in names}
        for k, record in enumerate(records):
            for name in names[k % 3 :] + names[: k % 3]:
                started_wall, started_cpu = time.perf_counter(), time.thread_time()
                writers[name].append(record)
                cpu[name].append(time.thread_time() - started_cpu)
                wall[name].append(time.perf_counter() - started_wall)
        for writer in writers.values():
            writer.close()
        sizes = {name: writers[name].path.stat().st_size for name in names}
    result = {name: _figures(wall[name], cpu[name]) for name in names}
    for name in names:
        result[name]["file_kib"] = sizes[name] / 1024
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=3000, help="ticks (default 3000: 60 s)")
    parser.add_argument("--json", action="store_true", help="the figures as JSON")
    args = parser.parse_args()
    result = run(args.ticks)
    if args.json:
        print(json.dumps(result, indent=2))
        return
    print(f"{args.ticks} ticks ({args.ticks * TICK_S:.0f} s of flight), each writer in turn")
    print("per tick [ms]           wall: median    p99    max   CPU: median    p99  flush   file")
    for name, f in result.items():
        print(
            f"{name:<22} {f['wall_median_ms']:>13.3f} {f['wall_p99_ms']:>6.2f} "
            f"{f['wall_max_ms']:>6.1f} {f['cpu_median_ms']:>12.3f} {f['cpu_p99_ms']:>6.2f} "
            f"{f['cpu_flush_tick_median_ms']:>6.2f} {math.ceil(f['file_kib']):>5}KiB"
        )


if __name__ == "__main__":
    main()
