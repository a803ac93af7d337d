"""MPC tick benchmark: every QP back-end on the same closed-loop-like sequence.

The sequence is recorded once: the centralized MPC flies the controllers' nonlinear model
from a perturbed start (0.4 m, 30° bar-yaw and UAV-yaw errors, the bar swinging in yaw so
every yaw angle changes every tick, θ_l switching between 0° and 20°, and a gust every
2 s that spins both UAVs so the torques saturate). Each back-end
then replays the same states and references from a fresh controller and is timed over the
full tick (equilibria, model update, QP data, solve, extracting u*). Accuracy is the
largest input difference to the exact active-set solver (DAQP), relative to the actuator
range; speed ratios are against OSQP measured in the same run.

Run: ``python -m benchmarks.mpc [--ticks N] [--json]`` or ``uavbar-supervisor bench``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from controllers.formation_equilibria import (
    FormationReference,
    agent_equilibrium,
    formation_equilibrium,
)
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from controllers.mpc import CentralizedMpc, DecentralizedMpc, agent_state, measured_yaws
from controllers.params import MpcSettings
from controllers.qp.registry import BACKEND_NAMES
from supervisor.app.config_files import DEFAULT_SETUP

DEFAULT_CONFIG = DEFAULT_SETUP
REFERENCE_BACKEND = "daqp"
BASELINE_BACKEND = "osqp"
Sequence = list[tuple[np.ndarray, FormationReference]]


def record_sequence(
    params: FormationParams, settings: MpcSettings, ticks: int, backend: str = REFERENCE_BACKEND
) -> Sequence:
    """States and references of a closed loop on the nonlinear model (RK4, 4 substeps),
    flown by the centralized MPC on ``backend``."""
    controller = CentralizedMpc(params, settings, backend, clock=time.perf_counter)
    f = FormationModel(params).dynamics
    layout = params.layout
    n = layout.n_vehicles
    # UAV i starts 0.5 rad off the bar's 30° yaw, alternately either way.
    start_yaws = tuple(0.5 * (-1.0) ** (i - 1) for i in layout.vehicles)
    start = FormationReference((0.4, -0.2, 1.2), math.radians(30), start_yaws)
    x = formation_equilibrium(params, start).x
    h = settings.dt_s / 4
    out: Sequence = []
    for k in range(ticks):
        yaw = 0.6 * math.sin(2 * math.pi * k / 400)  # ~0.2 rad/s: every yaw moves every tick
        reference = FormationReference(
            (0.0, 0.0, 1.0), yaw, (yaw,) * n, math.radians(20) * (k // 250 % 2)
        )
        if k % 100 == 50:  # a gust spins every UAV, alternately: the torques saturate a while
            for i in layout.vehicles:
                x[layout.uav_slices(i)[3]] += np.array((3.0, -3.0, 2.0)) * (-1.0) ** (i - 1)
        out.append((x.copy(), reference))
        u = controller.step(x, reference, k * settings.dt_s).u
        for _ in range(4):
            k1 = np.asarray(f(x, u)).ravel()
            k2 = np.asarray(f(x + h / 2 * k1, u)).ravel()
            k3 = np.asarray(f(x + h / 2 * k2, u)).ravel()
            k4 = np.asarray(f(x + h * k3, u)).ravel()
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return out


def _time_ticks(tick: Callable[[int], np.ndarray], ticks: int) -> tuple[np.ndarray, np.ndarray]:
    durations, inputs = [], []
    for k in range(ticks):
        start = time.perf_counter()
        u = tick(k)
        durations.append(time.perf_counter() - start)
        inputs.append(u)
    return np.array(durations), np.array(inputs)


def centralized_run(
    params: FormationParams, settings: MpcSettings, backend: str, seq: Sequence
) -> tuple[np.ndarray, np.ndarray]:
    controller = CentralizedMpc(params, settings, backend, clock=time.perf_counter)
    return _time_ticks(lambda k: controller.step(seq[k][0], seq[k][1], 0.02 * k).u, len(seq))


def decentralized_run(
    params: FormationParams, settings: MpcSettings, backend: str, seq: Sequence
) -> tuple[np.ndarray, np.ndarray]:
    """UAV 1's agent alone: its full tick from the formation's state to its u*, as on a
    computer of its own (its own part of the equilibria, not the formation's)."""
    agent = DecentralizedMpc(params, settings, backend, clock=time.perf_counter).agents[0]

    def tick(k: int) -> np.ndarray:
        state, reference = seq[k]
        eq = agent_equilibrium(params, reference, 1)
        turned = reference.with_yaws(*measured_yaws(state, params.layout))
        lin = agent_equilibrium(params, turned, 1)
        result = agent.solve(agent_state(state, params, 1), eq, agent.linearize(lin))
        if isinstance(result, str):
            return np.full(4, np.nan)
        u: np.ndarray = result[0][0]
        return u

    return _time_ticks(tick, len(seq))


def summarize(
    durations: np.ndarray, inputs: np.ndarray, reference: np.ndarray, scale: np.ndarray
) -> dict[str, float]:
    ms = durations * 1e3
    return {
        "p50_ms": float(np.median(ms)),
        "p99_ms": float(np.percentile(ms, 99)),
        "max_ms": float(ms.max()),
        "max_err": float(np.nanmax(np.abs(inputs - reference) / scale))
        if np.all(np.isfinite(inputs))
        else math.inf,
    }


def run_benchmark(
    config_path: Path, ticks: int, backends: tuple[str, ...] = BACKEND_NAMES, progress: bool = True
) -> dict[str, object]:
    """The benchmark's result object (see the module docstring)."""
    from supervisor.app.config import load_config  # benchmarks may use the service's config loader

    config = load_config(config_path)
    params = config.system.to_params()
    # The real-time budget is the service's concern; here every solve is kept and timed.
    central = dataclasses.replace(config.mpc_settings("centralized"), late_after_s=math.inf)
    decentral = dataclasses.replace(config.mpc_settings("decentralized"), late_after_s=math.inf)
    lim = central.limits
    per_uav = np.array([lim.thrust_max_n - lim.thrust_min_n] + [2 * lim.torque_max_nm] * 3)
    sequence = record_sequence(params, central, ticks)
    result: dict[str, object] = {}
    saturated_ticks: dict[str, int] = {}
    for label, run, scale, settings in (
        ("centralized", centralized_run, np.tile(per_uav, params.n_vehicles), central),
        ("decentralized", decentralized_run, per_uav, decentral),
    ):
        ordered = [REFERENCE_BACKEND] + [b for b in backends if b != REFERENCE_BACKEND]
        outcomes = {}
        for backend in ordered:
            if progress:
                print(f"  {label:13s} {backend:6s} …", file=sys.stderr, flush=True)
            outcomes[backend] = run(params, settings, backend, sequence)
        reference_inputs = outcomes[REFERENCE_BACKEND][1]
        torques = reference_inputs[:, [i for i in range(reference_inputs.shape[1]) if i % 4]]
        saturated_ticks[label] = int(
            np.sum(np.any(np.isclose(np.abs(torques), lim.torque_max_nm, atol=1e-6), axis=1))
        )
        table = {b: summarize(d, u, reference_inputs, scale) for b, (d, u) in outcomes.items()}
        baseline = table.get(BASELINE_BACKEND, {}).get("p50_ms")
        for entry in table.values():
            entry["speedup_vs_osqp"] = baseline / entry["p50_ms"] if baseline else math.nan
        result[label] = table
    central_table = result["centralized"]
    assert isinstance(central_table, dict)
    robust = [b for b in backends if central_table[b]["max_err"] <= 1e-4]
    result["default"] = (
        min(robust, key=lambda b: central_table[b]["p50_ms"]) if robust else BASELINE_BACKEND
    )
    result["ticks"] = ticks
    result["saturated_ticks"] = saturated_ticks
    if "hpipm" in backends:
        from controllers.qp.hpipm import library_build  # loads libhpipm only when benched

        result["hpipm_build"] = library_build()
    return result


def print_table(result: dict[str, object]) -> None:
    for label in ("centralized", "decentralized"):
        table = result[label]
        saturated = result["saturated_ticks"]
        assert isinstance(table, dict) and isinstance(saturated, dict)
        print(f"{label} ({result['ticks']} ticks, {saturated[label]} with a saturated torque)")
        header = ("p50 ms", "p99 ms", "max ms", "max err", "vs osqp")
        print(f"  {'backend':8s} " + " ".join(f"{h:>8s}" for h in header))
        for backend, row in table.items():
            print(
                f"  {backend:8s} {row['p50_ms']:8.3f} {row['p99_ms']:8.3f} {row['max_ms']:8.3f}"
                f" {row['max_err']:10.2e} {row['speedup_vs_osqp']:7.1f}x"
            )
    print(f"default (fastest with max err ≤ 1e-4 on the centralized problem): {result['default']}")
    if "hpipm_build" in result:
        print(f"HPIPM's BLASFEO build: {result['hpipm_build']}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The benchmark's options (shared with ``uavbar-supervisor bench``)."""
    parser.add_argument("--ticks", type=int, default=600, help="ticks in the sequence (≥ 500)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--backends",
        default=",".join(BACKEND_NAMES),
        help=f"comma-separated subset of {', '.join(BACKEND_NAMES)}",
    )


def run(config_path: Path, ticks: int, backends_csv: str, as_json: bool) -> int:
    """Run, then print the table or the JSON object; returns the exit status."""
    backends = tuple(b.strip() for b in backends_csv.split(",") if b.strip())
    unknown = [b for b in backends if b not in BACKEND_NAMES]
    if unknown or ticks < 1:
        print(f"bench: unknown back-end(s) {unknown} or --ticks < 1", file=sys.stderr)
        return 2
    # BLAS pinned to one thread (docs/reference/qp-solvers.md: 10x slower p50 otherwise on
    # two cores).
    with threadpool_limits(limits=1):
        result = run_benchmark(config_path, ticks, backends, progress=not as_json)
    if as_json:
        print(json.dumps(result))
    else:
        print_table(result)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="setup file")
    args = parser.parse_args(argv)
    return run(args.config, args.ticks, args.backends, args.json)


if __name__ == "__main__":
    sys.exit(main())
