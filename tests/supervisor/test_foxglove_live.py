"""The live Foxglove view: a WebSocket client (``websockets``, real sockets on loopback)
speaking Foxglove's protocol is advertised the flight log's channels and receives each tick
it subscribed to, from the view alone, through the API process's gateway, and from ``serve``
during a flight.

foxglove-sdk's server names the protocol ``foxglove.sdk.v1``: Foxglove's
``foxglove.websocket.v1`` renamed, the same messages; it refuses a client offering only the
old name at the handshake (tested, so that the day the SDK accepts it again is seen), which
is why clients come through the gateway (api/foxglove_gateway.py), which takes either."""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import struct
from pathlib import Path
from typing import Any

import pytest
import websockets

from api.foxglove_gateway import TRY_AGAIN_LATER, FoxgloveGateway
from benchmarks.service import running_service
from controllers.params import BarSystemParams
from supervisor.logs.flight_messages import JSON_SCHEMAS, WELL_KNOWN
from supervisor.logs.foxglove_live import FoxgloveLiveView
from tests.supervisor.test_mcap_log import flight_records
from tests.test_service import TOKEN

SUBPROTOCOL = websockets.Subprotocol("foxglove.sdk.v1")
OLD_NAME = websockets.Subprotocol("foxglove.websocket.v1")


async def advertised(socket: Any) -> dict[str, dict[str, Any]]:
    """The channels the server advertises, by topic (after its serverInfo)."""
    channels: dict[str, dict[str, Any]] = {}
    async with asyncio.timeout(10.0):
        while len(channels) < len(JSON_SCHEMAS) + len(WELL_KNOWN):
            message = await socket.recv()
            if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                channels |= {c["topic"]: c for c in json.loads(message)["channels"]}
    return channels


async def subscribe_to_state(socket: Any, subscription: int) -> dict[str, Any]:
    """Read the advertisement (every channel of the log), subscribe to the state's as
    ``subscription``; the channels by topic."""
    channels = await advertised(socket)
    assert set(channels) == set(JSON_SCHEMAS) | set(WELL_KNOWN)
    state = channels["/uavbar/state"]["id"]
    request = {"op": "subscribe", "subscriptions": [{"id": subscription, "channelId": state}]}
    await socket.send(json.dumps(request))
    return channels


async def message_data(socket: Any) -> tuple[int, int, bytes]:
    """The next binary Message Data frame: (subscription id, log time [ns], payload)."""
    while True:
        message = await socket.recv()
        if isinstance(message, bytes) and message[0] == 0x01:
            subscription, log_time_ns = struct.unpack_from("<IQ", message, 1)
            return subscription, log_time_ns, message[13:]


async def test_a_client_is_advertised_the_channels_and_gets_the_ticks(
    lab_params: BarSystemParams,
) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.arms_m)
    records = flight_records(lab_params, 200)
    try:
        async with websockets.connect(
            f"ws://127.0.0.1:{view.port}", subprotocols=[SUBPROTOCOL]
        ) as socket:
            assert socket.subprotocol == SUBPROTOCOL
            channels = await subscribe_to_state(socket, 7)
            state = channels["/uavbar/state"]
            assert (state["encoding"], state["schemaName"]) == ("json", "uavbar.BarSystemState")
            assert channels["/tf"]["schemaName"] == "foxglove.FrameTransforms"
            received: list[tuple[int, int, bytes]] = []
            async with asyncio.timeout(10.0):
                for record in records:
                    view.append(record)
                    await asyncio.sleep(0.002)  # the server's threads send meanwhile
                    if len(received) < 5:
                        with_timeout = asyncio.wait_for(message_data(socket), 0.05)
                        with contextlib.suppress(TimeoutError):
                            received.append(await with_timeout)
            assert received, "no tick reached the subscriber"
            subscription, _, payload = received[0]
            message = json.loads(payload)
            assert subscription == 7
            times = [r.t_s for r in records]
            assert message["t_s"] in times
            record = records[times.index(message["t_s"])]
            assert message["uav2"]["position_m"]["z"] == record.state[26]
    finally:
        view.close()


