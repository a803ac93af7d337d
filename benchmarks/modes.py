"""The closed loops' slowest modes: how fast each MPC damps the bar system's motions.

At a few equilibria of the lab's setup (hover; bar and UAVs turned with the cables tilted
by θ_l = 20°; the paper's θ_l = 45° pose), the plant's Jacobian discretized exactly and
each controller's gain probed from its own ``step`` (controllers/linear_modes.py) give the
closed loop's modes; the three slowest physical ones are printed per controller (the
decentralized one also with the reference lead beyond the paper, ``ReferenceLead``), with
the share of the bar's yaw in each. A magnitude above 1 grows.

Run: ``python -m benchmarks.modes [--config PATH] [--json]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from controllers.formation_equilibria import FormationReference
from controllers.linear_modes import PAYLOAD_YAW_MOTION, physical_closed_loop_modes
from controllers.mpc import CentralizedMpc, DecentralizedMpc
from controllers.params import RECOMMENDED_LEAD, ReferenceLead
from supervisor.app.config_files import CONFIG_DIR

DEFAULT_CONFIG = CONFIG_DIR / "kth_sml.toml"
# The lab's two UAVs.
EQUILIBRIA = {
    "hover": FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0)),
    "theta_l 20°, turned": FormationReference((0.5, -0.3, 1.2), 0.8, (0.8, 1.4), math.radians(20)),
    "theta_l 45°": FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0), math.pi / 4),
}
SHOWN = 3


def slowest_modes(config_path: Path) -> dict[str, dict[str, list[dict[str, float]]]]:
    """{controller: {equilibrium: [mode, ...]}} with the slowest physical modes first
    (each conjugate pair once)."""
    from supervisor.app.config import load_config  # benchmarks may use the service's loader

    config = load_config(config_path)
    params = config.system.to_params()
    result: dict[str, dict[str, list[dict[str, float]]]] = {}
    controllers = (
        ("centralized", CentralizedMpc, ReferenceLead()),
        ("decentralized", DecentralizedMpc, ReferenceLead()),
        ("decentralized with reference lead", DecentralizedMpc, RECOMMENDED_LEAD),
    )
    for name, cls, lead in controllers:
        settings = dataclasses.replace(
            config.mpc_settings("centralized" if cls is CentralizedMpc else "decentralized"),
            late_after_s=math.inf,
            reference_lead=lead,
        )
        result[name] = {}
        for label, reference in EQUILIBRIA.items():
            controller = cls(params, settings, "daqp", clock=time.perf_counter)
            modes = physical_closed_loop_modes(controller, params, reference)
            rows: list[dict[str, float]] = []
            for mode in modes:
                row = {
                    "magnitude": mode.magnitude,
                    "frequency_hz": mode.frequency_hz,
                    "growth_per_s": mode.growth_per_s(settings.dt_s),
                    "bar_yaw_share": float(np.linalg.norm(mode.shape[list(PAYLOAD_YAW_MOTION)])),
                }
                conjugate = (
                    bool(rows)
                    and row["frequency_hz"] > 0
                    and math.isclose(row["magnitude"], rows[-1]["magnitude"], rel_tol=1e-9)
                )
                if not conjugate:
                    rows.append(row)
                if len(rows) == SHOWN:
                    break
            result[name][label] = rows
    return result


def print_table(result: dict[str, dict[str, list[dict[str, float]]]]) -> None:
    for name, table in result.items():
        print(f"{name}: slowest physical modes (|λ| per 20 ms tick, frequency, growth, yaw share)")
        for label, rows in table.items():
            cells = "  ".join(
                f"{r['magnitude']:.5f} {r['frequency_hz']:4.2f} Hz"
                f" {100 * r['growth_per_s']:+5.1f} %/s yaw {r['bar_yaw_share']:.2f}"
                for r in rows
            )
            print(f"  {label:22s} {cells}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help="setup file")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    result = slowest_modes(args.config)
    if args.json:
        print(json.dumps(result))
    else:
        print_table(result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
