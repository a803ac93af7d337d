"""What the terminal client prints: the service's JSON (SI, radians) as lines and tables an
operator reads, in metres, degrees and seconds."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from supervisor.flight.modes import Mode

if TYPE_CHECKING:  # the client parses the status only once it has one
    from supervisor.flight.status import PathStatus, Status, WorldStatus

# The modes in which an arm is the next thing an operator may want.
WAITING_ON_THE_GROUND = frozenset({Mode.DISARMED, Mode.DISARMING, Mode.PX4_LANDING, Mode.KILLED})


def table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """Columns padded to their widest cell, two spaces apart."""
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows, strict=True)]
    lines = [header, *rows]
    return "\n".join(
        "  ".join(str(cell).ljust(width) for cell, width in zip(line, widths, strict=True)).rstrip()
        for line in lines
    )


def degrees(radians: Any) -> str:
    """An angle in radians as degrees ("-" when unknown)."""
    if not isinstance(radians, int | float):
        return "-"
    return f"{math.degrees(radians):+.1f}°"


def _position(values: Sequence[float | None]) -> str:
    if any(v is None for v in values):
        return "unknown"
    return "(" + ", ".join(f"{v:+.3f}" for v in values if v is not None) + ") m"


def _milliseconds(value: float | None) -> str:
    return f"{value or 0.0:.2f}"


def format_status(status: Status) -> str:
    """A few lines an operator reads at a glance."""
    bar, mocap, setpoints, tick = status.bar, status.mocap, status.setpoints, status.tick
    reference = status.reference
    lines = [
        f"mode {status.mode.value} ({status.phase.value}), controller "
        f"{status.controller}{'  [STALE]' if status.stale else ''}",
        f"bar  {_position(bar.position)}, yaw "
        + (degrees(bar.yaw) if bar.yaw is not None else "unknown")
        + (f", θ_l {degrees(reference.theta_l)} (reference)" if reference else ""),
    ]
    for i, (uav, armed) in enumerate(zip(status.uavs, status.armed, strict=True), start=1):
        lines.append(
            f"uav{i} {_position(uav.position)}, px4 {uav.px4_mode}, "
            f"{'armed' if armed else 'disarmed'}, link {'up' if uav.connected else 'DOWN'}"
            + (f", battery {uav.battery_v:.1f} V" if uav.battery_v is not None else "")
        )
    refused = ", ".join(f"{reason} {n}" for reason, n in mocap.refused.items())
    unreached = not mocap.connected and mocap.server
    lines.append(
        f"mocap {'healthy' if mocap.healthy else 'NOT HEALTHY'} at "
        f"{mocap.rate_hz:.0f} Hz{f' (refused: {refused})' if refused else ''}"
        + (f" (QTM at {mocap.server}: {mocap.last_error or 'no answer'})" if unreached else "")
        + "; setpoints: "
        f"{'active' if setpoints.active else 'none active'}, {len(setpoints.queued)} queued"
    )
    if status.path is not None:
        lines.append(_path_line(status.path))
    lines.append(
        f"ticks {tick.count}, missed {tick.missed_deadlines}, compute p50/p99 "
        f"{_milliseconds(tick.compute_ms_p50)}/{_milliseconds(tick.compute_ms_p99)} ms"
    )
    if status.mode in WAITING_ON_THE_GROUND and status.arm_blocked_by:
        lines.append(f"arm would be refused: {status.arm_blocked_by}")
    ending = status.last_flight
    if ending is not None:
        lines.append(f"last flight ended in {ending.ended_in.value} {ending.age_s:.0f} s ago")
    if status.log_stopped:
        lines.append(f"flight log: {status.log_stopped}")
    for name, process in status.processes.items():
        if process.last_exit:
            again = "started again" if process.alive else "NOT RUNNING"
            lines.append(
                f"the {name} process died ({process.last_exit}): {again}, "
                f"{process.restarts} restarts"
            )
    world = _world_line(status.world)
    if world:
        lines.append(world)
    lines += [
        f"notice ({notice.age_s:.0f} s ago): {notice.message}" for notice in status.notices[-3:]
    ]
    return "\n".join(lines)


def _path_line(path: PathStatus) -> str:
    """The active setpoint's path: its length, waypoints and how far along it is."""
    if path.elapsed_s is None:
        progress = "not begun"
    elif path.elapsed_s >= path.duration_s:
        progress = "flown, its end held"
    else:
        progress = f"{path.elapsed_s:.1f} of {path.duration_s:.1f} s"
    return (
        f"path {path.length_m:.2f} m through {len(path.waypoints)} waypoints "
        f"in {path.duration_s:.1f} s: {progress}"
    )


