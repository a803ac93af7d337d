"""The messages between the API process and the simulated world's process (``serve`` with
``sim.embedded``), typed: fault injection and the world reset (docs/faults.md).

A fault is a JSON object discriminated on ``kind``, the same type the REST body of
``POST /api/sim/faults`` is parsed into, so a malformed one is refused (422, naming the
field) before it leaves the API process. The world checks it again as the authority
(``sim.faults.parse_fault``: the rigid body must be one QTM streams, the vehicle one of
its 1 … N) — the kinds and their fields here mirror ``sim.faults``, which the API process
may not import; a test holds the two equal. A request is discriminated on ``action``; the
reply is the flight channel's ``Reply`` (outcome, reason, data).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, TypeAdapter

from geometry.formation import MAX_VEHICLES
from supervisor.flight.operator_requests import Reply

# The bounds of sim.faults (MAX_DURATION_S, MAX_OFFSET_M, PUSH_MAX_N), which this module
# may not import.
Seconds = Annotated[
    float, Field(gt=0.0, le=3600.0, strict=True, description="seconds, > 0, at most 3600")
]
Coordinate = Annotated[
    float, Field(ge=-20.0, le=20.0, strict=True, description="metres, within ±20")
]


def _integral_number(value: object) -> object:
    # JSON Schema's "integer" is any number without a fraction (1.0 is one); a boolean or a
    # string is not a number, and strict int still refuses those.
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return value


Vehicle = Annotated[
    int,
    Field(
        ge=1,
        le=MAX_VEHICLES,
        strict=True,
        description=f"a vehicle number, 1 to {MAX_VEHICLES} (the world's: 1 to its N)",
    ),
    BeforeValidator(_integral_number),
]
Body = Annotated[str, Field(min_length=1, description="a rigid body of mocap.bodies")]


class _Fault(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    duration_s: Seconds | None = None
    """How long it lasts [s]; absent: until cleared (``px4_reboot``: its boot time, 3 s)."""


class MocapSilentFault(_Fault):
    """The whole QTM stream stops: no frames at all."""

    kind: Literal["mocap_silent"]


class MocapBodyLostFault(_Fault):
    """``body`` is reported untracked (NaN 6D record); the others stream."""

    kind: Literal["mocap_body_lost"]
    body: Body


class MocapFreezeFault(_Fault):
    """Frames keep coming (new frame numbers and timestamps) with the same poses."""

    kind: Literal["mocap_freeze"]


class MocapJumpFault(_Fault):
    """``body``'s reported position is offset by ``offset_m`` (arena frame)."""

    kind: Literal["mocap_jump"]
    body: Body
    offset_m: tuple[Coordinate, Coordinate, Coordinate]


class LinkLostFault(_Fault):
    """Every MAVLink datagram to and from ``vehicle`` is dropped."""

    kind: Literal["link_lost"]
    vehicle: Vehicle


class Px4RebootFault(_Fault):
    """``vehicle``'s PX4 reboots: motors off, silent for ``duration_s`` (default 3 s)."""

    kind: Literal["px4_reboot"]
    vehicle: Vehicle


class UdpLossFault(_Fault):
    """That ``fraction`` of the world's UDP datagrams (mocap, MAVLink) is dropped."""

    kind: Literal["udp_loss"]
    fraction: Annotated[float, Field(ge=0.0, le=1.0, strict=True)]


PushComponent = Annotated[
    float, Field(ge=-50.0, le=50.0, strict=True, description="newtons, within ±50")
]  # PUSH_MAX_N


class PushFault(_Fault):
    """A force ``force_n`` [N] (arena frame) at ``body``'s centre of mass acts on the plant."""

    kind: Literal["push"]
    body: Body
    force_n: tuple[PushComponent, PushComponent, PushComponent]


FaultSpec = Annotated[
    MocapSilentFault
    | MocapBodyLostFault
    | MocapFreezeFault
    | MocapJumpFault
    | LinkLostFault
    | Px4RebootFault
    | UdpLossFault
    | PushFault,
    Field(discriminator="kind"),
]
"""A fault to inject, as the REST body and the channel carry it."""


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class StartFault(_Request):
    """Put a fault in effect (one of its kind on the same target is replaced)."""

    action: Literal["start_fault"] = "start_fault"
    fault: FaultSpec


class ClearFaults(_Request):
    """End every fault."""

    action: Literal["clear_faults"] = "clear_faults"


class ListFaults(_Request):
    """The faults in effect."""

    action: Literal["list_faults"] = "list_faults"


class ResetWorld(_Request):
    """Back to the resting pose (refused while a vehicle is armed)."""

    action: Literal["reset"] = "reset"


WorldRequest = Annotated[
    StartFault | ClearFaults | ListFaults | ResetWorld, Field(discriminator="action")
]


class _Envelope(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, ser_json_inf_nan="null")


class WorldRequestMessage(_Envelope):
    type: Literal["world_request"] = "world_request"
    id: int
    request: WorldRequest


class WorldReplyMessage(_Envelope):
    type: Literal["world_reply"] = "world_reply"
    id: int
    reply: Reply


WorldMessage = WorldRequestMessage | WorldReplyMessage
WORLD_MESSAGE: TypeAdapter[WorldMessage] = TypeAdapter(
    Annotated[WorldMessage, Field(discriminator="type")]
)
