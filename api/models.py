"""Request and error bodies of the REST API (pydantic: unknown fields, non-finite numbers
and booleans where numbers belong are rejected with 422 and the reason). A setpoint's body
is the operator request's own type, so it is parsed once and travels to the flight process
as it is."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Discriminator, Field, Tag

from supervisor.flight.operator_requests import MAX_SETPOINTS_PER_REQUEST, SetpointFields

SetpointBody = SetpointFields


def _length_first(value: object) -> object:
    """A list's length is checked before any entry is validated: 100 000 entries are
    refused at the cost of reading one number."""
    if isinstance(value, list):
        if not value:
            raise ValueError("an empty list queues nothing")
        if len(value) > MAX_SETPOINTS_PER_REQUEST:
            raise ValueError(
                f"{len(value)} setpoints: one request queues at most "
                f"{MAX_SETPOINTS_PER_REQUEST} (the queue's capacity)"
            )
    return value


SetpointList = Annotated[
    list[SetpointBody],
    BeforeValidator(_length_first),
    Field(min_length=1, max_length=MAX_SETPOINTS_PER_REQUEST),
]


def _setpoint_or_list(value: object) -> str:
    return "list" if isinstance(value, list) else "setpoint"


# One setpoint or a list of them, told apart by the JSON's own type, so that a problem is
# reported once, for the form sent (its loc starts with "setpoint" or "list").
SetpointsBody = Annotated[
    Annotated[SetpointBody, Tag("setpoint")] | Annotated[SetpointList, Tag("list")],
    Discriminator(_setpoint_or_list),
]


def _exactly_true(value: object) -> object:
    # pydantic's Literal[True] takes 1 and 1.0 as True, even in strict mode.
    if value is not True:
        raise ValueError("confirm must be exactly true")
    return value


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ModeBody(_Body):
    """Which MPC flies the bar."""

    controller: Literal["centralized", "decentralized"]


class KillRequest(_Body):
    """Kill stops the motors in the air: the vehicles fall. It must be confirmed with
    ``true`` itself (not 1, not "true")."""

    confirm: Annotated[Literal[True], BeforeValidator(_exactly_true)]


class WaitOutcome(BaseModel):
    """How a request's ``?wait_s=`` ended: the system there, or why not."""

    reached: bool
    message: str


class ErrorBody(BaseModel):
    """Why a request was refused. The flight process's and the world's refusals also say
    ``accepted: false`` and what they know (the mode, the faults in effect). A request
    accepted whose wait (``?wait_s=``) ended without the system getting there says
    ``accepted: true`` and the wait's ``outcome``."""

    model_config = ConfigDict(extra="allow")

    detail: str
    accepted: bool | None = None
    outcome: WaitOutcome | None = None


class Problem(BaseModel):
    """One thing wrong with a request: where (``loc``: body, query, ... then field names
    and list indices), what, and pydantic's error type."""

    loc: list[str | int]
    msg: str
    type: str


class ValidationFailed(BaseModel):
    """A request that does not validate (422): every problem found."""

    model_config = ConfigDict(extra="allow")

    detail: list[Problem]
    accepted: Literal[False] | None = None
