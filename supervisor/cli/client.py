"""The terminal client: status, arm, takeoff, land, abort, disarm, kill, mode, setpoint and
path against a running service's REST API; fault and reset for the embedded simulated world
(docs/faults.md).

It starts on the standard library (``supervisor.cli.rest_client``), so that it answers at
once; a command that reads the status loads its pydantic model then. The service is
found as ``supervisor.cli.address`` says; the token comes from ``--token`` or the
environment variable ``UAVBAR_TOKEN``. Abort and kill give the API 0.3 s, then go straight
to the flight process (``supervisor.cli.direct``). Angles are degrees here and radians in
REST. Exit status: 0 done, 1 refused or failed (the reason is printed), 2 a usage error,
3 the service cannot be reached.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from supervisor.app.config_files import TOKEN_ENV
from supervisor.cli import awaiting
from supervisor.cli.address import CA_FILE_ENV, URL_ENV, ServiceAddress, service_address
from supervisor.cli.direct import DirectPathError, direct_request
from supervisor.cli.output import (
    format_answer,
    format_detail,
    format_faults,
    format_path_answer,
    format_setpoints,
    format_status,
)
from supervisor.cli.parsing import finite_float, non_negative_float, positive_float
from supervisor.cli.path_file import FILE_FORMAT, read_path_file
from supervisor.cli.rest_client import JsonClient, UnreachableError
from supervisor.cli.usage import EXIT_REFUSED, EXIT_UNREACHABLE, UsageError
from supervisor.flight import outcomes

if TYPE_CHECKING:  # each command imports what it runs, when it runs it
    from supervisor.flight.status import Status

SIMPLE_REQUESTS = {
    "arm": "arm every vehicle (PX4's refusal is printed)",
    "takeoff": "lift the bar to 1 m above its resting height and hover",
    "land": "lower the payload, land every vehicle, disarm",
    "abort": "coordinated landing now, from any airborne mode (on the ground: disarm)",
    "disarm": "disarm every vehicle on the ground",
}
URGENT_COMMANDS = ("abort", "kill")
URGENT_HTTP_TIMEOUT_S = 0.3
HTTP_TIMEOUT_S = 10.0
# How long --wait waits by default: a take-off climbs for about 10 s, a landing from a few
# metres takes under a minute, a setpoint travels and holds; a path's is counted beyond its
# own duration and hold.
WAIT_TIMEOUT_S = {
    "arm": 15.0,
    "takeoff": 60.0,
    "land": 120.0,
    "setpoint": 120.0,
    "path": 120.0,
    "mode": 10.0,
}
CONTROLLERS = ("centralized", "decentralized")
PROBLEMS_SHOWN = 3  # of a status that does not fit: the first few fields name the mismatch


class MalformedStatusError(Exception):
    """The service's status does not fit this client's schema (exit status 1)."""


def _parse_status(body: Any) -> Status:
    """``GET /api/status``'s answer as its model; raises ``MalformedStatusError`` naming the
    fields that do not fit (missing, or a string where a number belongs)."""
    from pydantic import ValidationError

    from supervisor.flight.status import Status

    try:
        return Status.model_validate(body)
    except ValidationError as error:
        problems = error.errors(include_url=False)
        shown = format_detail(problems[:PROBLEMS_SHOWN])
        more = len(problems) - PROBLEMS_SHOWN
        raise MalformedStatusError(
            f"the service's status does not fit this client's ({shown}"
            + (f"; {more} more" if more > 0 else "")
            + "): is the service another version of uavbar-supervisor?"
        ) from None


def _token(args: argparse.Namespace) -> str | None:
    return args.token or os.environ.get(TOKEN_ENV)


def _headers(args: argparse.Namespace) -> dict[str, str]:
    token = _token(args)
    return {"Authorization": f"Bearer {token}"} if token else {}


def _unreachable(address: ServiceAddress, why: object) -> int:
    print(
        f"cannot reach the service at {address.url} ({address.found_by}): {why}; "
        f"is `uavbar-supervisor serve` running? (--url or ${URL_ENV} to name another)",
        file=sys.stderr,
    )
    return EXIT_UNREACHABLE


def _urgent_directly(address: ServiceAddress, args: argparse.Namespace, why: Exception) -> int:
    """Abort or kill through the flight process's own socket (the API did not answer)."""
    try:
        reply, took_s = direct_request(address.url, _token(args), args.command)
    except DirectPathError as error:
        return _unreachable(address, f"{why}; directly: {error}")
    print(f"the API did not answer ({why}): sent straight to the flight process", file=sys.stderr)
    if reply.get("outcome") != "ok":
        print(f"{args.command} refused: {reply.get('reason')}", file=sys.stderr)
        return EXIT_REFUSED
    answer = {**reply.get("data", {}), "direct": True, "took_s": took_s}
    if args.json:
        print(json.dumps(answer))
    else:
        print(format_answer(args.command, answer) + f" (direct, {took_s * 1e3:.0f} ms)")
    return 0


