"""The terminal client: ``uavbar-supervisor status|arm|takeoff|land|abort|disarm|kill|mode|
setpoint`` against a running service's REST API, for scripts and the laptop next to the
drones; ``fault`` and ``reset`` for the embedded simulated world (docs/faults.md).

The URL defaults to the configured ``api.host``/``api.port``; the token comes from
``--token`` or the environment variable ``UAVBAR_TOKEN``. ``abort`` and ``kill`` give the
API 0.3 s, then go straight to the flight process (``supervisor.cli.direct``). Exit
status: 0 done, 1 refused (the reason is printed), 3 the service cannot be reached (2 is a
usage error, as for every command).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import Any

import httpx

from supervisor.app.config import TOKEN_ENV, Config
from supervisor.cli.direct import DirectPathError, direct_request
from supervisor.cli.usage import UsageError

EXIT_REFUSED = 1
EXIT_UNREACHABLE = 3
SIMPLE_REQUESTS = ("arm", "takeoff", "land", "abort", "disarm")
URGENT_COMMANDS = ("abort", "kill")
URGENT_HTTP_TIMEOUT_S = 0.3


def add_client_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--url", metavar="URL", help="service address (default: from config)")
    parser.add_argument("--token", metavar="TOKEN", help=f"API token (default: ${TOKEN_ENV})")
    parser.add_argument("--json", action="store_true", help="print the raw JSON answer")


def _base_url(config: Config, args: argparse.Namespace) -> str:
    if args.url:
        return str(args.url).rstrip("/")
    host = config.api.host if config.api.host not in ("0.0.0.0", "::") else "127.0.0.1"
    return f"http://{host}:{config.api.port}"


def _token(args: argparse.Namespace) -> str | None:
    return args.token or os.environ.get(TOKEN_ENV)


def _headers(args: argparse.Namespace) -> dict[str, str]:
    token = _token(args)
    return {"Authorization": f"Bearer {token}"} if token else {}


def _urgent_directly(url: str, args: argparse.Namespace, why: Exception) -> int:
    """Abort or kill through the flight process's own socket (the API did not answer)."""
    try:
        reply, took_s = direct_request(url, _token(args), args.command)
    except DirectPathError as error:
        print(f"cannot reach the service at {url}: {why}; directly: {error}", file=sys.stderr)
        return EXIT_UNREACHABLE
    print(f"the API did not answer ({why}): sent straight to the flight process", file=sys.stderr)
    if reply.get("outcome") != "ok":
        print(f"refused: {reply.get('reason')}", file=sys.stderr)
        return EXIT_REFUSED
    if args.json:
        print(json.dumps({**reply.get("data", {}), "direct": True, "took_s": took_s}))
    else:
        answer = {**reply.get("data", {}), "direct": True}
        print(", ".join(f"{k}: {v}" for k, v in answer.items()) + f" ({took_s * 1e3:.0f} ms)")
    return 0


def _format_position(values: Any) -> str:
    if not values or any(v is None for v in values):
        return "unknown"
    return "(" + ", ".join(f"{v:+.3f}" for v in values) + ") m"


