"""The live Foxglove view: a WebSocket server streaming the flight log's channels
(``flight_messages``: the payload, cables, UAVs and reference in 3D, every figure as a plot) as
the ticks happen, every payload sealed (``view_seal``): only the API process's gateway
(api/foxglove_gateway.py), which holds the API token, opens them for the clients it admits.
Its subprotocol is ``foxglove.sdk.v1``, the SDK's name for Foxglove's
``foxglove.websocket.v1`` (the same messages); a client offering only the old name is
refused at the handshake, and the gateway takes either.

The server is ``foxglove-sdk``'s, in Rust on threads of its own: it accepts clients,
advertises the channels and sends to each subscriber without the Python interpreter, so
what a tick spends on it is building, encoding and sealing its messages and queueing them,
and that only while a client is subscribed. A client too slow to read loses messages
(the SDK's backlog is bounded), never the tick time. The SDK authenticates no client (no
hook at its handshake): any local program may connect to its loopback port, and gets the
channel list and ciphertext.
"""

from __future__ import annotations

import json
import secrets
import time
from collections.abc import Sequence
from typing import Any

import foxglove

from controllers.formation_params import Vector3
from geometry.formation import FormationLayout
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_messages import SceneStyle, json_schemas, well_known
from supervisor.logs.mcap_log import tick_messages
from supervisor.logs.view_seal import STREAM_ID_BYTES, Sealer, ViewKeys


class _SealedChannels:
    """The flight log's channels for ``layout``'s formation (topics, encodings and schemas
    as in the MCAP log), each taking sealed bytes: Foxglove's messages are encoded here, not
    by the SDK."""

    def __init__(self, context: foxglove.Context, layout: FormationLayout) -> None:
        self._channels: dict[str, foxglove.Channel] = {}
        for topic, (name, schema) in json_schemas(layout).items():
            data = json.dumps(schema).encode()
            self._channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=name, encoding="jsonschema", data=data),
                message_encoding="json",
                context=context,
            )
        for topic, kind in well_known(layout).items():
            self._channels[topic] = foxglove.Channel(
                topic, schema=kind.get_schema(), message_encoding="protobuf", context=context
            )

    def write(self, topic: str, log_time_ns: int, sealed: bytes) -> None:
        self._channels[topic].log(sealed, log_time=log_time_ns)

    def has_sinks(self) -> bool:
        return any(channel.has_sinks() for channel in self._channels.values())

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()


class FoxgloveLiveView:
    """The WebSocket server on ``host:port`` (0: a free port, then ``port`` says which),
    sealing with ``keys`` (``view_seal.view_keys`` of the API token), for the formation
    whose cables hang from ``attachments_m`` (the payload's frame [m], cable 1's first:
    ``PayloadParams.attachments_m``). Raises ``RuntimeError`` when the port cannot be bound,
    ``ValueError`` for fewer than 2 or more than 8 attachments."""

    def __init__(
        self, host: str, port: int, attachments_m: Sequence[Vector3], keys: ViewKeys
    ) -> None:
        self._style = SceneStyle(tuple(attachments_m))
        self._context = foxglove.Context()
        self._channels = _SealedChannels(self._context, self._style.layout)
        self._sealer = Sealer(keys, secrets.token_bytes(STREAM_ID_BYTES))
        self._server = foxglove.start_server(
            name="uavbar-supervisor", host=host, port=port, context=self._context
        )
        self.port: int = self._server.port

    @property
    def subscribed(self) -> bool:
        """Whether a client is subscribed to any channel (else a tick does nothing here)."""
        return self._channels.has_sinks()

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None:
        """Stream one tick's messages, stamped with the wall clock (nothing to do while no
        client is subscribed)."""
        if not self.subscribed:
            return
        log_time_ns = time.time_ns()
        messages = tick_messages(record, notices, log_time_ns, self._style.layout, self._style)
        for topic, message in messages:
            payload = message if isinstance(message, bytes) else _encoded(message)
            self._channels.write(topic, log_time_ns, self._sealer.seal(payload))

    def close(self) -> None:
        self._server.stop()
        self._channels.close()


def _encoded(message: Any) -> bytes:
    """One of Foxglove's messages (``foxglove.messages``) as protobuf."""
    data: bytes = message.encode()
    return data
