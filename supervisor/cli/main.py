"""The ``uavbar-supervisor`` command line.

Building the parser imports the standard library only, and the terminal client's commands
import nothing more than httpx (``supervisor.cli.client``): the service stack, the
controllers and the simulator are imported by the commands that use them, when they run.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from supervisor.app.config_files import (
    DEFAULT_SETUP,
    ConfigError,
    setup_path,
    shipped_scenarios,
    shipped_setups,
)
from supervisor.cli.client import CONTROLLERS, add_client_commands
from supervisor.cli.fleet_certs import add_fleet_certs_command
from supervisor.cli.keys import add_keys_command
from supervisor.cli.parsing import PROG, Parser, VersionAction, finite_float
from supervisor.cli.usage import EXIT_USAGE, UsageError

if TYPE_CHECKING:
    from supervisor.app.config import Config

EXIT_INTERRUPTED = 130

DESCRIPTION = """\
Flight supervisor for PX4 quadrotors carrying a payload under model predictive control:
the service (serve), its terminal client, the fast simulator and the tools around them.

Units: metres, degrees and seconds on the command line (named in each option: --yaw-deg,
--hold-s); the REST API takes SI units and radians."""

EPILOG = """\
examples:
  uavbar-supervisor serve                          # the embedded simulator, dashboard on :8000
  uavbar-supervisor serve --set api.port=8131      # another port; the client finds it
  uavbar-supervisor takeoff --wait                 # exit 0 once hovering
  uavbar-supervisor setpoint 0.5 0 1.2 --yaw-deg 20 --wait
  uavbar-supervisor path square.toml --wait        # waypoints in a TOML file (path --help)
  uavbar-supervisor land --wait
  uavbar-supervisor simulate --scenario paper --controller decentralized
  uavbar-supervisor config show --config kth_sml

exit status: 0 done, 1 refused or failed (the reason is printed), 2 a usage or setup
error (nothing was done), 3 the service cannot be reached.