def format_status(status: dict[str, Any]) -> str:
    """A few lines an operator reads at a glance."""
    bar = status.get("bar", {})
    yaw = bar.get("yaw")
    tick = status.get("tick", {})
    mocap = status.get("mocap", {})
    lines = [
        f"mode {status.get('mode')} ({status.get('phase', '-')}), controller "
        f"{status.get('controller')}{'  [STALE]' if status.get('stale') else ''}",
        f"bar  {_format_position(bar.get('position'))}, yaw "
        + (f"{math.degrees(yaw):+.1f}°" if yaw is not None else "unknown"),
    ]
    for i, uav in enumerate(status.get("uavs", []), start=1):
        armed = status.get("armed", [False, False])[i - 1]
        lines.append(
            f"uav{i} {_format_position(uav.get('position'))}, px4 {uav.get('px4_mode')}, "
            f"{'armed' if armed else 'disarmed'}, link {'up' if uav.get('connected') else 'DOWN'}"
        )
    refused = ", ".join(f"{reason} {n}" for reason, n in (mocap.get("refused") or {}).items())
    lines.append(
        f"mocap {'healthy' if mocap.get('healthy') else 'NOT HEALTHY'} at "
        f"{mocap.get('rate_hz') or 0:.0f} Hz{f' (refused: {refused})' if refused else ''}; "
        "setpoints: "
        f"{'active' if status.get('setpoints', {}).get('active') else 'none active'}, "
        f"{len(status.get('setpoints', {}).get('queued', []))} queued"
    )
    lines.append(
        f"ticks {tick.get('count')}, missed {tick.get('missed_deadlines')}, compute p50/p99 "
        f"{tick.get('compute_ms_p50') or 0:.2f}/{tick.get('compute_ms_p99') or 0:.2f} ms"
    )
    lines += [
        f"notice ({notice['age_s']:.0f} s ago): {notice['message']}"
        for notice in status.get("notices", [])[-3:]
    ]
    return "\n".join(lines)


