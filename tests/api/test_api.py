"""The REST API and telemetry WebSocket over HTTP on loopback."""

from __future__ import annotations

import asyncio
import json
import math
import re
from typing import Any

import pytest
import websockets

from supervisor.flight.modes import Mode
from supervisor.flight.setpoints import Setpoint, SetpointError
from supervisor.flight.status import Status, WorldStatus
from tests.api.conftest import TOKEN, ApiUnderTest

MUTATING = [
    ("/api/arm", None),
    ("/api/takeoff", None),
    ("/api/land", None),
    ("/api/abort", None),
    ("/api/disarm", None),
    ("/api/kill", {"confirm": True}),
    ("/api/mode", {"controller": "decentralized"}),
    ("/api/setpoints", {"bar_position": [0.0, 0.0, 1.0]}),
    (
        "/api/path",
        {"waypoints": [{"bar_position": [0.5, 0.0, 1.0]}], "speed_mps": 0.4, "accel_mps2": 0.5},
    ),
]
PATH = {
    "waypoints": [
        {"bar_position": [0.2, 0.0, 1.2]},
        {"bar_position": [0.5, 0.0, 1.2], "bar_yaw": 0.3},
        {"bar_position": [0.6, 0.5, 1.2], "theta_l": 0.2},
    ],
    "speed_mps": 0.4,
    "accel_mps2": 0.5,
    "hold_s": 2.0,
}


@pytest.mark.parametrize("token", [None, "wrong-token", "Bearer"])
@pytest.mark.parametrize(("path", "body"), MUTATING)
async def test_mutating_requests_need_the_token(
    api: ApiUnderTest, path: str, body: object, token: str | None
) -> None:
    response = await api.post(path, body, token=token)
    assert response.status_code == 401
    assert response.headers["www-authenticate"] == "Bearer"
    assert api.core.modes.mode is Mode.DISARMED
    assert api.core.controller == "centralized"
    assert api.core.queue.queued == [] and api.core.queue.active is None


async def test_delete_needs_the_token_too(api: ApiUnderTest) -> None:
    assert (await api.post("/api/arm")).status_code == 200  # setpoints are taken once armed
    await api.post("/api/setpoints", {"bar_position": [0.0, 0.0, 1.0]})
    response = await api.http.delete("/api/setpoints")
    assert response.status_code == 401
    assert len(api.core.queue.queued) == 1


async def test_the_status_is_its_model_exactly(api: ApiUnderTest) -> None:
    """What ``GET /api/status`` answers parses as ``Status`` and is nothing but it: every
    key the model has, none it does not, the dashboard's names and nesting."""
    response = await api.http.get("/api/status")
    assert response.status_code == 200
    status = Status.model_validate_json(response.content)
    assert response.json() == status.model_dump(mode="json")
    assert status.mode is Mode.DISARMED and status.controller == "centralized"
    assert status.armed == [False, False] and len(status.uavs) == 2
    assert not status.stale and status.world == WorldStatus(embedded=False)
    assert status.processes == {}
    body = response.json()  # the JSON the dashboard reads (api/static/app.js)
    assert {"position", "ends", "yaw", "velocity", "error_m"} <= set(body["bar"])
    assert {"position", "yaw", "attitude", "connected", "px4_mode"} <= set(body["uavs"][0])
    assert {"active", "queued"} <= set(body["setpoints"]) and "count" in body["tick"]


async def test_the_openapi_document_gives_the_status_its_schema(api: ApiUnderTest) -> None:
    schema = (await api.http.get("/openapi.json")).json()
    answer = schema["paths"]["/api/status"]["get"]["responses"]["200"]["content"]
    assert answer["application/json"]["schema"] == {"$ref": "#/components/schemas/Status"}
    status = schema["components"]["schemas"]["Status"]
    assert status["additionalProperties"] is False
    assert set(status["required"]) >= set(Status.model_fields) - {"processes"}
    armed = status["properties"]["armed"]
    assert (armed["minItems"], armed["maxItems"]) == (2, 8)
    tick = schema["components"]["schemas"]["TickSummary"]["properties"]
    assert "[ms]" in tick["compute_ms_p50"]["description"]


async def test_a_refused_transition_is_409_with_the_reason(api: ApiUnderTest) -> None:
    response = await api.post("/api/takeoff")
    assert response.status_code == 409
    assert "not allowed in mode 'disarmed'" in response.json()["detail"]
    assert api.core.modes.mode is Mode.DISARMED


async def test_arm_then_disarm(api: ApiUnderTest) -> None:
    response = await api.post("/api/arm")
    assert response.status_code == 200 and response.json() == {"accepted": True, "mode": "armed"}
    assert (await api.post("/api/arm")).status_code == 409
    assert (await api.post("/api/disarm")).json()["mode"] == "disarmed"