environment: UAVBAR_TOKEN (the API token), UAVBAR_URL (the service's address).

Each command has its own --help."""


def _add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        metavar="PATH|NAME",
        help="setup file, or the name of a shipped setup "
        f"({', '.join(shipped_setups())}; default: {DEFAULT_SETUP.stem})",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override one setting; VALUE is a TOML literal (repeatable)",
    )


def _setup_path(args: argparse.Namespace) -> Path:
    return setup_path(args.config) if args.config is not None else DEFAULT_SETUP


def _config(args: argparse.Namespace) -> Config:
    from supervisor.app.config import load_config

    return load_config(_setup_path(args), args.overrides)


def _logging() -> None:
    from supervisor.logs.logging_setup import configure_logging

    configure_logging()


def _equilibria(args: argparse.Namespace) -> int:
    import json
    import math

    from controllers.equilibria import EquilibriumError
    from controllers.formation_equilibria import FormationReference, formation_equilibrium
    from supervisor.flight.equilibrium_summary import equilibrium_summary

    config = _config(args)
    theta_l_deg: float = args.theta_l_deg
    if not 0.0 <= theta_l_deg < 90.0:
        raise UsageError(f"--theta-l-deg {theta_l_deg}: must lie in [0, 90) degrees")
    params = config.system.to_params()
    try:
        result = equilibrium_summary(params, math.radians(theta_l_deg), config.setpoint_bounds())
    except EquilibriumError as error:
        raise UsageError(str(error)) from error
    layout = params.layout
    eq = formation_equilibrium(
        params,
        FormationReference((0.0, 0.0, 0.0), 0.0, (0.0,) * layout.n_vehicles, result["theta_l"]),
    )
    theta_f = result["theta_f"]
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"setup {config.name}: θ_l = {theta_l_deg:.2f}° (bar along x, yaw 0, centre at origin)")
    print(f"  θ_f (Proposition 1)  {math.degrees(theta_f):8.4f}°  ({theta_f:.6f} rad)")
    for i in layout.vehicles:
        x, y, z = eq.uav_position(i)
        tilt_deg = math.degrees(eq.tilts_rad[i - 1])
        print(
            f"  UAV {i}: thrust {eq.thrusts_n[i - 1]:7.3f} N, tilt θ_f {tilt_deg:7.3f}°,"
            f" cable {math.degrees(eq.cable_angles_rad[i - 1]):6.2f}°"
            f" T = {eq.tensions_n[i - 1]:6.3f} N, position ({x:+.4f}, {y:+.4f}, {z:+.4f}) m"
        )
    if not params.is_symmetric:
        print("  (asymmetric setup: per-cable angles from the general static equilibrium)")
    for refusal in result["refusals"]:
        print(f"  refused as a setpoint: {refusal}")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from benchmarks.mpc import run as run_mpc_benchmark
    from controllers.qp.registry import BACKEND_NAMES

    _config(args)  # a bad setup stops here, with its key named
    backends = args.backends or ",".join(BACKEND_NAMES)
    return run_mpc_benchmark(_setup_path(args), args.ticks, backends, args.json)


def _simulate(args: argparse.Namespace) -> int:
    import tempfile

    import pydantic_core

    from supervisor.cli.console import SimulationProgress, format_summary
    from supervisor.logs.flight_log import SUFFIXES, read_flight_log
    from supervisor.logs.report import summarize
    from supervisor.runtime.cpu import single_threaded_blas
    from supervisor.simulate.closed_loop import result_summary, run_scenario
    from supervisor.simulate.scenarios import load_scenario, scenario_duration_s

    config = _config(args)
    scenario = load_scenario(args.scenario)
    if args.seed is not None and args.seed < 0:
        raise UsageError(f"--seed {args.seed}: must be >= 0")
    if args.log is not None and args.log.suffix not in SUFFIXES:
        raise UsageError(f"--log {args.log}: a flight log is .jsonl or .mcap (the format)")
    _logging()
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


def _serve(args: argparse.Namespace) -> int:
    from supervisor.app.serve import run_serve  # the service stack only when serving

    _config(args)  # a bad setup stops here, before anything starts
    _logging()
    return run_serve(_setup_path(args), args.overrides)


def _agent(args: argparse.Namespace) -> int:
    import os

    from supervisor.app.agent_main import AgentStart, run_agent_process
    from supervisor.app.config import TOKEN_ENV, ConfigError, check_fleet_endpoints

    config = _config(args)
    n = config.system.n_vehicles
    if not 1 <= args.vehicle <= n:
        raise ConfigError(f"--vehicle: 1 … {n} (this setup's UAVs), got {args.vehicle}")
    token = config.api.token or os.environ.get(TOKEN_ENV)
    if not token:
        raise ConfigError(
            f"an agent takes commands only with its ground station's token: set {TOKEN_ENV} "
            "or api.token to serve's"
        )
    endpoints = config.agents.agent_endpoints or []
    listen = args.listen or endpoints[args.vehicle - 1 : args.vehicle]
    peers = [e for i, e in enumerate(endpoints, start=1) if i != args.vehicle]
    connect = args.connect or [config.agents.ground_endpoint, *peers]
    try:
        check_fleet_endpoints([*listen, *connect], config.agents.tls_folder)
    except ValueError as error:
        raise ConfigError(f"--listen/--connect: {error}") from None
    _logging()
    return run_agent_process(config, AgentStart(args.vehicle, tuple(listen), tuple(connect), token))


def _sitl(args: argparse.Namespace) -> int:
    from supervisor.app.world_process import run_sitl

    config = _config(args)
    _logging()
    return run_sitl(config)


def _report(args: argparse.Namespace) -> int:
    from supervisor.logs.flight_log import read_flight_log
    from supervisor.logs.report import write_report

    paths: list[Path] = args.logs
    if len(paths) > 2:
        raise UsageError("report takes one or two logs")
    try:
        logs = [read_flight_log(path) for path in paths]
    except (OSError, ValueError) as error:
        raise UsageError(str(error)) from error
    for log in logs:
        if not len(log.t_s):
            raise UsageError(f"{log.path}: no tick logged (the flight never started): no report")
    try:
        written = write_report(logs, args.out)
    except ValueError as error:  # logs of two different formations
        raise UsageError(str(error)) from error
    for path in written:
        print(path)
    return 0


def _csv(args: argparse.Namespace) -> int:
    from supervisor.logs.csv_export import write_csv
    from supervisor.logs.flight_log import read_flight_log

    out: Path = args.out or args.log.with_suffix(".csv")
    try:
        rows = write_csv(read_flight_log(args.log), out)
    except (OSError, ValueError) as error:
        raise UsageError(str(error)) from error
    print(f"{out}: {rows} ticks")
    return 0


def _mocap(args: argparse.Namespace) -> int:
    from supervisor.app.mocap_recording import run_record, run_replay

    if args.action == "record":
        if not args.duration > 0:
            raise UsageError(f"--duration {args.duration}: must be > 0 (seconds)")
        return run_record(args.host, args.port, args.duration, args.out, _say)
    from mocap.recording import read_recording, truncation_warning

    if not args.file.is_file():
        raise UsageError(f"{args.file}: no such recording")
    try:
        recording = read_recording(args.file)
    except ValueError as error:
        raise UsageError(str(error)) from error
    if not recording.packets:
        raise UsageError(f"{args.file}: holds no packet: nothing to replay")
    # A recording cut short is what a killed or disk-starved recorder leaves: what it holds
    # is still the stream as it came, so it is served, and the operator told where it ends.
    warning = truncation_warning(args.file, recording)
    if warning is not None:
        _warn(args, f"{warning}; replaying what it holds")
    return run_replay(args.file, args.host, args.port, args.loop, _say)


def _mocap_check(args: argparse.Namespace) -> int:
    from mocap.recording import truncation_warning
    from supervisor.app.assembly import body_names_from_config, fusion_from_config
    from supervisor.logs.flight_log import mocap_recording_path, read_flight_log
    from supervisor.logs.mocap_replay import check_flight, describe, flight_recording

    config = _config(args)
    try:
        log = read_flight_log(args.log)
        recording = flight_recording(log)
        _, comparison = check_flight(
            log,
            fusion_from_config(config),
            body_names_from_config(config),
            args.tolerance,
            recording,
        )
    except (OSError, ValueError) as error:
        raise UsageError(str(error)) from error
    # A recording cut short (a killed flight process) still checks the ticks before its
    # end; refusing it would leave unchecked the flights that ended worst.
    warning = truncation_warning(mocap_recording_path(log.path), recording)
    if warning is not None:
        _warn(args, f"{warning}; comparing the ticks before its end only")
    print(describe(args.log, comparison))
    return 0 if comparison.same else 1


def _warn(args: argparse.Namespace, line: str) -> None:
    print(f"{PROG} {args.command}: warning: {line}", file=sys.stderr, flush=True)


def _say(line: str) -> None:
    print(line, flush=True)


def _config_command(args: argparse.Namespace) -> int:
    from supervisor.cli.config_show import show_config

    return show_config(_setup_path(args), args.overrides, args.json)


def _keys(args: argparse.Namespace) -> int:
    from supervisor.cli.keys import make_keys

    return make_keys(_config(args), args)


def _fleet_certs(args: argparse.Namespace) -> int:
    from supervisor.cli.fleet_certs import make_fleet_certificates

    return make_fleet_certificates(_config(args), args)


Handler = Callable[[argparse.Namespace], int]


def _add_commands(commands: argparse._SubParsersAction[Parser]) -> None:
    eq = commands.add_parser(
        "equilibria",
        help="equilibrium of the bar system for a cable angle θ_l",
        description="The static equilibrium (Proposition 1) of the setup for a cable angle.",
        epilog="example:\n  uavbar-supervisor equilibria --theta-l-deg 45",
    )
    eq.add_argument(
        "--theta-l-deg",
        "--theta-l",
        type=finite_float,
        required=True,
        metavar="DEG",
        help="cable angle θ_l [°], in [0, 90)",
    )
    eq.add_argument("--json", action="store_true", help="print one JSON object")
    eq.set_defaults(handler=_equilibria)

    bench = commands.add_parser(
        "bench",
        help="time every QP back-end on the same MPC ticks",
        description="Time every QP back-end on the same closed-loop-like MPC ticks.",
        epilog="example:\n  uavbar-supervisor bench --ticks 600 --backends hpipm,osqp",
    )
    bench.add_argument(
        "--ticks", type=int, default=600, metavar="N", help="ticks in the sequence (default: 600)"
    )
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.add_argument(
        "--backends", metavar="A,B", help="comma-separated subset (default: every back-end)"
    )
    bench.set_defaults(handler=_bench)

    serve = commands.add_parser(
        "serve",
        help="the flight supervisor service (default setup: the embedded simulator)",
        description="The flight supervisor: API and dashboard, flight process, mocap relay "
        "(and the simulated world with sim.embedded). Ctrl-C lands whatever is airborne, "
        "then stops.",
        epilog="examples:\n  uavbar-supervisor serve\n"
        "  uavbar-supervisor serve --set api.port=8131\n"
        "  uavbar-supervisor serve --config kth_sml --set 'vehicles.bind_host=\"192.168.1.20\"'",
    )
    serve.set_defaults(handler=_serve)
    agent = commands.add_parser(
        "agent",
        help="one vehicle's agent: its link, its decentralized MPC, over Zenoh",
        description="One vehicle's agent (docs/agents.md): its MAVLink link, its own QTM "
        "client and decentralized MPC, its safety monitors; commands come from the ground "
        "station (serve with agents.enabled) over Zenoh, with the API token (UAVBAR_TOKEN). "
        "SIGTERM or Ctrl-C lands its vehicle's part first.",
        epilog="example (beyond loopback over TLS: uavbar-supervisor fleet-certs):\n"
        "  UAVBAR_TOKEN=... uavbar-supervisor agent --vehicle 2 --config lab "
        "--set 'agents.tls_folder=\"/etc/uavbar/fleet\"' "
        "--connect tls/192.168.1.20:7447 --listen tls/192.168.1.32:7448",
    )
    agent.add_argument("--vehicle", type=int, required=True, metavar="I", help="its UAV (1 … N)")
    agent.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="a Zenoh endpoint to join (repeatable; default: agents.ground_endpoint and "
        "the other agents' agent_endpoints)",
    )
    agent.add_argument(
        "--listen",
        action="append",
        metavar="ENDPOINT",
        help="where its peers reach it (default: its agents.agent_endpoints entry)",
    )
    agent.set_defaults(handler=_agent)
    sitl = commands.add_parser(
        "sitl",
        help="the simulated world alone, in real time: plant, a PX4 per UAV, a QTM server",
        description="The simulated world alone, in real time: physics plant, a PX4 per UAV "
        "(MAVLink on UDP 14580+i to 14540+i), a QTM RT server on TCP 22223.",
    )
    sitl.set_defaults(handler=_sitl)

    simulate = commands.add_parser(
        "simulate",
        help="fly a scenario on the embedded simulator, faster than real time",
        description="Fly a scenario through the service's tick core against the physics "
        "plant, on simulated time.",
        epilog="example:\n  uavbar-supervisor simulate --scenario paper --controller "
        "decentralized --log flight.mcap",
    )
    simulate.add_argument(
        "--scenario",
        required=True,
        metavar="NAME|PATH",
        help=f"a shipped scenario ({', '.join(shipped_scenarios())}) or a scenario file",
    )
    simulate.add_argument(
        "--controller", choices=CONTROLLERS, default="centralized", help="(default: centralized)"
    )
    simulate.add_argument(
        "--log",
        type=Path,
        metavar="PATH",
        help="write the flight log here: PATH.mcap (MCAP) or PATH.jsonl (JSON Lines)",
    )
    simulate.add_argument(
        "--seed", type=int, metavar="N", help="noise seed (default: the setup's sim.seed)"
    )
    simulate.add_argument("--json", action="store_true", help="print one JSON object")
    simulate.set_defaults(handler=_simulate)

    report = commands.add_parser(
        "report",
        help="figures (Figs 6-8) and a Table III summary of flight logs",
        description="Figures like the paper's Figs 6-8 and a Table III summary of one "
        "flight log, or two overlaid.",
        epilog="example:\n  uavbar-supervisor report flight-logs/flight-20261123-031500.mcap "
        "--out report/",
    )
    report.add_argument(
        "logs",
        nargs="+",
        type=Path,
        metavar="LOG",
        help="one log (.jsonl or .mcap), or two to overlay",
    )
    report.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    report.set_defaults(handler=_report)

    export = commands.add_parser(
        "csv",
        help="a flight log as one CSV table (PlotJuggler, spreadsheets)",
        description="Write a flight log (.jsonl or .mcap) as CSV: a row per tick, t_s first, "
        "then the state, the reference and the inputs by name, the timings, mode, "
        "controller and plan status; a value that was not finite is an empty cell.",
        epilog="example:\n  uavbar-supervisor csv flight-logs/flight-20261123-031500.mcap",
    )
    export.add_argument("log", type=Path, metavar="LOG", help="a .jsonl or .mcap flight log")
    export.add_argument(
        "--out", type=Path, metavar="FILE", help="the CSV file (default: LOG with .csv)"
    )
    export.set_defaults(handler=_csv)

    mocap = commands.add_parser(
        "mocap",
        help="record a QTM RT stream to a file, or serve a recording as a QTM RT server",
        description="Record a QTM RT stream (a real QTM or the simulator) with every "
        "packet's arrival time, or replay a recording as a QTM RT server (TCP commands, "
        "UDP or TCP frames, the recorded timing) for the supervisor or Qualisys' SDK.",
        epilog="examples:\n  uavbar-supervisor mocap record --host 192.168.1.10 --port 22223 "
        "--duration 20 --out hover.qtm.gz\n"
        "  uavbar-supervisor mocap replay hover.qtm.gz --port 22223 --loop\n"
        "  uavbar-supervisor mocap check flight-logs/flight-20261203-101500.mcap",
    )
    mocap_actions = mocap.add_subparsers(dest="action", required=True, metavar="ACTION")
    record = mocap_actions.add_parser("record", help="record a stream into a file")
    record.add_argument("--host", default="127.0.0.1", help="QTM's address (default: loopback)")
    record.add_argument("--port", type=int, default=22223, help="QTM's little-endian port")
    record.add_argument("--duration", type=float, required=True, metavar="S", help="how long [s]")
    record.add_argument("--out", type=Path, required=True, metavar="FILE", help="the recording")
    record.set_defaults(handler=_mocap)
    replay = mocap_actions.add_parser("replay", help="serve a recording as a QTM RT server")
    replay.add_argument("file", type=Path, metavar="FILE", help="a recording (mocap record)")
    replay.add_argument(
        "--port", type=int, default=22223, help="the TCP port to serve on (default 22223)"
    )
    replay.add_argument("--host", default="127.0.0.1", help="the address to serve on")
    replay.add_argument("--loop", action="store_true", help="start over at the end, until stopped")
    replay.set_defaults(handler=_mocap)
    check = mocap_actions.add_parser(
        "check",
        help="replay a flight's own mocap recording and compare the estimates with its log",
        description="Replay the mocap the flight process recorded during a flight "
        "(flight-….qtm.gz beside the log) on the flight's own clock through today's "
        "receiver and fusion, and compare the estimate at every tick with the log's "
        "(exit 1 if any differs by more than --tolerance). --config: the flight's setup.",
    )
    check.add_argument("log", type=Path, metavar="LOG", help="a flight log (.mcap or .jsonl)")
    check.add_argument(
        "--tolerance", type=float, default=1e-9, help="largest difference taken as the same"
    )
    _add_config_options(check)
    check.set_defaults(handler=_mocap_check)

    config = commands.add_parser(
        "config",
        help="print the effective configuration, each key with its source",
        description="Print the effective configuration (the setup file, the files it "
        "extends, --set overrides and the defaults), each key with where it came from.",
        epilog="examples:\n  uavbar-supervisor config show\n"
        "  uavbar-supervisor config show --config kth_sml --set api.port=8131",
    )
    config.add_argument("action", choices=("show",), help="what to do (show)")
    config.add_argument("--json", action="store_true", help="print one JSON object")
    config.set_defaults(handler=_config_command)

    add_client_commands(commands)
    add_keys_command(commands, _keys)
    add_fleet_certs_command(commands, _fleet_certs)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand."""
    parser = Parser(prog=PROG, description=DESCRIPTION, epilog=EPILOG)
    parser.add_argument("--version", action=VersionAction)
    commands = parser.add_subparsers(
        dest="command", required=True, metavar="COMMAND", parser_class=Parser
    )
    _add_commands(commands)
    for sub in commands.choices.values():
        _add_config_options(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the console script; returns the exit status."""
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as done:  # --help, --version, or a usage error already printed
        return done.code if isinstance(done.code, int) else EXIT_USAGE
    handler: Handler = args.handler
    try:
        return handler(args)
    except (ConfigError, UsageError) as error:
        print(f"{PROG} {args.command}: {error}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{PROG} {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # `status | head -1`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