FAULT_OPTIONS = (
    ("duration", "duration_s"),
    ("body", "body"),
    ("offset_m", "offset_m"),
    ("vehicle", "vehicle"),
    ("fraction", "fraction"),
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
    for option in given:
        value = getattr(args, option)
        numbers = value if isinstance(value, list) else [value]
        if any(isinstance(v, float) and not math.isfinite(v) for v in numbers):
            # JSON has no NaN or infinity: say so here rather than send what cannot be sent.
            flag = "--" + option.replace("_", "-")
            raise UsageError(f"{flag} {value}: must be finite")
    fields = dict(FAULT_OPTIONS)
    body: dict[str, Any] = {"kind": args.kind}
    body.update((fields[option], getattr(args, option)) for option in given)
    return "POST", "/api/sim/faults", body


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
    if args.clear:
        return "DELETE", "/api/setpoints", None
    if not args.position:
        return "GET", "/api/setpoints", None
    if len(args.position) != 3:
        raise UsageError(f"setpoint takes X Y Z (metres), got {len(args.position)} numbers")
    body: dict[str, Any] = {"bar_position": args.position, "hold_s": args.hold}
    if args.yaw is not None:
        body["bar_yaw"] = args.yaw
    if args.uav_yaw is not None:
        body["uav_yaw"] = args.uav_yaw
    if args.theta_l is not None:
        body["theta_l"] = args.theta_l
    return "POST", "/api/setpoints", body


def _format_fault(fault: dict[str, Any]) -> str:
    params = " ".join(f"{k} {v}" for k, v in fault.get("params", {}).items())
    remaining = fault.get("remaining_s")
    left = "until cleared" if remaining is None else f"{remaining:.1f} s left"
    return f"{fault.get('kind')}{' ' + params if params else ''} ({left})"


def format_faults(answer: dict[str, Any]) -> str:
    """The answer of ``fault`` or ``reset``: what ended, then what is in effect."""
    if not answer.get("embedded", True):
        return "no simulated world here (sim.embedded is false): no faults"
    lines = []
    if answer.get("reset"):
        lines.append("world reset: resting pose, PX4s disarmed in their boot mode")
    lines += [f"ended: {_format_fault(fault)}" for fault in answer.get("cleared", [])]
    faults = answer.get("faults", [])
    lines += [f"in effect: {_format_fault(fault)}" for fault in faults]
    if not faults:
        lines.append("no fault in effect")
    return "\n".join(lines)


def _field(location: list[Any]) -> str:
    """Where a validation error is, without FastAPI's leading "body" (the request's)."""
    parts = location[1:] if location[:1] == ["body"] else location
    return ".".join(str(part) for part in parts) or "body"


def _format_detail(detail: Any) -> str:
    """A refusal's reason; a validation error list as ``field: message`` per problem."""
    if isinstance(detail, list) and all(isinstance(d, dict) and "msg" in d for d in detail):
        return "; ".join(f"{_field(list(d.get('loc', [])))}: {d['msg']}" for d in detail)
    return str(detail)


def run_client(config: Config, args: argparse.Namespace) -> int:
    """Send the command, print the answer; returns the exit status."""
    method, path, body = _request_for(args)
    url = _base_url(config, args)
    urgent = args.command in URGENT_COMMANDS
    timeout_s = URGENT_HTTP_TIMEOUT_S if urgent else 10.0
    try:
        response = httpx.request(
            method, url + path, json=body, headers=_headers(args), timeout=timeout_s
        )
    except httpx.HTTPError as error:
        if urgent:
            return _urgent_directly(url, args, error)
        print(f"cannot reach the service at {url}: {error}", file=sys.stderr)
        return EXIT_UNREACHABLE
    try:
        answer = response.json()
    except ValueError:
        answer = {"detail": response.text}
    if response.status_code >= 400:
        detail = answer.get("detail", answer) if isinstance(answer, dict) else answer
        print(f"refused ({response.status_code}): {_format_detail(detail)}", file=sys.stderr)
        return EXIT_REFUSED
    if args.json:
        print(json.dumps(answer))
    elif args.command == "status":
        print(format_status(answer))
    elif args.command in ("fault", "reset"):
        print(format_faults(answer))
    else:
        print(", ".join(f"{k}: {v}" for k, v in answer.items()))
    return 0


def add_client_commands(commands: Any) -> list[argparse.ArgumentParser]:
    """The client subcommands, each with ``handler`` set to ``run_client``."""
    parsers = [commands.add_parser("status", help="the running service's status")]
    parsers += [
        commands.add_parser(name, help=f"ask the running service to {name}")
        for name in SIMPLE_REQUESTS
    ]
    kill = commands.add_parser("kill", help="force-disarm both vehicles (they fall)")
    kill.add_argument("--confirm", action="store_true", help="required: yes, kill")
    mode = commands.add_parser("mode", help="switch the controller")
    mode.add_argument("controller", choices=("centralized", "decentralized"))
    setpoint = commands.add_parser(
        "setpoint", help="queue a bar setpoint (no position: list them; --clear: drop them)"
    )
    setpoint.add_argument("position", nargs="*", type=float, metavar="X Y Z")
    setpoint.add_argument("--yaw", type=float, metavar="RAD", help="bar yaw")
    setpoint.add_argument("--uav-yaw", type=float, nargs=2, metavar=("PSI1", "PSI2"))
    setpoint.add_argument("--theta-l", type=float, metavar="RAD", help="cable angle")
    setpoint.add_argument("--hold", type=float, default=5.0, metavar="S", help="hold time")
    setpoint.add_argument("--clear", action="store_true", help="drop queue and active")
    fault = commands.add_parser(
        "fault",
        help="inject a fault into the embedded simulated world (no KIND: list them; "
        "--clear: end them all)",
    )
    fault.add_argument(
        "kind",
        nargs="?",
        metavar="KIND",
        help="mocap_silent, mocap_body_lost, mocap_freeze, mocap_jump, link_lost, "
        "px4_reboot or udp_loss (docs/faults.md)",
    )
    fault.add_argument(
        "--duration", type=float, metavar="S", help="seconds (default: until cleared)"
    )
    fault.add_argument("--body", metavar="NAME", help="a rigid body of mocap.bodies")
    fault.add_argument("--offset-m", type=float, nargs=3, metavar=("X", "Y", "Z"), help="metres")
    fault.add_argument("--vehicle", type=int, metavar="N", help="1 or 2")
    fault.add_argument("--fraction", type=float, metavar="F", help="in [0, 1]")
    fault.add_argument("--clear", action="store_true", help="end every fault")
    reset = commands.add_parser(
        "reset", help="put the embedded simulated world back in its resting pose (disarmed)"
    )
    parsers += [kill, mode, setpoint, fault, reset]
    for parser in parsers:
        add_client_options(parser)
        parser.set_defaults(handler=run_client)
    return parsers
