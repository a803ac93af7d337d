"""Request bodies of the REST API (pydantic: unknown fields and non-finite numbers are
rejected with 422 and the reason). A setpoint's body is the operator request's own type, so
it is parsed once and travels to the flight process as it is."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict

from supervisor.flight.operator_requests import SetpointFields

SetpointBody = SetpointFields


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ModeBody(_Body):
    """Which MPC flies the bar."""

    controller: Literal["centralized", "decentralized"]


class KillRequest(_Body):
    """Kill stops the motors in the air: the vehicles fall. It must be confirmed."""

    confirm: Literal[True]
