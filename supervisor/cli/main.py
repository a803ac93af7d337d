"""``uavbar-supervisor``: the command line.

Every command takes ``--config PATH`` (default: the embedded simulator's setup) and repeated
``--set section.key=value``. A bad setup or argument prints one clear message and exits
with status 2 before anything runs.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

import pydantic_core

from benchmarks.mpc import add_arguments as _bench_arguments
from benchmarks.mpc import run as run_mpc_benchmark
from controllers.equilibria import EquilibriumError, Reference, bar_equilibrium
from supervisor.app.config import CONFIG_DIR, Config, ConfigError, load_config
from supervisor.cli.client import add_client_commands
from supervisor.cli.console import SimulationProgress, format_summary
from supervisor.cli.keys import add_keys_command
from supervisor.cli.usage import UsageError
from supervisor.flight.core import CONTROLLERS
from supervisor.flight.equilibrium_summary import equilibrium_summary
from supervisor.logs.flight_log import read_flight_log
from supervisor.logs.logging_setup import configure_logging
from supervisor.logs.report import summarize, write_report
from supervisor.runtime.cpu import single_threaded_blas
from supervisor.simulate.closed_loop import result_summary, run_scenario
from supervisor.simulate.scenarios import available_scenarios, load_scenario, scenario_duration_s

DEFAULT_CONFIG = CONFIG_DIR / "sim.toml"

EXIT_USAGE = 2


def _add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        type=Path,
        default=DEFAULT_CONFIG,
        metavar="PATH",
        help=f"setup file (default: {DEFAULT_CONFIG.relative_to(CONFIG_DIR.parent)})",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one setting; VALUE is a TOML literal (repeatable)",
    )


def _equilibria(config: Config, args: argparse.Namespace) -> int:
    theta_l_deg: float = args.theta_l
    if not (math.isfinite(theta_l_deg) and 0.0 <= theta_l_deg < 90.0):
        raise UsageError(f"--theta-l {theta_l_deg}: must lie in [0, 90) degrees")
    params = config.system.to_params()
    try:
        result = equilibrium_summary(params, math.radians(theta_l_deg))
    except EquilibriumError as error:
        raise UsageError(str(error)) from error
    eq = bar_equilibrium(params, Reference((0.0, 0.0, 0.0), 0.0, (0.0, 0.0), result["theta_l"]))
    theta_f = result["theta_f"]
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"setup {config.name}: θ_l = {theta_l_deg:.2f}° (bar along x, yaw 0, centre at origin)")
    print(f"  θ_f (Proposition 1)  {math.degrees(theta_f):8.4f}°  ({theta_f:.6f} rad)")
    for k in range(2):
        x, y, z = eq.uav_position(k + 1)
        tilt_deg = math.degrees(eq.theta_f_rad[k])
        print(
            f"  UAV {k + 1}: thrust {eq.thrusts_n[k]:7.3f} N, tilt θ_f {tilt_deg:7.3f}°,"
            f" cable {math.degrees(eq.theta_l_rad[k]):6.2f}° T = {eq.tensions_n[k]:6.3f} N,"
            f" position ({x:+.4f}, {y:+.4f}, {z:+.4f}) m"
        )
    if not params.is_symmetric:
        print("  (asymmetric setup: per-cable angles from the general static equilibrium)")
    return 0


def _bench(config: Config, args: argparse.Namespace) -> int:
    return run_mpc_benchmark(args.config, args.ticks, args.backends, args.json)


def _simulate(config: Config, args: argparse.Namespace) -> int:
    scenario = load_scenario(args.scenario)
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed {args.seed}: must be >= 0")
    single_threaded_blas()
    with tempfile.TemporaryDirectory() as scratch:
        destination = args.log or Path(scratch) / "flight.jsonl"
        with SimulationProgress(scenario_duration_s(scenario), enabled=not args.json) as progress:
            result = run_scenario(
                config, scenario, args.controller, args.seed, destination, progress.update
            )
        assert result.log_path is not None
        summary = {
            **summarize(read_flight_log(result.log_path)),
            **result_summary(result, args.controller),
        }
        if args.log is not None:
            summary["log"] = str(result.log_path)
    if args.json:
        print(pydantic_core.to_json(summary, inf_nan_mode="null").decode())
    else:
        print(format_summary(summary))
    return 0 if result.completed else 1


def _serve(config: Config, args: argparse.Namespace) -> int:
    from supervisor.app.serve import run_serve  # the service stack only when serving

    return run_serve(args.config, args.overrides)


def _sitl(config: Config, args: argparse.Namespace) -> int:
    from supervisor.app.world_process import run_sitl

    return run_sitl(config)


def _report(config: Config, args: argparse.Namespace) -> int:
    paths: list[Path] = args.logs
    if len(paths) > 2:
        raise UsageError("report takes one or two logs")
    try:
        logs = [read_flight_log(path) for path in paths]
    except (OSError, ValueError) as error:
        raise UsageError(str(error)) from error
    for path in write_report(logs, args.out):
        print(path)
    return 0


Handler = Callable[[Config, argparse.Namespace], int]


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = argparse.ArgumentParser(prog="uavbar-supervisor", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    eq = commands.add_parser(
        "equilibria", help="equilibrium of the bar system for a cable angle θ_l"
    )
    eq.add_argument(
        "--theta-l",
        type=float,
        required=True,
        metavar="DEG",
        help="cable angle θ_l, degrees in [0, 90)",
    )
    eq.add_argument("--json", action="store_true", help="print one JSON object")
    eq.set_defaults(handler=_equilibria)

    bench = commands.add_parser("bench", help="time every QP back-end on the same MPC ticks")
    _bench_arguments(bench)
    bench.set_defaults(handler=_bench)

    serve = commands.add_parser(
        "serve", help="the flight supervisor service (default setup: the embedded simulator)"
    )
    serve.set_defaults(handler=_serve)
    sitl = commands.add_parser(
        "sitl", help="the simulated world alone, in real time: plant, two PX4s, a QTM server"
    )
    sitl.set_defaults(handler=_sitl)

    simulate = commands.add_parser(
        "simulate", help="fly a scenario on the embedded simulator, faster than real time"
    )
    simulate.add_argument(
        "--scenario",
        required=True,
        metavar="NAME",
        help=f"configs/scenarios/NAME.toml or a path ({', '.join(available_scenarios())})",
    )
    simulate.add_argument("--controller", choices=CONTROLLERS, default="centralized")
    simulate.add_argument("--log", type=Path, metavar="PATH", help="write the flight log here")
    simulate.add_argument("--seed", type=int, metavar="N", help="noise seed (default sim.seed)")
    simulate.add_argument("--json", action="store_true", help="print one JSON object")
    simulate.set_defaults(handler=_simulate)

    report = commands.add_parser(
        "report", help="figures (Figs 6-8) and a Table III summary of flight logs"
    )
    report.add_argument(
        "logs", nargs="+", type=Path, metavar="LOG", help="one log, or two to overlay"
    )
    report.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    report.set_defaults(handler=_report)

    add_client_commands(commands)
    add_keys_command(commands)
    for sub in commands.choices.values():
        _add_config_options(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging()
    try:
        config = load_config(args.config, args.overrides)
        handler: Handler = args.handler
        return handler(config, args)
    except (ConfigError, UsageError) as error:
        print(f"uavbar-supervisor {args.command}: {error}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