def _world_line(world: WorldStatus) -> str:
    """The embedded simulated world's faults and stalls, when there is something to say."""
    if not world.embedded:
        return ""
    if not world.reachable:
        return "simulated world: NOT REACHABLE"
    parts = [_fault_words(f.kind, f.params, f.remaining_s) for f in world.faults]
    stalls = world.stalls
    if stalls is not None and stalls.count:
        parts.append(
            f"stalled {stalls.count} times by this computer (worst {stalls.worst_ms:.0f} "
            f"ms, last {stalls.last_ms:.0f} ms {stalls.last_age_s or 0.0:.0f} s ago)"
        )
    return "simulated world: " + "; ".join(parts) if parts else ""


def _setpoint_row(label: str, setpoint: dict[str, Any]) -> list[str]:
    x, y, z = setpoint.get("bar_position", [math.nan] * 3)
    uav_yaw = setpoint.get("uav_yaw") or [None, None]
    return [
        label,
        f"{x:+.3f}",
        f"{y:+.3f}",
        f"{z:+.3f}",
        degrees(setpoint.get("bar_yaw")),
        f"{degrees(uav_yaw[0])} {degrees(uav_yaw[1])}",
        degrees(setpoint.get("theta_l")),
        f"{setpoint.get('hold_s', 0.0):g}",
    ]


def format_setpoints(answer: dict[str, Any]) -> str:
    """The active setpoint and the queue, one row each."""
    rows = []
    if answer.get("active"):
        rows.append(_setpoint_row("active", answer["active"]))
    rows += [_setpoint_row(str(k), s) for k, s in enumerate(answer.get("queued", []), start=1)]
    if not rows:
        return "no setpoint active or queued"
    header = ["", "x [m]", "y [m]", "z [m]", "bar yaw", "UAV yaws", "θ_l", "hold [s]"]
    return table(header, rows)


def format_path_answer(answer: dict[str, Any]) -> str:
    """An accepted path in one line: ``path: accepted, queued 2, 3.21 m in 8.4 s``."""
    return (
        f"path: accepted, queued {answer.get('queued')}, "
        f"{answer.get('length_m', math.nan):.2f} m in {answer.get('duration_s', math.nan):.1f} s"
    )


def _fault_words(kind: object, params: Mapping[str, object], remaining_s: float | None) -> str:
    """A fault in effect: its kind, its parameters, how long it still lasts."""
    words = " ".join(f"{k} {v}" for k, v in params.items())
    left = "until cleared" if remaining_s is None else f"{remaining_s:.1f} s left"
    return f"{kind}{' ' + words if words else ''} ({left})"


def _format_fault(fault: dict[str, Any]) -> str:
    return _fault_words(fault.get("kind"), fault.get("params", {}), fault.get("remaining_s"))


def format_faults(answer: dict[str, Any]) -> str:
    """The answer of ``fault`` or ``reset``: what ended, then what is in effect."""
    if not answer.get("embedded", True):
        return "no simulated world here (sim.embedded is false): no faults"
    lines = []
    if answer.get("reset"):
        lines.append("world reset: resting pose, PX4s disarmed in their boot mode")
        if not answer.get("tracked", True):
            lines.append("motion capture does not track the bodies at the resting pose yet")
        if answer.get("arm_blocked_by"):
            lines.append(f"not ready to arm: {answer['arm_blocked_by']}")
    lines += [f"ended: {_format_fault(fault)}" for fault in answer.get("cleared", [])]
    faults = answer.get("faults", [])
    lines += [f"in effect: {_format_fault(fault)}" for fault in faults]
    if not faults:
        lines.append("no fault in effect")
    return "\n".join(lines)


def format_answer(command: str, answer: Any) -> str:
    """An accepted request's answer in one line: ``takeoff: accepted, mode takeoff``."""
    if not isinstance(answer, dict):
        return f"{command}: {answer}"
    details = [
        f"{key} {value}" for key, value in answer.items() if key not in ("accepted", "direct")
    ]
    return f"{command}: accepted" + (", " + ", ".join(details) if details else "")


def _field(location: list[Any]) -> str:
    """Where a validation error is, without FastAPI's leading "body" (the request's)."""
    parts = location[1:] if location[:1] == ["body"] else location
    return ".".join(str(part) for part in parts) or "body"


def format_detail(detail: Any) -> str:
    """A refusal's reason; a validation error list as ``field: message`` per problem."""
    if isinstance(detail, list) and all(isinstance(d, dict) and "msg" in d for d in detail):
        return "; ".join(f"{_field(list(d.get('loc', [])))}: {d['msg']}" for d in detail)
    return str(detail)
