"""The fleet's status from its agents' reports, and the operator's reply from theirs."""

from __future__ import annotations

from supervisor.agents.ground import combined_reply
from supervisor.agents.messages import AgentAnswer, AgentReport
from supervisor.agents.status_merge import merged_status
from supervisor.flight.operator_requests import Outcome, Reply
from supervisor.flight.status import AgentStatus, FlightStatus
from tests.status_examples import flight_status_json


def _report(vehicle: int, mode: str, notices: list[dict[str, object]] | None = None) -> AgentReport:
    status = flight_status_json(mode=mode, notices=notices or [])
    status["armed"] = [mode != "disarmed"] * 2
    status["uavs"][vehicle - 1]["px4_mode"] = f"seen by agent {vehicle}"
    return AgentReport(
        vehicle=vehicle,
        host="h",
        pid=1000 + vehicle,
        sent_s=0.0,
        status=FlightStatus.model_validate(status),
    )


AGENTS = [
    AgentStatus(
        vehicle=i, alive=True, pid=1000 + i, mode=None, link_latency_ms=0.1, last_message_age_s=0
    )
    for i in (1, 2)
]


def test_the_least_safe_agent_speaks_and_each_vehicle_is_its_own_agents() -> None:
    fresh = {1: _report(1, "disarmed"), 2: _report(2, "hover")}
    status = merged_status(fresh, AGENTS, now_s=7.0)
    assert status is not None
    assert status.mode.value == "hover"  # never a safer state than a vehicle is in
    assert [u.px4_mode for u in status.uavs] == ["seen by agent 1", "seen by agent 2"]
    assert status.armed == [False, True]
    assert status.agents == AGENTS and status.time_s == 7.0


def test_no_fresh_report_says_nothing_rather_than_something_old() -> None:
    assert merged_status({}, AGENTS, now_s=7.0) is None


def test_notices_of_every_agent_once_each_oldest_first() -> None:
    same = {"age_s": 2.0, "message": "ground: ground station lost"}
    fresh = {
        1: _report(1, "hover", [same, {"age_s": 5.0, "message": "vehicle: one"}]),
        2: _report(2, "hover", [{**same, "age_s": 1.5}]),
    }
    status = merged_status(fresh, AGENTS, now_s=0.0)
    assert status is not None
    assert [(n.message, n.age_s) for n in status.notices] == [
        ("vehicle: one", 5.0),
        ("ground: ground station lost", 1.5),
    ]


def _answer(vehicle: int, outcome: Outcome, reason: str = "") -> AgentAnswer:
    return AgentAnswer(vehicle=vehicle, reply=Reply(outcome=outcome, reason=reason))


def test_the_reply_is_ok_only_when_every_agent_says_so() -> None:
    ok = {1: _answer(1, Outcome.OK), 2: _answer(2, Outcome.OK)}
    assert combined_reply((1, 2), ok).ok
    refused = {1: _answer(1, Outcome.OK), 2: _answer(2, Outcome.REFUSED, "no room")}
    reply = combined_reply((1, 2), refused)
    assert reply.outcome is Outcome.REFUSED and reply.reason == "vehicle 2: no room"
    silent = combined_reply((1, 2), {1: ok[1]})
    assert silent.outcome is Outcome.UNAVAILABLE and "vehicle 2's agent" in silent.reason