async def test_kill_needs_confirmation(api: ApiUnderTest) -> None:
    await api.post("/api/arm")
    for body in (None, {}, {"confirm": False}, {"confirm": "yes"}):
        response = await api.post("/api/kill", body)
        assert response.status_code == 422, body
        assert api.core.modes.mode is Mode.ARMED
    response = await api.post("/api/kill", {"confirm": True})
    assert response.status_code == 200 and response.json()["mode"] == "killed"


async def test_abort_is_always_accepted(api: ApiUnderTest) -> None:
    for _ in range(2):
        response = await api.post("/api/abort")
        assert response.status_code == 200


async def test_controller_switch(api: ApiUnderTest) -> None:
    response = await api.post("/api/mode", {"controller": "decentralized"})
    assert response.status_code == 200 and response.json()["controller"] == "decentralized"
    assert api.core.controller == "decentralized"
    bad = await api.post("/api/mode", {"controller": "pid"})
    assert bad.status_code == 422
    assert api.core.controller == "decentralized"


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        ({"bar_position": [0.0, 0.0, 1.0], "theta_l": 1.7}, "less than 1.57"),
        ({"bar_position": [0.0, 0.0]}, "at least 3"),
        ({"bar_position": [0.0, 0.0, 1.0], "hold_s": -1}, "greater than or equal to 0"),
        ({"bar_position": [0.0, 0.0, 1.0], "colour": "red"}, "Extra inputs"),
        ({"bar_position": ["a", 0.0, 1.0]}, "valid number"),
        ([], "empty list"),
    ],
)
async def test_bad_setpoints_are_422_and_queue_nothing(
    api: ApiUnderTest, body: object, reason: str
) -> None:
    response = await api.post("/api/setpoints", body)
    assert response.status_code == 422
    assert reason in json.dumps(response.json())
    assert api.core.queue.queued == []


async def test_a_setpoint_that_cannot_be_flown_here_is_409_and_queues_nothing(
    api: ApiUnderTest,
) -> None:
    """Well-formed (its schema holds) but outside this arena: refused, as a full queue is."""
    response = await api.post("/api/setpoints", {"bar_position": [0.0, 0.0, 2.5]})
    assert response.status_code == 409
    assert "outside the arena" in response.json()["detail"]
    assert api.core.queue.queued == []


@pytest.mark.parametrize(
    ("theta_l_deg", "bound"),
    [
        (85.0, "θ_l 85.0° exceeds the maximum 75.0° by 10.0°"),
        (80.0, "UAV 1's equilibrium tilt"),
        (89.9, "equilibrium thrust"),
    ],
)
async def test_a_setpoint_the_vehicles_cannot_hold_is_409_naming_the_bound(
    api: ApiUnderTest, theta_l_deg: float, bound: str
) -> None:
    assert (await api.post("/api/arm")).status_code == 200
    theta_l = math.radians(theta_l_deg)
    response = await api.post(
        "/api/setpoints", {"bar_position": [0.0, 0.0, 1.5], "theta_l": theta_l}
    )
    assert response.status_code == 409
    assert bound in response.json()["detail"]
    assert api.core.queue.queued == []
    # The tick core itself, the authority behind the API, refuses it for the same reason.
    with pytest.raises(SetpointError, match=bound):
        api.core.queue_setpoints([Setpoint((0.0, 0.0, 1.5), theta_l_rad=theta_l)])


async def test_non_finite_numbers_are_refused(api: ApiUnderTest) -> None:
    content = '{"bar_position": [NaN, 0.0, 1.0]}'
    response = await api.http.post(
        "/api/setpoints",
        content=content,
        headers={"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"},
    )
    assert response.status_code == 422
    assert api.core.queue.queued == []


async def test_a_list_is_queued_all_or_none(api: ApiUnderTest) -> None:
    good = {"bar_position": [0.5, 0.0, 1.0], "bar_yaw": 0.3, "hold_s": 2}
    bad = {"bar_position": [9.0, 0.0, 1.0]}
    assert (await api.post("/api/arm")).status_code == 200
    response = await api.post("/api/setpoints", [good, bad])
    assert response.status_code == 409 and "setpoint 1" in response.json()["detail"]
    assert api.core.queue.queued == []
    response = await api.post("/api/setpoints", [good, good])
    assert response.status_code == 200 and response.json()["queued"] == 2
    listed = (await api.http.get("/api/setpoints")).json()
    assert listed["active"] is None
    assert [q["bar_position"] for q in listed["queued"]] == [[0.5, 0.0, 1.0]] * 2
    assert listed["queued"][0]["uav_yaw"] == [0.3, 0.3]  # defaults to the bar yaw
    response = await api.http.delete("/api/setpoints", headers={"Authorization": f"Bearer {TOKEN}"})
    assert response.status_code == 200
    assert api.core.queue.queued == []