FAULT_OPTIONS = (
    ("duration_s", "duration_s"),
    ("body", "body"),
    ("offset_m", "offset_m"),
    ("vehicle", "vehicle"),
    ("fraction", "fraction"),
    ("force_n", "force_n"),
)


def _fault_request(args: argparse.Namespace) -> tuple[str, str, Any]:
    """``fault KIND [options]``, ``fault --clear``, or ``fault`` (list them). Only the options
    given go into the body: the service says which a kind takes and which it lacks."""
    given = [option for option, _ in FAULT_OPTIONS if getattr(args, option) is not None]
    if args.clear:
        if args.kind is not None or given:
            raise UsageError("fault --clear ends every fault: give it no KIND and no option")
        return "DELETE", "/api/sim/faults", None
    if args.kind is None:
        if given:
            raise UsageError("fault: name a KIND for the options to apply to")
        return "GET", "/api/sim/faults", None
    fields = dict(FAULT_OPTIONS)
    body: dict[str, Any] = {"kind": args.kind}
    body.update((fields[option], getattr(args, option)) for option in given)
    return "POST", "/api/sim/faults", body


def _setpoint_body(args: argparse.Namespace) -> dict[str, Any]:
    """The REST body of ``setpoint X Y Z ...`` (degrees in, radians out)."""
    if len(args.position) != 3:
        raise UsageError(f"setpoint takes X Y Z (metres), got {len(args.position)} numbers")
    body: dict[str, Any] = {"bar_position": args.position, "hold_s": args.hold_s}
    if args.yaw_deg is not None:
        body["bar_yaw"] = math.radians(args.yaw_deg)
    if args.uav_yaw_deg is not None:
        body["uav_yaw"] = [math.radians(v) for v in args.uav_yaw_deg]
    if args.theta_l_deg is not None:
        if not 0.0 <= args.theta_l_deg < 90.0:
            raise UsageError(f"--theta-l-deg {args.theta_l_deg:g}: must lie in [0, 90) degrees")
        body["theta_l"] = math.radians(args.theta_l_deg)
    return body


def _request_for(args: argparse.Namespace) -> tuple[str, str, Any]:
    """(method, path, JSON body) of the command in ``args``."""
    command = args.command
    if command == "status":
        return "GET", "/api/status", None
    if command == "fault":
        return _fault_request(args)
    if command == "reset":
        return "POST", "/api/sim/reset", None
    if command in SIMPLE_REQUESTS:
        return "POST", f"/api/{command}", None
    if command == "kill":
        if not args.confirm:
            raise UsageError("kill stops the motors in the air: add --confirm")
        return "POST", "/api/kill", {"confirm": True}
    if command == "mode":
        return "POST", "/api/mode", {"controller": args.controller}
    if command == "path":
        return "POST", "/api/path", read_path_file(args.file)
    if args.clear:
        if args.position:
            raise UsageError("setpoint --clear drops every setpoint: give it no X Y Z")
        return "DELETE", "/api/setpoints", None
    if not args.position:
        return "GET", "/api/setpoints", None
    return "POST", "/api/setpoints", _setpoint_body(args)


