"""The messages on a channel between the API process and the flight process, typed.

Each is a JSON object discriminated on ``type``: a ``request`` (an operator request with
the ``id`` its reply repeats), a ``reply``, or ``telemetry`` (the status the flight process
pushes at 25 Hz). JSON has no NaN: the serializer writes non-finite numbers as null.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, TypeAdapter

from supervisor.flight.operator_requests import Reply, Request


class _Envelope(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")


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
    status: dict[str, Any]


ChannelMessage = RequestMessage | ReplyMessage | TelemetryMessage
CHANNEL_MESSAGE: TypeAdapter[ChannelMessage] = TypeAdapter(
    Annotated[ChannelMessage, Field(discriminator="type")]
)
