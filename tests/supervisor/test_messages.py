"""Typed messages between the processes: one parse, strict types, no NaN in JSON."""

from __future__ import annotations

import math

import pydantic
import pytest

from supervisor.flight.operator_requests import (
    ModeRequest,
    Outcome,
    QueueRequest,
    Reply,
    SetpointFields,
    is_urgent,
)
from supervisor.flight.status import FlightStatus
from supervisor.ipc.messages import (
    CHANNEL_MESSAGE,
    ReplyMessage,
    RequestMessage,
    TelemetryMessage,
)
from tests.status_examples import flight_status_json, status_json


def test_a_request_survives_the_channel_as_its_type() -> None:
    setpoint = SetpointFields(bar_position=[0.5, 0.0, 1.2], theta_l=0.3, timeout_s=12.0)
    sent = RequestMessage(id=7, request=QueueRequest(setpoints=[setpoint]))
    received = CHANNEL_MESSAGE.validate_json(sent.model_dump_json())
    assert received == sent and isinstance(received, RequestMessage)
    assert isinstance(received.request, QueueRequest)
    assert received.request.setpoints[0].to_setpoint().timeout_s == 12.0


def test_replies_and_telemetry_carry_nan_as_null() -> None:
    reply = ReplyMessage(id=1, reply=Reply(outcome=Outcome.OK, data={"x": math.nan}))
    assert '"x":null' in reply.model_dump_json()
    bar = status_json()["bar"] | {"yaw": math.inf}
    status = TelemetryMessage(status=FlightStatus.model_validate(flight_status_json(bar=bar)))
    text = status.model_dump_json()
    assert '"yaw":null' in text
    decoded = CHANNEL_MESSAGE.validate_json(text)
    assert isinstance(decoded, TelemetryMessage) and decoded.status.bar.yaw is None


def test_telemetry_that_is_not_a_status_is_refused_at_the_parse() -> None:
    telemetry = {"type": "telemetry", "status": {"bar": {"yaw": 0.0}}}
    with pytest.raises(pydantic.ValidationError, match=r"status\.mode"):
        CHANNEL_MESSAGE.validate_python(telemetry)


@pytest.mark.parametrize(
    "body",
    [
        {"kind": "fly_away"},
        {"kind": "kill", "confirm": 1},
        {"kind": "queue", "setpoints": []},
        {"kind": "queue", "setpoints": [{"bar_position": [True, 0, 1]}]},
        {"kind": "queue", "setpoints": [{"bar_position": [0, 0, 1], "hold_s": -1}]},
        {"kind": "controller", "controller": "lqr"},
    ],
)
def test_malformed_requests_are_refused_at_the_parse(body: dict[str, object]) -> None:
    with pytest.raises(pydantic.ValidationError):
        CHANNEL_MESSAGE.validate_python({"type": "request", "id": 1, "request": body})


def test_abort_and_kill_take_the_urgent_channel() -> None:
    assert is_urgent(ModeRequest(kind="abort")) and is_urgent(ModeRequest(kind="kill"))
    assert not is_urgent(ModeRequest(kind="land"))
