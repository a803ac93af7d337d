"""The messages on a channel between the API process and the flight process, typed.

Each is a JSON object discriminated on ``type``: a ``hello`` (the first message of a
connection to the flight process: its role and the API token), a ``request`` (an operator
request with the ``id`` its reply repeats), a ``reply``, or ``telemetry`` (the status the
flight process pushes at 25 Hz, ``supervisor.flight.status.FlightStatus``). JSON has no NaN:
the serializer writes non-finite numbers as null.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from supervisor.flight.operator_requests import Reply, Request
from supervisor.flight.status import FlightStatus


class _Envelope(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")


ConnectionRole = Literal["commands", "urgent", "operator"]


class HelloMessage(_Envelope):
    """Who connects: ``commands`` (every request, and the telemetry stream) and ``urgent``
    (abort and kill, never behind anything else) are the API process's, and need the
    token; ``operator`` is the terminal client's direct path: abort, and kill with the
    token."""

    type: Literal["hello"] = "hello"
    role: ConnectionRole
    token: str | None = None


class RequestMessage(_Envelope):
    type: Literal["request"] = "request"
    id: int
    request: Request


class ReplyMessage(_Envelope):
    type: Literal["reply"] = "reply"
    id: int
    reply: Reply


class TelemetryMessage(_Envelope):
    type: Literal["telemetry"] = "telemetry"
    status: FlightStatus


ChannelMessage = HelloMessage | RequestMessage | ReplyMessage | TelemetryMessage
CHANNEL_MESSAGE: TypeAdapter[ChannelMessage] = TypeAdapter(
    Annotated[ChannelMessage, Field(discriminator="type")]
)
