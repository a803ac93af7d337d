"""``--wait``'s goals on status answers, and the polling loop on a simulated clock."""

from __future__ import annotations

from typing import Any

from supervisor.cli.awaiting import await_goal
from supervisor.flight import outcomes
from supervisor.flight.operator_requests import SetpointFields
from supervisor.flight.outcomes import Verdict
from supervisor.flight.status import Status
from tests.status_examples import a_status, status_json


def status(mode: str, *notices: tuple[float, str], **extra: Any) -> Status:
    said = [{"age_s": age_s, "message": text} for age_s, text in notices]
    return a_status(**{"mode": mode, "armed": [mode != "disarmed"] * 2, "notices": said, **extra})


def test_takeoff_is_reached_in_hover_and_fails_with_the_abort_s_notice() -> None:
    assert outcomes.hovering(status("takeoff"), 3.0) is None
    reached = outcomes.hovering(status("hover"), 8.0)
    assert reached is not None and reached.reached
    old = (30.0, "abort: vehicle 2 link lost")  # from an earlier flight: not this one's reason
    new = (1.5, "abort: vehicle 1 link lost")
    failed = outcomes.hovering(status("abort", old, new), 4.0)
    assert failed is not None and failed.verdict is Verdict.FAILED
    assert failed.message == "take-off failed: abort: vehicle 1 link lost"
    without = outcomes.hovering(status("abort", old), 4.0)
    assert without is not None and "the system is in mode abort" in without.message


def test_land_is_reached_disarmed_on_the_ground_and_fails_killed() -> None:
    assert outcomes.landed(status("landing"), 2.0) is None
    armed_still = status("disarmed", armed=[False, True])
    assert outcomes.landed(armed_still, 2.0) is None  # PX4 has not said so yet
    landed = outcomes.landed(status("disarmed"), 9.0)
    assert landed is not None and landed.reached
    killed = outcomes.landed(status("killed"), 1.0)
    assert killed is not None and not killed.reached


def test_arm_fails_on_a_vehicle_s_notice() -> None:
    assert outcomes.armed(status("disarmed"), 0.1) is None  # the status not yet updated
    refused = outcomes.armed(status("disarmed", (0.5, "vehicle: arming refused: no GPS")), 1.0)
    assert refused is not None and "arming refused: no GPS" in refused.message


def test_an_arm_waits_for_every_one_of_n_vehicles() -> None:
    """Three vehicles: armed once all three PX4s say so."""
    uavs = status_json()["uavs"]
    three = [*uavs, uavs[0]]
    assert outcomes.armed(status("armed", armed=[True, True, False], uavs=three), 0.5) is None
    reached = outcomes.armed(status("armed", armed=[True] * 3, uavs=three), 0.5)
    assert reached is not None and reached.reached


def test_a_setpoint_is_flown_once_it_has_left_the_queue() -> None:
    wanted = SetpointFields(bar_position=[0.3, 0.0, 1.1], hold_s=1.0)
    shown = {**wanted.model_dump(), "uav_yaw": [0.0, 0.0]}
    goal = outcomes.setpoint_flown(wanted)
    other = {**shown, "bar_position": [0.0, 0.0, 1.0]}
    assert goal(status("tracking", setpoints={"active": other, "queued": [shown]}), 0.2) is None
    assert goal(status("tracking", setpoints={"active": shown, "queued": []}), 2.0) is None
    flown = goal(status("hover", setpoints={"active": None, "queued": []}), 6.0)
    assert flown is not None and flown.reached
    aborted = outcomes.setpoint_flown(wanted)(status("abort", (0.4, "abort: UAV 1 tilted 50°")), 1)
    assert aborted is not None and aborted.message.endswith("abort: UAV 1 tilted 50°")


def a_path(waypoints: list[list[float]], elapsed_s: float | None) -> dict[str, Any]:
    """The status's ``path`` of a path through ``waypoints``, 5 s long."""
    return {
        "waypoints": waypoints,
        "speed_mps": 0.4,
        "accel_mps2": 0.5,
        "jerk_mps3": 2.0,
        "length_m": 1.2,
        "duration_s": 5.0,
        "elapsed_s": elapsed_s,
        "points": [[0.0, 0.0, 1.0], *waypoints],
    }


def test_a_path_is_flown_once_it_is_no_longer_the_active_setpoint() -> None:
    wanted = [[0.6, 0.0, 1.0], [0.6, 0.5, 1.2]]
    end = {**SetpointFields(bar_position=[0.6, 0.5, 1.2]).model_dump(), "uav_yaw": [0.0, 0.0]}
    flying = {"active": end, "queued": []}
    goal = outcomes.path_flown(wanted)
    other = a_path([[0.0, 0.5, 1.0]], 2.0)  # one queued before it
    assert goal(status("tracking", path=other, setpoints=flying | {"queued": [end]}), 0.2) is None
    assert goal(status("tracking", path=a_path(wanted, None), setpoints=flying), 1.0) is None
    assert goal(status("tracking", path=a_path(wanted, 6.5), setpoints=flying), 8.0) is None
    flown = goal(status("hover", setpoints={"active": None, "queued": []}), 9.0)
    assert flown is not None and flown.reached and flown.message.startswith("path flown")
    between_polls = outcomes.path_flown(wanted)  # never seen: flown once idle for a second
    assert between_polls(status("hover"), 0.5) is None
    assert (unseen := between_polls(status("hover"), 1.5)) is not None and unseen.reached
    landing = outcomes.path_flown(wanted)(status("abort", (0.4, "abort: UAV 1 tilted 50°")), 1)
    assert landing is not None and landing.message == "path not flown: abort: UAV 1 tilted 50°"


def test_the_wait_gives_up_after_its_timeout_and_on_a_silent_flight_process() -> None:
    now = [0.0]

    def sleep(seconds: float) -> None:
        now[0] += seconds

    climbing = await_goal(
        outcomes.hovering, lambda: status("takeoff"), 0.0, 5.0, lambda: now[0], sleep
    )
    assert climbing.verdict is Verdict.FAILED and "not there after 5 s" in climbing.message
    assert 5.0 < now[0] < 5.5
    now[0] = 0.0
    stale = await_goal(
        outcomes.hovering, lambda: status("hover", stale=True), 0.0, 60.0, lambda: now[0], sleep
    )
    assert not stale.reached and "has not reported" in stale.message and now[0] < 4.0
