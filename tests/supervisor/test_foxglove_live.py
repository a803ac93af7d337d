"""The live Foxglove view: a WebSocket client (``websockets``, real sockets on loopback)
speaking Foxglove's protocol is advertised the flight log's channels and receives each tick
it subscribed to, through the API process's gateway with the API token, and from ``serve``
during a flight; without the token it gets nothing, neither from the gateway (refused at
the handshake) nor from the flight process's own server (sealed payloads).

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
from urllib.parse import quote

import pydantic_core
import pytest
import websockets

from api.foxglove_gateway import TRY_AGAIN_LATER, FoxgloveGateway, opened
from api.guard import HttpPolicy
from benchmarks.service import all_connected, running_service
from controllers.formation_params import FormationParams
from geometry.formation import FormationLayout
from supervisor.logs.flight_messages import json_messages, json_schemas, well_known
from supervisor.logs.foxglove_live import FoxgloveLiveView
from supervisor.logs.view_seal import (
    SEAL_OVERHEAD_BYTES,
    STREAM_ID_BYTES,
    Sealer,
    unseal,
    view_keys,
)
from tests.supervisor.test_mcap_log import flight_records
from tests.test_service import TOKEN

SUBPROTOCOL = websockets.Subprotocol("foxglove.sdk.v1")
OLD_NAME = websockets.Subprotocol("foxglove.websocket.v1")
KEYS = view_keys(TOKEN)
BAR = FormationLayout(2)  # the lab's: the paper's two UAVs and bar
JSON_SCHEMAS, WELL_KNOWN = json_schemas(BAR), well_known(BAR)
POLICY = HttpPolicy(token=TOKEN)


def with_token(port: int, token: str = TOKEN) -> str:
    return f"ws://127.0.0.1:{port}/?token={quote(token, safe='')}"


async def advertised(socket: Any) -> dict[str, dict[str, Any]]:
    """The channels the server advertises, by topic (after its serverInfo)."""
    channels: dict[str, dict[str, Any]] = {}
    async with asyncio.timeout(10.0):
        while len(channels) < len(JSON_SCHEMAS) + len(WELL_KNOWN):
            message = await socket.recv()
            if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                channels |= {c["topic"]: c for c in json.loads(message)["channels"]}
    return channels


async def subscribe(socket: Any, topics: list[str], first_id: int) -> dict[str, Any]:
    """Read the advertisement (every channel of the log), subscribe to ``topics`` as
    ``first_id``, ``first_id + 1``, ...; the channels by topic."""
    channels = await advertised(socket)
    assert set(channels) == set(JSON_SCHEMAS) | set(WELL_KNOWN)
    subscriptions = [
        {"id": first_id + k, "channelId": channels[topic]["id"]} for k, topic in enumerate(topics)
    ]
    await socket.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
    return channels


async def subscribe_to_state(socket: Any, subscription: int) -> dict[str, Any]:
    return await subscribe(socket, ["/uavbar/state"], subscription)


async def message_data(socket: Any) -> tuple[int, int, bytes]:
    """The next binary Message Data frame: (subscription id, log time [ns], payload)."""
    while True:
        message = await socket.recv()
        if isinstance(message, bytes) and message[0] == 0x01:
            subscription, log_time_ns = struct.unpack_from("<IQ", message, 1)
            return subscription, log_time_ns, message[13:]


async def stream_and_receive(
    view: FoxgloveLiveView, socket: Any, records: list[Any], wanted: int
) -> list[tuple[int, int, bytes]]:
    """Append ``records`` to ``view`` one by one while reading messages, until ``wanted``
    came or 1 s after the last record."""
    received: list[tuple[int, int, bytes]] = []

    async def read() -> None:
        while len(received) < wanted:
            received.append(await message_data(socket))

    reader = asyncio.create_task(read())
    try:
        for record in records:
            view.append(record)
            await asyncio.sleep(0.002)  # the server's threads send meanwhile
            if reader.done():
                break
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(asyncio.shield(reader), 1.0)
    finally:
        reader.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await reader
    return received


def test_a_sealed_payload_opens_with_its_keys_only() -> None:
    sealer = Sealer(KEYS, bytes(STREAM_ID_BYTES))
    payload = b'{"t_s": 100.0, "mode": "hover"}'
    first, second = sealer.seal(payload), sealer.seal(payload)
    assert len(first) == len(payload) + SEAL_OVERHEAD_BYTES
    assert first != second  # a new nonce each time: equal payloads do not show
    assert payload not in first
    assert unseal(KEYS, first) == unseal(KEYS, second) == payload
    assert unseal(KEYS, sealer.seal(b"")) == b""
    assert unseal(view_keys("another token"), first) is None
    tampered = bytearray(first)
    tampered[20] ^= 1
    assert unseal(KEYS, bytes(tampered)) is None
    assert unseal(KEYS, first[: SEAL_OVERHEAD_BYTES - 1]) is None
    assert repr(KEYS.key) not in repr(KEYS)
    with pytest.raises(ValueError, match=f"{STREAM_ID_BYTES} bytes"):
        Sealer(KEYS, b"short")


def test_the_gateway_opens_message_data_and_passes_every_other_frame() -> None:
    header = struct.pack("<BIQ", 0x01, 7, 123)
    sealed = Sealer(KEYS, bytes(STREAM_ID_BYTES)).seal(b"{}")
    assert opened(KEYS, header + sealed) == header + b"{}"
    assert opened(view_keys("another token"), header + sealed) is None
    assert opened(KEYS, header + b"{}") is None  # not sealed: never passed on
    assert opened(KEYS, '{"op": "advertise"}') == '{"op": "advertise"}'
    assert opened(KEYS, b"\x02" + bytes(8)) == b"\x02" + bytes(8)  # server time


async def test_the_views_own_port_advertises_the_channels_and_sends_each_tick_sealed(
    lab_params: FormationParams,
) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
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
            assert channels["/tf"]["encoding"] == "protobuf"
            received = await stream_and_receive(view, socket, records, 5)
        assert received, "no tick reached the subscriber"
        subscription, _, sealed = received[0]
        payload = unseal(KEYS, sealed)
        assert payload is not None
        message = json.loads(payload)
        assert subscription == 7
        times = [r.t_s for r in records]
        assert message["t_s"] in times
        record = records[times.index(message["t_s"])]
        assert message["uav2"]["position_m"]["z"] == record.state[26]
    finally:
        view.close()


async def test_a_plain_client_on_the_views_own_port_reads_nothing(
    lab_params: FormationParams,
) -> None:
    """A local program that finds the flight process's port (``live_view.sdk_port`` in
    ``/api/status``) and subscribes to every channel gets only ciphertext."""
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
    records = flight_records(lab_params, 100)
    topics = [*JSON_SCHEMAS, *WELL_KNOWN]
    try:
        async with websockets.connect(
            f"ws://127.0.0.1:{view.port}", subprotocols=[OLD_NAME, SUBPROTOCOL]
        ) as socket:
            await subscribe(socket, topics, 1)
            received = await stream_and_receive(view, socket, records, 10_000)
    finally:
        view.close()
    # Every channel a tick writes (no notice here) came, each subscription its topic's.
    assert {topics[s - 1] for s, _, _ in received} == set(topics) - {"/uavbar/notices"}
    plaintexts = [
        pydantic_core.to_json(payload, inf_nan_mode="null")
        for record in records
        for _, payload in json_messages(record, BAR)
    ]
    for _, _, payload in received:
        with pytest.raises(ValueError):
            json.loads(payload)
        assert b'"t_s"' not in payload
        assert b"world" not in payload  # the frame of every Foxglove message
        assert not any(plain in payload for plain in plaintexts)
        assert unseal(view_keys("a guessed token"), payload) is None
    # What it got was the flight, sealed: the gateway's keys open every message.
    opened_json = [unseal(KEYS, payload) for _, _, payload in received]
    assert all(p is not None for p in opened_json)
    assert set(plaintexts) & set(opened_json)


def test_a_taken_port_is_refused_with_an_error(lab_params: FormationParams) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
    try:
        with pytest.raises(RuntimeError, match="in use"):
            FoxgloveLiveView("127.0.0.1", view.port, lab_params.payload.attachments_m, KEYS)
    finally:
        view.close()


async def test_the_old_protocol_name_alone_is_refused(lab_params: FormationParams) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
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
async def test_the_gateway_gives_either_name_the_view(
    lab_params: FormationParams, subprotocol: websockets.Subprotocol
) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
    gateway = FoxgloveGateway(lambda: view.port, POLICY)
    await gateway.start("127.0.0.1", 0)
    records = flight_records(lab_params, 50)
    try:
        async with websockets.connect(
            with_token(gateway.port), subprotocols=[subprotocol]
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
        assert json.loads(payload)["t_s"] == records[0].t_s  # opened by the gateway
    finally:
        await gateway.close()
        view.close()


@pytest.mark.parametrize(
    ("url_tail", "headers"),
    [
        ("", {}),
        ("?token=wrong", {}),
        (f"?token={TOKEN[:-1]}", {}),
        (f"?t={TOKEN}", {}),
        ("", {"Authorization": "Bearer wrong"}),
        ("", {"Authorization": f"Basic {TOKEN}"}),
    ],
    ids=["none", "wrong", "prefix", "other-parameter", "wrong-bearer", "not-bearer"],
)
async def test_the_gateway_refuses_a_client_without_the_token_at_the_handshake(
    lab_params: FormationParams, url_tail: str, headers: dict[str, str]
) -> None:
    view = FoxgloveLiveView("127.0.0.1", 0, lab_params.payload.attachments_m, KEYS)
    looked_up: list[int] = []

    def upstream_port() -> int:
        looked_up.append(view.port)
        return view.port

    gateway = FoxgloveGateway(upstream_port, POLICY)
    await gateway.start("127.0.0.1", 0)
    try:
        for subprotocol in (OLD_NAME, SUBPROTOCOL):
            with pytest.raises(websockets.InvalidStatus) as refused:
                async with websockets.connect(
                    f"ws://127.0.0.1:{gateway.port}/{url_tail}",
                    subprotocols=[subprotocol],
                    additional_headers=headers,
                ):
                    pass
            assert refused.value.response.status_code == 401
            assert refused.value.response.headers["WWW-Authenticate"] == "Bearer"
            assert b"token" in refused.value.response.body
        assert looked_up == []  # no WebSocket opened: the view was never even looked for
    finally:
        await gateway.close()
        view.close()


@pytest.mark.parametrize("token", [TOKEN, "a+b/c=d&e f%"], ids=["urlsafe", "percent-encoded"])
async def test_the_gateway_takes_the_token_in_the_url_or_a_bearer_header(token: str) -> None:
    gateway = FoxgloveGateway(lambda: None, HttpPolicy(token=token), view_wait_s=0.1)
    await gateway.start("127.0.0.1", 0)
    try:
        for url, headers in [
            (with_token(gateway.port, token), {}),
            (f"ws://127.0.0.1:{gateway.port}", {"Authorization": f"Bearer {token}"}),
        ]:
            async with websockets.connect(
                url, subprotocols=[OLD_NAME], additional_headers=headers
            ) as socket:
                with pytest.raises(websockets.ConnectionClosed) as closed:
                    await asyncio.wait_for(socket.recv(), 10.0)
            assert closed.value.rcvd is not None
            assert closed.value.rcvd.code == TRY_AGAIN_LATER  # admitted: no view here
    finally:
        await gateway.close()


async def test_the_gateway_passes_on_nothing_sealed_with_another_token(
    lab_params: FormationParams,
) -> None:
    view = FoxgloveLiveView(
        "127.0.0.1", 0, lab_params.payload.attachments_m, view_keys("another serve")
    )
    gateway = FoxgloveGateway(lambda: view.port, POLICY)
    await gateway.start("127.0.0.1", 0)
    try:
        async with websockets.connect(with_token(gateway.port), subprotocols=[OLD_NAME]) as socket:
            await subscribe_to_state(socket, 1)
            for _ in range(1000):  # until the subscription reaches the view
                if view.subscribed:
                    break
                await asyncio.sleep(0.01)
            assert view.subscribed
            reading = asyncio.create_task(message_data(socket))
            for record in flight_records(lab_params, 50):
                view.append(record)  # sealed and sent: the gateway drops each
                await asyncio.sleep(0.02)
            assert not reading.done()
            reading.cancel()
    finally:
        await gateway.close()
        view.close()


async def test_the_gateway_without_a_view_says_try_again_later() -> None:
    gateway = FoxgloveGateway(lambda: None, POLICY, view_wait_s=0.3)
    await gateway.start("127.0.0.1", 0)
    try:
        async with websockets.connect(with_token(gateway.port), subprotocols=[OLD_NAME]) as socket:
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
    ``serve``'s port with the token: the channels advertised, the modes live on the ground
    and in a flight; without the token refused; the flight process's own port
    (``live_view.sdk_port`` in ``/api/status``) gives only sealed payloads."""
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
        with pytest.raises(websockets.InvalidStatus, match="401"):
            async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[OLD_NAME]):
                pass
        async with (
            websockets.connect(with_token(port), subprotocols=[OLD_NAME]) as socket,
            service.client() as http,
        ):
            assert socket.subprotocol == OLD_NAME
            # Until it has heard both vehicles disarmed, the flight process says px4_landing.
            await service.wait_for(http, all_connected, 60.0, "both vehicles heard")
            channels = await advertised(socket)
            mode = channels["/uavbar/mode"]
            subscribe_mode = {
                "op": "subscribe",
                "subscriptions": [{"id": 1, "channelId": mode["id"]}],
            }
            await socket.send(json.dumps(subscribe_mode))
            async with asyncio.timeout(20.0):
                on_the_ground = await modes_received(socket, 10)
            status = (await http.get("/api/status")).json()
            sdk_port = status["live_view"]["sdk_port"]
            async with websockets.connect(
                f"ws://127.0.0.1:{sdk_port}", subprotocols=[SUBPROTOCOL]
            ) as direct:
                await subscribe(direct, ["/uavbar/mode"], 1)
                async with asyncio.timeout(20.0):
                    _, _, sealed = await message_data(direct)
            with pytest.raises(ValueError):
                json.loads(sealed)
            await service.take_off(http)
            async with asyncio.timeout(30.0):  # past what queued up during the take-off
                while (await modes_received(socket, 1)) != ["hover"]:
                    pass
    assert set(on_the_ground) == {"disarmed"}