def _goal(args: argparse.Namespace, body: Any) -> outcomes.Goal:
    command = args.command
    if command == "arm":
        return outcomes.armed
    if command == "takeoff":
        return outcomes.hovering
    if command == "land":
        return outcomes.landed
    if command == "mode":
        return outcomes.controller(args.controller)
    if command == "path":
        return outcomes.path_flown([point["bar_position"] for point in body["waypoints"]])
    from supervisor.flight.operator_requests import SetpointFields

    return outcomes.setpoint_flown(SetpointFields.model_validate(body))


def _print_answer(args: argparse.Namespace, answer: Any) -> None:
    if args.json:
        print(json.dumps(answer))
    elif args.command == "status":
        print(format_status(_parse_status(answer)))
    elif args.command in ("fault", "reset"):
        print(format_faults(answer))
    elif args.command == "setpoint" and "queued" in answer and isinstance(answer["queued"], list):
        print(format_setpoints(answer))
    elif args.command == "path":
        print(format_path_answer(answer))
    else:
        print(format_answer(args.command, answer))


def _wait_timeout_s(args: argparse.Namespace, body: Any, answer: Any) -> float:
    """``--timeout``, else the command's own; a path's beyond its duration and hold."""
    if args.timeout is not None:
        return float(args.timeout)
    timeout_s = WAIT_TIMEOUT_S[args.command]
    if args.command == "path":
        timeout_s += float(answer.get("duration_s", 0.0)) + float(body.get("hold_s", 0.0))
    return timeout_s


def _wait(
    client: JsonClient, args: argparse.Namespace, body: Any, answer: Any, sent_at_s: float
) -> int:
    """Poll the status until the request's outcome is known; its exit status."""

    def fetch() -> Status:
        response = client.request("GET", "/api/status")
        if response.status != 200:
            raise UnreachableError(f"GET /api/status answered {response.status}")
        return _parse_status(response.body)

    timeout_s = _wait_timeout_s(args, body, answer)
    outcome = awaiting.await_goal(_goal(args, body), fetch, sent_at_s, timeout_s)
    if args.json:
        print(json.dumps({"reached": outcome.reached, "message": outcome.message}))
    elif outcome.reached:
        print(f"{args.command}: {outcome.message}")
    if not outcome.reached:
        print(f"{args.command}: {outcome.message}", file=sys.stderr)
        return EXIT_REFUSED
    return 0


def run_client(args: argparse.Namespace) -> int:
    """Send the command, print the answer (and with ``--wait`` the outcome); returns the
    exit status."""
    method, path, body = _request_for(args)
    waiting = bool(getattr(args, "wait", False))
    if waiting and method != "POST":
        raise UsageError("--wait waits for a request: give the setpoint X Y Z")
    address = service_address(args)
    urgent = args.command in URGENT_COMMANDS
    timeout_s = URGENT_HTTP_TIMEOUT_S if urgent else HTTP_TIMEOUT_S
    try:
        client = JsonClient(address.url, _headers(args), timeout_s, address.cafile)
    except ValueError as error:
        raise UsageError(f"{error} (from {address.found_by})") from None
    with client:
        sent_at_s = time.monotonic()
        try:
            response = client.request(method, path, body)
        except UnreachableError as error:
            if urgent:
                return _urgent_directly(address, args, error)
            return _unreachable(address, error)
        answer = response.body
        if response.status == 401 and _token(args) is None:
            raise UsageError(
                f"no API token: export {TOKEN_ENV}=TOKEN (or --token TOKEN), the token "
                "`serve` printed as it started (its line 'API token', or the dashboard "
                "address's #token=)"
            )
        if response.status >= 400:
            detail = answer.get("detail", answer) if isinstance(answer, dict) else answer
            print(
                f"{args.command} refused ({response.status}): {format_detail(detail)}",
                file=sys.stderr,
            )
            return EXIT_REFUSED
        try:
            if not waiting:
                _print_answer(args, answer)
                return 0
            return _wait(client, args, body, answer, sent_at_s)
        except UnreachableError as error:
            return _unreachable(address, f"while waiting: {error}")
        except MalformedStatusError as error:
            print(f"{args.command}: {error}", file=sys.stderr)
            return EXIT_REFUSED


