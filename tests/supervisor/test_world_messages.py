"""The world channel's messages: one parse, strict types, the same kinds and fields as the
world's own fault model, and a round trip over a real socket pair."""

from __future__ import annotations

import asyncio
import math
import socket
from typing import Any, get_args

import pydantic
import pytest

from sim.faults import KINDS, parameter_names
from supervisor.flight.operator_requests import Outcome, Reply
from supervisor.ipc.channel import WorldChannel
from supervisor.ipc.world_client import WORLD_GONE, WorldClient, serve_world_requests
from supervisor.ipc.world_messages import (
    WORLD_MESSAGE,
    FaultSpec,
    LinkLostFault,
    ListFaults,
    MocapJumpFault,
    Px4RebootFault,
    StartFault,
    WorldRequest,
    WorldRequestMessage,
)

FAULT = pydantic.TypeAdapter(FaultSpec)


def test_the_schema_has_the_same_kinds_and_fields_as_the_worlds_model() -> None:
    """The API process may not import sim: its copy is held equal here, kind by kind."""
    union = get_args(get_args(FaultSpec)[0])
    schema = {
        get_args(model.model_fields["kind"].annotation)[0]: set(model.model_fields) - {"kind"}
        for model in union
    }
    assert schema == {kind: {*parameter_names(t), "duration_s"} for kind, t in KINDS.items()}


def test_a_fault_survives_the_channel_as_its_type() -> None:
    fault = FAULT.validate_python({"kind": "mocap_jump", "body": "bar", "offset_m": [0, 0.1, 0]})
    sent = WorldRequestMessage(id=3, request=StartFault(fault=fault))
    received = WORLD_MESSAGE.validate_json(sent.model_dump_json())
    assert received == sent and isinstance(received, WorldRequestMessage)
    assert isinstance(received.request, StartFault)
    assert isinstance(received.request.fault, MocapJumpFault)
    assert received.request.fault.offset_m == (0.0, 0.1, 0.0)


@pytest.mark.parametrize(
    ("body", "where"),
    [
        ({"kind": "meteor"}, ()),
        ({}, ()),
        ({"kind": "mocap_silent", "body": "bar"}, ("mocap_silent", "body")),
        ({"kind": "mocap_body_lost"}, ("mocap_body_lost", "body")),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [0, 0]}, ("mocap_jump", "offset_m")),
        ({"kind": "link_lost", "vehicle": 0}, ("link_lost", "vehicle")),
        ({"kind": "link_lost", "vehicle": 9}, ("link_lost", "vehicle")),
        ({"kind": "link_lost", "vehicle": True}, ("link_lost", "vehicle")),
        ({"kind": "link_lost", "vehicle": "1"}, ("link_lost", "vehicle")),
        ({"kind": "link_lost", "vehicle": 1.5}, ("link_lost", "vehicle")),
        ({"kind": "udp_loss", "fraction": 1.01}, ("udp_loss", "fraction")),
        ({"kind": "udp_loss", "fraction": math.nan}, ("udp_loss", "fraction")),
        ({"kind": "udp_loss", "fraction": "0.5"}, ("udp_loss", "fraction")),
        ({"kind": "mocap_freeze", "duration_s": -2}, ("mocap_freeze", "duration_s")),
        ({"kind": "mocap_freeze", "duration_s": math.inf}, ("mocap_freeze", "duration_s")),
        ({"kind": "mocap_freeze", "duration_s": 1e300}, ("mocap_freeze", "duration_s")),
        (
            {"kind": "mocap_jump", "body": "bar", "offset_m": [0, 0, 1e9]},
            ("mocap_jump", "offset_m"),
        ),
        ({"kind": "push", "body": "bar", "force_n": [0, 0, 51]}, ("push", "force_n", 2)),
        ({"kind": "push", "body": "bar"}, ("push", "force_n")),
    ],
)
def test_malformed_faults_are_refused_at_the_parse_naming_the_field(
    body: dict[str, Any], where: tuple[str, ...]
) -> None:
    with pytest.raises(pydantic.ValidationError) as raised:
        FAULT.validate_python(body)
    [error] = raised.value.errors()[:1]
    assert tuple(error["loc"][: len(where)]) == where
    if not where:
        assert "kind" in error["msg"]


def test_a_vehicle_is_any_json_integer_1_to_8() -> None:
    """JSON Schema's integer: 1.0 is 1 (the OpenAPI document says "integer"). Whether the
    world has that vehicle is the world's to say (``sim.faults.check_target``)."""
    fault = FAULT.validate_python({"kind": "link_lost", "vehicle": 2.0})
    assert isinstance(fault, LinkLostFault) and fault.vehicle == 2
    fault = FAULT.validate_python({"kind": "px4_reboot", "vehicle": 8})
    assert isinstance(fault, Px4RebootFault) and fault.vehicle == 8


async def test_requests_and_replies_over_a_socket_pair() -> None:
    api_end, world_end = socket.socketpair()
    client = WorldClient(await WorldChannel.open(api_end))
    channel = await WorldChannel.open(world_end)
    seen: list[WorldRequest] = []

    def handle(request: WorldRequest) -> Reply:
        seen.append(request)
        if isinstance(request, ListFaults):
            return Reply(outcome=Outcome.OK, data={"faults": []})
        raise RuntimeError("boom")

    async with asyncio.TaskGroup() as group:
        server = group.create_task(serve_world_requests(channel, handle))
        receiver = group.create_task(client.run())
        reply = await client.request(ListFaults())
        assert reply.ok and reply.data == {"faults": []}
        fault = FAULT.validate_python({"kind": "mocap_silent"})
        failed = await client.request(StartFault(fault=fault))
        assert failed.outcome is Outcome.INVALID and "boom" in failed.reason
        server.cancel()
        await channel.close()
        await receiver  # the world went away
    assert not client.connected
    gone = await client.request(ListFaults())
    assert gone.outcome is Outcome.UNAVAILABLE and gone.reason == WORLD_GONE
    assert [type(r) for r in seen] == [ListFaults, StartFault]
    await client.close()