async def test_a_full_queue_is_409(api: ApiUnderTest) -> None:
    entry = {"bar_position": [0.0, 0.0, 1.0]}
    capacity = api.core.queue.capacity
    assert (await api.post("/api/arm")).status_code == 200
    assert (await api.post("/api/setpoints", [entry] * capacity)).status_code == 200
    response = await api.post("/api/setpoints", entry)
    assert response.status_code == 409 and "at most" in response.json()["detail"]
    assert len(api.core.queue.queued) == capacity


async def test_a_path_is_queued_as_its_end_and_answers_its_timing(api: ApiUnderTest) -> None:
    refused = await api.post("/api/path", PATH)  # the tick core's mode table
    assert refused.status_code == 409 and "not allowed in mode 'disarmed'" in refused.text
    assert (await api.post("/api/arm")).status_code == 200
    response = await api.post("/api/path", PATH)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["accepted"] and answer["queued"] == 1
    assert 1.0 < answer["length_m"] < 1.5 and answer["duration_s"] > 1.0 / 0.4
    [end] = api.core.queue.queued
    assert end.path is not None and end.path.timed.duration_s == answer["duration_s"]
    listed = (await api.http.get("/api/setpoints")).json()["queued"]
    assert listed[0]["bar_position"] == pytest.approx([0.6, 0.5, 1.2])
    assert listed[0]["bar_yaw"] == pytest.approx(0.3) and listed[0]["hold_s"] == 2.0


NAMED = {"bar_yaw": 0.0, "theta_l": 0.0}  # a waypoint's yaw and θ_l, named


@pytest.mark.parametrize(
    ("waypoints", "reason"),
    [
        ([[0.0, 0.0, 2.9]], "waypoint 0: bar centre would be at (0.00, 0.00, 2.90) m, outside"),
        ([[0.0, 0.0, 1.0], [0.0, -2.9, 1.0]], "waypoint 1: bar centre would be at (0.00, -2.90"),
        # Its yaw and θ_l named (here, by the waypoint before): checked as a setpoint at rest,
        # its bar's ends and its UAVs too.
        ([[0.0, 0.0, 1.0, NAMED], [2.5, 0.0, 1.0]], "waypoint 1: bar end 2 would be at (3.2"),
        (
            [[0.0, 0.0, 1.5, {"bar_yaw": 0.0, "theta_l": math.radians(85)}]],
            "waypoint 0: θ_l 85.0° exceeds the maximum 75.0° by 10.0°",
        ),
        # Its yaw not yet named, the bar's ends depend on the start's: left to the tick core,
        # which refuses it along the path.
        ([[0.0, 0.0, 1.0], [2.5, 0.0, 1.0]], "s along the path: bar end 2 would be at"),
    ],
)
async def test_a_path_that_cannot_be_flown_is_409_by_its_waypoint_before_the_flight_process(
    api: ApiUnderTest, waypoints: list[list[Any]], reason: str
) -> None:
    """The API process refuses what it can know from the waypoints, naming the waypoint;
    the tick core, what only the start shows, naming the time along the path. Nothing is
    queued."""
    assert (await api.post("/api/arm")).status_code == 200
    points = [
        {"bar_position": point[:3], **(point[3] if len(point) > 3 else {})} for point in waypoints
    ]
    response = await api.post("/api/path", {**PATH, "waypoints": points})
    assert response.status_code == 409, response.text
    assert response.json()["accepted"] is False
    assert reason in response.json()["detail"], response.json()["detail"]
    assert api.core.queue.queued == []


@pytest.mark.parametrize(
    ("changes", "reason"),
    [
        ({"waypoints": []}, "at least 1 item"),
        ({"speed_mps": 0}, "greater than 0"),
        ({"accel_mps2": None}, "valid number"),
        ({"jerk_mps3": True}, "valid number"),
        ({"hold_s": -1}, "greater than or equal to 0"),
        ({"colour": "red"}, "Extra inputs"),
        ({"waypoints": [{"bar_position": [0.0, 1.0]}]}, "at least 3 items"),
        ({"waypoints": [{"bar_position": [0.0, 0.0, 1.0], "uav_yaw": [0, 0]}]}, "Extra inputs"),
    ],
)
async def test_a_path_that_does_not_fit_its_schema_is_422(
    api: ApiUnderTest, changes: dict[str, object], reason: str
) -> None:
    assert (await api.post("/api/arm")).status_code == 200
    response = await api.post("/api/path", {**PATH, **changes})
    assert response.status_code == 422
    assert reason in json.dumps(response.json())
    assert api.core.queue.queued == []


