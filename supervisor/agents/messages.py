"""What crosses Zenoh between the agents and their ground station (docs/agents.md): JSON of
these pydantic models, the encoding of every other process boundary of the project, read
by every side through the same model.

Operator requests are the flight channel's own (``supervisor.flight.operator_requests``),
and an agent's report carries the very ``FlightStatus`` a flight process publishes."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat, StrictInt

from geometry.formation import MAX_VEHICLES
from supervisor.flight.modes import Mode
from supervisor.flight.operator_requests import Reply, Request
from supervisor.flight.status import FlightStatus

Vehicle = Annotated[StrictInt, Field(ge=1, le=MAX_VEHICLES)]
Finite = Annotated[StrictFloat, Field(allow_inf_nan=False)]


class _AgentMessage(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")
    version: Literal[1] = 1


class VehicleReport(_AgentMessage):
    """An agent's own vehicle as its MAVLink link sees it: what its peers' view of that
    vehicle is made of (``supervisor.agents.peer_vehicle``)."""

    connected: StrictBool
    armed: StrictBool
    px4_mode: str
    battery_v: StrictFloat | None = None
    status_text: str = ""


class AgentTick(_AgentMessage):
    """What an agent tells its peers and the ground station every tick."""

    vehicle: Vehicle
    sent_s: Finite
    """Its wall clock (``time.time``) as it sent: an age only where clocks agree."""
    tick: Annotated[StrictInt, Field(ge=0)]
    mode: Mode
    own: VehicleReport
    bar_end_m: list[Finite] | None = Field(default=None, min_length=3, max_length=3)
    """Its estimate of its cable's attachment (null: no estimate)."""
    plan_u: list[list[Finite]] = Field(default_factory=list)
    """Its planned inputs [N, N m], one row (thrust, τx, τy, τz) per stage from now (empty:
    no plan, or not shared)."""
    plan_dt_s: Finite = 0.02
    setpoints_queued: Annotated[StrictInt, Field(ge=0)] = 0
    """How many setpoints it was ever given."""
    setpoints_finished: Annotated[StrictInt, Field(ge=0)] = 0
    """How many of them its queue has ended: an agent given the same setpoints that is
    behind its peers ends its active one too, so that every agent flies the same one."""


class AgentReport(_AgentMessage):
    """An agent's status for its ground station (25 Hz)."""

    vehicle: Vehicle
    host: str
    pid: StrictInt
    sent_s: Finite
    status: FlightStatus


class AgentCommand(_AgentMessage):
    """An operator request from the ground station, with the token it must show."""

    token: str
    request: Request


class AgentAnswer(_AgentMessage):
    """An agent's answer to a command: the reply and the status the request left."""

    vehicle: Vehicle
    reply: Reply
    status: FlightStatus | None = None


class Ping(_AgentMessage):
    kind: Literal["ping"] = "ping"


class Pong(_AgentMessage):
    vehicle: Vehicle
