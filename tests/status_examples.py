"""A whole status as ``GET /api/status`` answers it, for the tests of what reads one: two
UAVs resting on the ground, disarmed, mocap healthy, nothing queued."""

from __future__ import annotations

import copy
from typing import Any

from supervisor.flight.status import FlightStatus, Status


def _uav(x_m: float) -> dict[str, Any]:
    return {
        "position": [x_m, 0.0, 0.07],
        "yaw": 0.0,
        "attitude": [0.0, 0.0, 0.0],
        "connected": True,
        "px4_mode": "POSCTL",
        "battery_v": 16.2,
        "status_text": "",
        "link_refused": {},
    }


STATUS_JSON: dict[str, Any] = {
    "time_s": 12.5,
    "mode": "disarmed",
    "mode_for_s": 12.5,
    "phase": "ground",
    "controller": "centralized",
    "armed": [False, False],
    "arm_blocked_by": None,
    "arena": {"min": [-3.0, -3.0, 0.0], "max": [3.0, 3.0, 3.0]},
    "bar": {
        "position": [0.0, 0.0, 0.02],
        "ends": [[-0.705, 0.0, 0.02], [0.765, 0.0, 0.02]],
        "yaw": 0.0,
        "velocity": [0.0, 0.0, 0.0],
        "error_m": None,
    },
    "uavs": [_uav(-0.705), _uav(0.765)],
    "reference": None,
    "mocap": {
        "healthy": True,
        "connected": True,
        "server": "127.0.0.1:22223",
        "last_error": None,
        "rate_hz": 100.0,
        "age_ms": 5.0,
        "unhealthy": [],
        "frames": 1250,
        "dropped": 0,
        "refused": {},
    },
    "setpoints": {"active": None, "queued": []},
    "path": None,
    "plan": {"status": None, "solve_ms": None, "thrust_n": None},
    "loads": {
        "bar_force_n": [0.0, 0.0, 0.0],
        "bar_torque_nm": [0.0, 0.0, 0.0],
        "uav_forces_n": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        "at_bound": [],
    },
    "faults": [],
    "notices": [],
    "last_flight": None,
    "tick": {
        "count": 10,
        "missed_deadlines": 0,
        "compute_ms_p50": 1.2,
        "compute_ms_p99": 3.4,
        "lateness_ms_p99": 0.3,
        "latency_ms_p50": None,
        "latency_ms_p99": None,
    },
    "streaming": False,
    "log": None,
    "log_stopped": None,
    "live_view": None,
    "agents": None,
    "stale": False,
    "processes": {},
    "world": {"embedded": False},
}


def status_json(**changes: Any) -> dict[str, Any]:
    """The example as JSON (a fresh copy), with ``changes`` to its top-level fields."""
    return copy.deepcopy(STATUS_JSON) | changes


def flight_status_json(**changes: Any) -> dict[str, Any]:
    """The flight process's part of the example (what it publishes), with ``changes``."""
    return {k: v for k, v in status_json(**changes).items() if k in FlightStatus.model_fields}


def a_status(**changes: Any) -> Status:
    """The example, with ``changes`` to its top-level fields (validated)."""
    return Status.model_validate(status_json(**changes))