def _add_client_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--url",
        metavar="URL",
        help=f"the service's address (default: ${URL_ENV}, else the serve running here, "
        "else http://127.0.0.1:8000 from the setup)",
    )
    parser.add_argument("--token", metavar="TOKEN", help=f"API token (default: ${TOKEN_ENV})")
    parser.add_argument(
        "--cafile",
        metavar="PEM",
        help=f"over HTTPS, the certificate to trust (default: ${CA_FILE_ENV}, else the one "
        "the service found uses, else the system's)",
    )
    parser.add_argument("--json", action="store_true", help="print the raw JSON answer")


def _add_wait_options(parser: argparse.ArgumentParser, command: str, beyond: str = "") -> None:
    """``--wait`` and ``--timeout`` (``beyond``: what the default timeout is counted from)."""
    parser.add_argument(
        "--wait",
        action="store_true",
        help="return when the system is there (exit 0) or cannot get there (exit 1, with "
        "the reason: an abort's notice, PX4's refusal)",
    )
    parser.add_argument(
        "--timeout",
        type=positive_float,
        metavar="S",
        help=f"with --wait: give up after S seconds, exit 1 "
        f"(default: {WAIT_TIMEOUT_S[command]:g}{beyond})",
    )


EXAMPLES = {
    "status": "  uavbar-supervisor status\n  uavbar-supervisor status --json | jq .mode",
    "arm": "  uavbar-supervisor arm --wait",
    "takeoff": "  uavbar-supervisor takeoff --wait --timeout 30   # exit 0 once hovering",
    "land": "  uavbar-supervisor land --wait   # exit 0 once disarmed on the ground",
    "abort": "  uavbar-supervisor abort   # no API answer in 0.3 s: straight to the flight process",
    "disarm": "  uavbar-supervisor disarm",
    "kill": "  uavbar-supervisor kill --confirm",
    "mode": "  uavbar-supervisor mode decentralized --wait",
    "setpoint": (
        "  uavbar-supervisor setpoint 0.5 0.3 1.2 --yaw-deg 20 --hold-s 3 --wait\n"
        "  uavbar-supervisor setpoint 0 0 1 --theta-l-deg 30   # the θ_l = 30° equilibrium\n"
        "  uavbar-supervisor setpoint                          # list active and queued\n"
        "  uavbar-supervisor setpoint --clear                  # drop them, hold where it is"
    ),
    "path": (
        "  uavbar-supervisor path square.toml --wait   # exit 0 once its end is reached and held"
    ),
    "fault": (
        "  uavbar-supervisor fault mocap_silent --duration-s 1\n"
        "  uavbar-supervisor fault link_lost --vehicle 2\n"
        "  uavbar-supervisor fault push --body uav1 --force-n 1 0 0 --duration-s 5\n"
        "  uavbar-supervisor fault --clear"
    ),
    "reset": "  uavbar-supervisor reset",
}


