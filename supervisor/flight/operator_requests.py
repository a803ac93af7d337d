"""Operator requests (from the API channel) applied to the tick core, between ticks.

Pure: a request message in, a reply message out (``{"id", "outcome", "reason", "data"}``
with outcome ``ok``, ``refused`` or ``invalid``). The tick core's own checks decide; this
module only translates.
"""

from __future__ import annotations

from typing import Any

from supervisor.flight.core import FlightCore
from supervisor.flight.modes import OPERATOR_REQUESTS
from supervisor.flight.setpoints import Setpoint, SetpointError

REQUEST_KINDS = (*OPERATOR_REQUESTS, "controller", "queue", "clear_setpoints", "setpoints")


def setpoint_json(setpoint: Setpoint | None) -> dict[str, Any] | None:
    """A setpoint as the API shows it (radians, metres, seconds)."""
    if setpoint is None:
        return None
    return {
        "bar_position": list(setpoint.bar_position_m),
        "bar_yaw": setpoint.bar_yaw_rad,
        "uav_yaw": list(setpoint.reference().uav_yaw_rad),
        "theta_l": setpoint.theta_l_rad,
        "hold_s": setpoint.hold_s,
    }


def handle_request(core: FlightCore, message: dict[str, Any], now_s: float) -> dict[str, Any]:
    """Apply one request message to ``core``; returns the reply message."""
    kind = message.get("kind")
    reply: dict[str, Any] = {"id": message.get("id"), "outcome": "ok", "reason": "", "data": {}}

    def refuse(reason: str, outcome: str = "refused") -> dict[str, Any]:
        return {**reply, "outcome": outcome, "reason": reason}

    if kind in OPERATOR_REQUESTS:
        transition = core.request(str(kind), now_s)
        reply["data"] = {"mode": transition.mode.value}
        return reply if transition.accepted else refuse(transition.reason)
    if kind == "controller":
        transition = core.set_controller(str(message.get("controller")), now_s)
        reply["data"] = {"controller": core.controller, "mode": core.modes.mode.value}
        return reply if transition.accepted else refuse(transition.reason, "invalid")
    if kind == "queue":
        try:
            setpoints = [Setpoint.from_json(entry) for entry in message.get("setpoints", [])]
        except SetpointError as error:
            return refuse(str(error), "invalid")
        try:
            core.queue_setpoints(setpoints)
        except SetpointError as error:
            return refuse(str(error))
        reply["data"] = {"queued": len(core.queue.queued)}
        return reply
    if kind == "clear_setpoints":
        core.clear_setpoints()
        return reply
    if kind == "setpoints":
        reply["data"] = {
            "active": setpoint_json(core.queue.active),
            "queued": [setpoint_json(s) for s in core.queue.queued],
        }
        return reply
    return refuse(f"unknown request {kind!r}", "invalid")
