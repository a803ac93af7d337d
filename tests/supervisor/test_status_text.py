"""The status as text: what an operator must see at a glance, from one status answer."""

from __future__ import annotations

import math

from supervisor.cli.output import format_status
from tests.status_examples import a_status, status_json

REFERENCE = {
    "bar_position": [0.0, 0.0, 1.0],
    "bar_yaw": 0.0,
    "uav_yaw": [0.0, 0.0],
    "theta_l": math.radians(30.0),
    "uav_positions": [[-0.9, 0.0, 2.0], [0.9, 0.0, 2.0]],
    "bar_ends": [[-0.705, 0.0, 1.0], [0.765, 0.0, 1.0]],
}


def test_the_text_says_what_blocks_arming_and_the_cable_angle() -> None:
    quiet = format_status(a_status())
    assert "arm would be refused" not in quiet and "θ_l" not in quiet
    blocked = a_status(arm_blocked_by="UAV 1 is not heard (no heartbeat): check its link")
    assert "arm would be refused: UAV 1 is not heard" in format_status(blocked)
    hovering = format_status(
        a_status(mode="hover", phase="hover", arm_blocked_by="in flight", reference=REFERENCE)
    )
    assert "θ_l +30.0°" in hovering and "arm would be refused" not in hovering


def test_an_unreachable_qtm_is_named_with_why_and_a_stopped_log_said() -> None:
    mocap = status_json()["mocap"] | {"healthy": False, "connected": False, "rate_hz": 0.0}
    mocap["server"] = "10.0.0.5:22223"
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


def test_every_vehicle_of_n_has_its_line_and_unknowns_are_said() -> None:
    """Three UAVs, the third not heard; no estimate (positions unknown) and no tick yet."""
    uavs = status_json()["uavs"]
    lost = uavs[0] | {"connected": False, "px4_mode": "unknown", "battery_v": None}
    lost["position"] = [None, None, None]
    tick = status_json()["tick"] | {"count": 0, "compute_ms_p50": None, "compute_ms_p99": None}
    text = format_status(a_status(uavs=[*uavs, lost], armed=[False] * 3, tick=tick))
    assert "uav3 unknown, px4 unknown, disarmed, link DOWN" in text
    assert "uav2 (+0.765, +0.000, +0.070) m, px4 POSCTL, disarmed, link up, battery 16.2 V" in text
    assert "ticks 0, missed 0, compute p50/p99 0.00/0.00 ms" in text


def test_how_the_last_flight_ended_is_said() -> None:
    assert "last flight" not in format_status(a_status())
    ended = {"ended_in": "abort", "age_s": 12.4}
    assert "last flight ended in abort 12 s ago" in format_status(a_status(last_flight=ended))


def test_a_path_flown_is_said_with_how_far_along_it_is() -> None:
    path = {
        "waypoints": [[0.6, 0.0, 1.0], [0.6, 0.5, 1.2]],
        "speed_mps": 0.4,
        "accel_mps2": 0.5,
        "jerk_mps3": 2.0,
        "length_m": 1.173,
        "duration_s": 4.75,
        "elapsed_s": None,
        "points": [[0.0, 0.0, 1.0], [0.6, 0.5, 1.2]],
    }
    assert "path" not in format_status(a_status(mode="tracking"))
    lines = [
        format_status(a_status(mode="tracking", path=path | {"elapsed_s": elapsed_s}))
        for elapsed_s in (None, 2.04, 6.0)
    ]
    said = "path 1.17 m through 2 waypoints in 4.8 s: "
    assert said + "not begun" in lines[0]
    assert said + "2.0 of 4.8 s" in lines[1]
    assert said + "flown, its end held" in lines[2]
