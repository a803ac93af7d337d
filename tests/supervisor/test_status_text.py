"""The status as text: what an operator must see at a glance, from one status answer."""

from __future__ import annotations

import math
from typing import Any

from supervisor.cli.output import format_status


def a_status(**changes: Any) -> dict[str, Any]:
    status: dict[str, Any] = {
        "mode": "disarmed",
        "phase": "ground",
        "controller": "centralized",
        "armed": [False, False],
        "arm_blocked_by": None,
        "bar": {"position": [0.0, 0.0, 0.02], "yaw": 0.0},
        "uavs": [{"position": [0.7, 0.0, 0.05], "px4_mode": "POSCTL", "connected": True}] * 2,
        "reference": None,
        "mocap": {"healthy": True, "connected": True, "rate_hz": 100.0, "server": "h:22223"},
        "setpoints": {"active": None, "queued": []},
        "tick": {"count": 10, "missed_deadlines": 0},
        "notices": [],
        "log_stopped": None,
    }
    return status | changes


def test_the_text_says_what_blocks_arming_and_the_cable_angle() -> None:
    quiet = format_status(a_status())
    assert "arm would be refused" not in quiet and "θ_l" not in quiet
    blocked = a_status(arm_blocked_by="UAV 1 is not heard (no heartbeat): check its link")
    assert "arm would be refused: UAV 1 is not heard" in format_status(blocked)
    reference = {"theta_l": math.radians(30.0), "bar_position": [0.0, 0.0, 1.0]}
    hovering = format_status(
        a_status(mode="hover", arm_blocked_by="in flight", reference=reference)
    )
    assert "θ_l +30.0°" in hovering and "arm would be refused" not in hovering


def test_an_unreachable_qtm_is_named_with_why_and_a_stopped_log_said() -> None:
    mocap = {"healthy": False, "connected": False, "rate_hz": 0.0, "server": "10.0.0.5:22223"}
    mocap["last_error"] = "ConnectionRefusedError: [Errno 111] Connection refused"
    text = format_status(a_status(mocap=mocap, log_stopped="log disk full: no longer recording"))
    assert "QTM at 10.0.0.5:22223: ConnectionRefusedError" in text
    assert "flight log: log disk full: no longer recording" in text


def test_a_process_that_died_is_said_with_how() -> None:
    processes = {
        "relay": {"pid": 7, "alive": True, "restarts": 1, "last_exit": "killed by SIGKILL"},
        "api": {"pid": 8, "alive": True, "restarts": 0, "last_exit": None},
    }
    text = format_status(a_status(processes=processes))
    assert "the relay process died (killed by SIGKILL): started again, 1 restarts" in text
    assert "api process" not in text