async def test_equilibria(api: ApiUnderTest) -> None:
    response = await api.http.get("/api/equilibria", params={"theta_l": math.pi / 4})
    assert response.status_code == 200
    body = response.json()
    assert body["theta_l"] == pytest.approx(math.pi / 4)
    assert 0.0 < body["theta_f"] < body["theta_l"]
    assert len(body["uav_positions"]) == 2
    assert body["refusals"] == []
    steep = (await api.http.get("/api/equilibria", params={"theta_l": math.radians(86)})).json()
    assert any("exceeds the maximum 75.0° by 11.0°" in r for r in steep["refusals"])
    assert any("equilibrium thrust" in r for r in steep["refusals"])
    for value in ("2.0", "-0.1", "nan", "x"):
        assert (await api.http.get(f"/api/equilibria?theta_l={value}")).status_code == 422


async def test_telemetry_websocket_passes_on_every_message_of_the_flight_process(
    api: ApiUnderTest,
) -> None:
    """The flight process publishes at 25 Hz (here the fixture, its messages numbered in
    ``tick.count``): a client that reads gets each one, none skipped, so it gets that rate.
    (The rate itself, on a shared machine, is the fixture's; benchmarks time it.)"""
    url = api.url.replace("http", "ws") + "/api/telemetry"
    async with websockets.connect(url) as ws:
        await ws.recv()
        messages = [Status.model_validate_json(await ws.recv()) for _ in range(10)]
    assert all(m.mode is Mode.DISARMED for m in messages)
    counts = [m.tick.count for m in messages]
    assert counts == list(range(counts[0], counts[0] + 10)), counts


async def test_openapi_schema_lists_the_routes(api: ApiUnderTest) -> None:
    schema = (await api.http.get("/openapi.json")).json()
    for path in (
        "/api/status",
        "/api/arm",
        "/api/kill",
        "/api/mode",
        "/api/setpoints",
        "/api/path",
    ):
        assert path in schema["paths"]


async def test_the_schema_gives_each_setpoint_field_its_unit(api: ApiUnderTest) -> None:
    """The REST API is in SI units, radians for angles; the schema names each (the CLI and
    the dashboard take degrees, and say so)."""
    schema = (await api.http.get("/openapi.json")).json()
    fields = schema["components"]["schemas"]["SetpointFields"]["properties"]
    assert set(fields) == {"bar_position", "bar_yaw", "uav_yaw", "theta_l", "hold_s", "timeout_s"}
    units = {
        name: re.search(r"\[(m|rad|s)\]", field.get("description", ""))
        for name, field in fields.items()
    }
    assert all(units.values()), {name: fields[name] for name, unit in units.items() if not unit}
    assert {name: unit.group(1) for name, unit in units.items() if unit} == {
        "bar_position": "m",
        "bar_yaw": "rad",
        "uav_yaw": "rad",
        "theta_l": "rad",
        "hold_s": "s",
        "timeout_s": "s",
    }


async def test_a_request_with_wait_s_answers_once_the_system_is_there(api: ApiUnderTest) -> None:
    """The telemetry shows the new controller within a period: 200 with the outcome."""
    response = await api.post("/api/mode?wait_s=5", {"controller": "decentralized"})
    assert response.status_code == 200, response.text
    assert response.json()["outcome"] == {"reached": True, "message": "controller decentralized"}


async def test_a_request_with_wait_s_that_never_gets_there_is_409_with_why(
    api: ApiUnderTest,
) -> None:
    """Accepted, but the vehicles (here: never armed by PX4) do not get there in time: 409,
    ``accepted`` still true, and the wait's reason; the request's answer took the wait."""
    started = asyncio.get_running_loop().time()
    response = await api.post("/api/arm?wait_s=0.3")
    waited_s = asyncio.get_running_loop().time() - started
    assert response.status_code == 409, response.text
    body = response.json()
    assert body["accepted"] is True and body["mode"] == "armed"
    assert body["outcome"]["reached"] is False
    assert body["detail"] == body["outcome"]["message"]
    assert body["detail"].startswith("not there after 0.3 s (mode armed")
    assert waited_s >= 0.3


async def test_a_refused_request_with_wait_s_is_answered_at_once(api: ApiUnderTest) -> None:
    response = await api.post("/api/takeoff?wait_s=60")
    assert response.status_code == 409
    assert "outcome" not in response.json()
    assert "not allowed in mode 'disarmed'" in response.json()["detail"]


@pytest.mark.parametrize("wait_s", ["0", "-1", "nan", "inf", "601", "soon"])
async def test_a_wait_beyond_its_range_is_422_and_nothing_is_sent(
    api: ApiUnderTest, wait_s: str
) -> None:
    response = await api.post(f"/api/arm?wait_s={wait_s}")
    assert response.status_code == 422, (wait_s, response.text)
    assert "wait_s" in response.text
    assert api.core.modes.mode is Mode.DISARMED