def test_a_taken_port_is_refused_with_an_error(lab_params: BarSystemParams) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.arms_m)
    try:
        with pytest.raises(RuntimeError, match="in use"):
            FoxgloveLiveView("127.0.0.1", view.port, lab_params.arms_m)
    finally:
        view.close()


async def test_the_old_protocol_name_alone_is_refused(lab_params: BarSystemParams) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.arms_m)
    try:
        with pytest.raises(websockets.InvalidStatus, match="400"):
            async with websockets.connect(f"ws://127.0.0.1:{view.port}", subprotocols=[OLD_NAME]):
                pass
        async with websockets.connect(  # offering both, as current clients do
            f"ws://127.0.0.1:{view.port}", subprotocols=[OLD_NAME, SUBPROTOCOL]
        ) as socket:
            assert socket.subprotocol == SUBPROTOCOL
    finally:
        view.close()


@pytest.mark.parametrize("subprotocol", [OLD_NAME, SUBPROTOCOL])
async def test_the_gateway_serves_either_name_from_the_view(
    lab_params: BarSystemParams, subprotocol: websockets.Subprotocol
) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.arms_m)
    gateway = FoxgloveGateway(lambda: view.port)
    await gateway.start("127.0.0.1", 0)
    records = flight_records(lab_params, 50)
    try:
        async with websockets.connect(
            f"ws://127.0.0.1:{gateway.port}", subprotocols=[subprotocol]
        ) as socket:
            assert socket.subprotocol == subprotocol
            await subscribe_to_state(socket, 3)
            async with asyncio.timeout(10.0):
                while True:  # the subscription reaches the view through the gateway
                    view.append(records[0])
                    with contextlib.suppress(TimeoutError):
                        subscription, _, payload = await asyncio.wait_for(message_data(socket), 0.1)
                        break
        assert subscription == 3
        assert json.loads(payload)["t_s"] == records[0].t_s
    finally:
        await gateway.close()
        view.close()


async def test_the_gateway_without_a_view_says_try_again_later() -> None:
    gateway = FoxgloveGateway(lambda: None, view_wait_s=0.3)
    await gateway.start("127.0.0.1", 0)
    try:
        async with websockets.connect(
            f"ws://127.0.0.1:{gateway.port}", subprotocols=[OLD_NAME]
        ) as socket:
            with pytest.raises(websockets.ConnectionClosed) as closed:
                await asyncio.wait_for(socket.recv(), 10.0)
        assert closed.value.rcvd is not None
        assert closed.value.rcvd.code == TRY_AGAIN_LATER
        assert "no live view" in closed.value.rcvd.reason
    finally:
        await gateway.close()


async def modes_received(socket: Any, count: int) -> list[str]:
    return [json.loads((await message_data(socket))[2])["mode"] for _ in range(count)]


@pytest.mark.slow
async def test_serve_streams_a_flight_to_a_foxglove_websocket_v1_client(tmp_path: Path) -> None:
    """A client offering only ``foxglove.websocket.v1`` (as Lichtblick does) connected to
    ``serve``'s port: the channels advertised, the modes live on the ground and in a flight."""
    async with running_service(
        TOKEN, tmp_path, ["foxglove.enabled=true", "foxglove.port=0"]
    ) as service:
        async with asyncio.timeout(60.0):
            port = None
            while port is None:
                found = [
                    re.search(r"Foxglove view: ws://\S+:(\d+)", line) for line in service.output
                ]
                port = next((int(m.group(1)) for m in found if m), None)
                await asyncio.sleep(0.1)
        async with (
            websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[OLD_NAME]) as socket,
            service.client() as http,
        ):
            assert socket.subprotocol == OLD_NAME
            channels = await advertised(socket)
            mode = channels["/uavbar/mode"]
            subscribe = {"op": "subscribe", "subscriptions": [{"id": 1, "channelId": mode["id"]}]}
            await socket.send(json.dumps(subscribe))
            async with asyncio.timeout(20.0):
                on_the_ground = await modes_received(socket, 10)
            await service.take_off(http)
            async with asyncio.timeout(30.0):  # past what queued up during the take-off
                while (await modes_received(socket, 1)) != ["hover"]:
                    pass
    assert set(on_the_ground) == {"disarmed"}
