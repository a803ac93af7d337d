"""How the MPC tick grows with the number of UAVs: both controllers on one back-end, N = 2
(the paper's bar, ``configs/sim.toml``) and rings of 3, 4, 6 and 8 UAVs.

Each ring is the paper's UAVs carrying a thin circular frame of 0.2 kg per UAV by cables of
1 m fixed at N points 0.75 m from its centre (three of them: about ``configs/sim_tri.toml``'s
plate). For each N the closed-loop-like sequence of ``benchmarks.mpc`` (perturbed start,
turning yaws, θ_l steps, gusts that saturate the torques) is recorded with the same back-end
and replayed by a fresh controller, timed over the full tick; the decentralized figure is
one agent's tick (each agent runs on its own). Ratios are against N = 2 in the same run.

Run: ``python -m benchmarks.scaling [--vehicles 2,3,4,6,8] [--ticks 300] [--backend hpipm]
[--json]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from benchmarks.mpc import centralized_run, decentralized_run, record_sequence
from controllers.formation_params import FormationParams, PayloadParams
from controllers.params import MpcSettings
from supervisor.app.config import Config, load_config
from supervisor.app.config_files import CONFIG_DIR

RING_RADIUS_M = 0.75
RING_MASS_PER_UAV_KG = 0.2
CABLE_LENGTH_M = 1.0


def ring_formation(bar: FormationParams, n_vehicles: int) -> FormationParams:
    """``n_vehicles`` of the bar's UAVs carrying a thin ring by N evenly spaced points."""
    mass = RING_MASS_PER_UAV_KG * n_vehicles
    in_plane = mass * RING_RADIUS_M**2 / 2.0
    angles = [2.0 * math.pi * k / n_vehicles for k in range(n_vehicles)]
    payload = PayloadParams(
        mass_kg=mass,
        inertia_kgm2=((in_plane, 0.0, 0.0), (0.0, in_plane, 0.0), (0.0, 0.0, 2.0 * in_plane)),
        attachments_m=tuple(
            (RING_RADIUS_M * math.cos(a), RING_RADIUS_M * math.sin(a), 0.0) for a in angles
        ),
    )
    return FormationParams(
        (bar.uavs[0],) * n_vehicles, payload, (CABLE_LENGTH_M,) * n_vehicles, bar.gravity_mps2
    )


def _settings(config: Config, controller: str, n_vehicles: int, backend: str) -> MpcSettings:
    settings = config.mpc.settings(controller, n_vehicles)
    # Every solve is kept and timed: the real-time budget is the service's concern.
    return dataclasses.replace(settings, late_after_s=math.inf, qp_backend=backend)


def _figures(durations_s: np.ndarray) -> dict[str, float]:
    ms = durations_s * 1e3
    return {"p50_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99))}


def measure(config: Config, n_vehicles: int, ticks: int, backend: str) -> dict[str, Any]:
    """Both controllers' tick times for ``n_vehicles`` UAVs."""
    bar = config.system.to_params()
    params = bar if n_vehicles == 2 else ring_formation(bar, n_vehicles)
    central = _settings(config, "centralized", n_vehicles, backend)
    decentral = _settings(config, "decentralized", n_vehicles, backend)
    sequence = record_sequence(params, central, ticks, backend)
    central_s, _ = centralized_run(params, central, backend, sequence)
    agent_s, _ = decentralized_run(params, decentral, backend, sequence)
    layout = params.layout
    return {
        "n_vehicles": n_vehicles,
        "states": layout.n_states,
        "inputs": layout.n_inputs,
        "centralized": _figures(central_s),
        "decentralized_agent": _figures(agent_s),
    }


def with_ratios(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each row's p50s as ratios to the first row's (N = 2 when it is measured)."""
    first = rows[0]
    for row in rows:
        for label in ("centralized", "decentralized_agent"):
            row[label]["p50_ratio"] = row[label]["p50_ms"] / first[label]["p50_ms"]
    return rows


def print_table(rows: list[dict[str, Any]], backend: str, ticks: int) -> None:
    first = rows[0]["n_vehicles"]
    print(f"MPC tick against N ({backend}, {ticks} ticks; ratios of p50 against N = {first})")
    print(
        f"  {'N':>2s} {'states':>6s} {'inputs':>6s}   "
        f"{'centralized p50/p99 ms':>22s} {'ratio':>6s}   "
        f"{'one agent p50/p99 ms':>20s} {'ratio':>6s}"
    )
    for row in rows:
        c, d = row["centralized"], row["decentralized_agent"]
        print(
            f"  {row['n_vehicles']:2d} {row['states']:6d} {row['inputs']:6d}   "
            f"{c['p50_ms']:10.3f} / {c['p99_ms']:9.3f} {c['p50_ratio']:6.2f}   "
            f"{d['p50_ms']:8.3f} / {d['p99_ms']:9.3f} {d['p50_ratio']:6.2f}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", default="2,3,4,6,8", help="comma-separated N (2 to 8)")
    parser.add_argument("--ticks", type=int, default=300, help="ticks per sequence")
    parser.add_argument("--backend", default="hpipm", help="the QP back-end of both MPCs")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    vehicles = [int(n) for n in args.vehicles.split(",")]
    config = load_config(CONFIG_DIR / "sim.toml")
    rows = []
    with threadpool_limits(limits=1):  # as the flight process runs (supervisor/runtime/cpu.py)
        for n in vehicles:
            if not args.json:
                print(f"  N = {n} …", file=sys.stderr, flush=True)
            rows.append(measure(config, n, args.ticks, args.backend))
    rows = with_ratios(rows)
    if args.json:
        print(json.dumps({"backend": args.backend, "ticks": args.ticks, "rows": rows}))
    else:
        print_table(rows, args.backend, args.ticks)
    return 0


if __name__ == "__main__":
    sys.exit(main())