def add_client_commands(commands: Any) -> list[argparse.ArgumentParser]:
    """The client subcommands, each with ``handler`` set to ``run_client``."""

    def command(name: str, help_text: str, description: str = "") -> argparse.ArgumentParser:
        parser: argparse.ArgumentParser = commands.add_parser(
            name,
            help=help_text,
            description=description or help_text[0].upper() + help_text[1:] + ".",
            epilog="examples:\n" + EXAMPLES[name],
        )
        return parser

    parsers = [command("status", "the running service's status: mode, bar, UAVs, mocap, ticks")]
    for name, text in SIMPLE_REQUESTS.items():
        parser = command(name, text)
        if name in ("arm", "takeoff", "land"):
            _add_wait_options(parser, name)
        parsers.append(parser)
    kill = command("kill", "force-disarm every vehicle at once: they fall")
    kill.add_argument("--confirm", action="store_true", help="required: yes, kill")
    mode = command("mode", "switch the controller (bumpless in flight)")
    mode.add_argument("controller", choices=CONTROLLERS, help="the MPC to fly the bar")
    _add_wait_options(mode, "mode")
    setpoint = command(
        "setpoint",
        "queue a bar setpoint (no X Y Z: list them; --clear: drop them)",
        "Queue a bar setpoint: the bar's centre in the arena frame (metres, z up), its yaw, "
        "the UAVs' yaws and the cable angle θ_l (degrees), held for --hold-s seconds once "
        "reached, then the next one. Taken only while armed or flying (refused disarmed, "
        "landing or aborting).",
    )
    setpoint.add_argument(
        "position", nargs="*", type=finite_float, metavar="X Y Z", help="bar centre [m]"
    )
    setpoint.add_argument(
        "--yaw-deg", type=finite_float, metavar="DEG", help="bar yaw [°] (default: 0)"
    )
    setpoint.add_argument(
        "--uav-yaw-deg",
        type=finite_float,
        nargs=2,
        metavar=("PSI1", "PSI2"),
        help="each UAV's yaw [°] (default: the bar's)",
    )
    setpoint.add_argument(
        "--theta-l-deg",
        type=finite_float,
        metavar="DEG",
        help="cable angle θ_l [°], in [0, 90) (default: 0, cables vertical)",
    )
    setpoint.add_argument(
        "--hold-s",
        "--hold",
        type=non_negative_float,
        default=5.0,
        metavar="S",
        help="seconds to hold once reached (default: 5)",
    )
    setpoint.add_argument("--clear", action="store_true", help="drop the queue and the active")
    _add_wait_options(setpoint, "setpoint")
    path = command(
        "path",
        "queue a path for the bar through waypoints, from a TOML file",
        "Queue a path: the bar from where it will be (after what is queued) through the "
        "waypoints, smooth, within a top speed, acceleration and jerk and the flight's yaw "
        "and θ_l rates; its end is then held as a setpoint. Taken only while armed or "
        "flying. FILE is TOML with the REST body's fields (metres, seconds, radians):"
        f"\n\n{FILE_FORMAT}",
    )
    path.add_argument("file", type=Path, metavar="FILE", help="the path (TOML, as above)")
    _add_wait_options(path, "path", " beyond the path's duration and hold")
    fault = command(
        "fault",
        "inject a fault into the embedded simulated world (no KIND: list them; --clear: "
        "end them all)",
    )
    fault.add_argument(
        "kind",
        nargs="?",
        metavar="KIND",
        help="mocap_silent, mocap_body_lost, mocap_freeze, mocap_jump, link_lost, "
        "px4_reboot, udp_loss or push (docs/faults.md)",
    )
    fault.add_argument(
        "--duration-s",
        "--duration",
        type=positive_float,
        metavar="S",
        help="seconds (default: until cleared)",
    )
    fault.add_argument("--body", metavar="NAME", help="a rigid body of mocap.bodies")
    fault.add_argument(
        "--offset-m", type=finite_float, nargs=3, metavar=("X", "Y", "Z"), help="metres"
    )
    fault.add_argument("--vehicle", type=int, metavar="N", help="1 … the number of UAVs")
    fault.add_argument("--fraction", type=finite_float, metavar="F", help="in [0, 1]")
    fault.add_argument(
        "--force-n",
        type=finite_float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="push: newtons at the body's centre of mass, arena frame (each within ±50)",
    )
    fault.add_argument("--clear", action="store_true", help="end every fault")
    reset = command("reset", "put the embedded simulated world back in its resting pose (disarmed)")
    parsers += [kill, mode, setpoint, path, fault, reset]
    for parser in parsers:
        _add_client_options(parser)
        parser.set_defaults(handler=run_client)
    return parsers
