"""The live Foxglove view: a WebSocket server streaming the flight log's channels
(``flight_messages``: the bar, cables, UAVs and reference in 3D, every figure as a plot) as
the ticks happen. Its subprotocol is ``foxglove.sdk.v1``, the SDK's name for Foxglove's
``foxglove.websocket.v1`` (the same messages); a client offering only the old name is
refused at the handshake, so ``serve`` runs it on loopback behind the API process's
gateway, which takes either (api/foxglove_gateway.py).

The server is ``foxglove-sdk``'s, in Rust on threads of its own: it accepts clients,
advertises the channels and sends to each subscriber without the Python interpreter, so
what a tick spends on it is building its messages and queueing them (as for the MCAP log),
and that only while a client is subscribed. A client too slow to read loses messages
(the SDK's backlog is bounded), never the tick time.
"""

from __future__ import annotations

import time

import foxglove

from supervisor.flight.tick_record import TickRecord
from supervisor.logs.mcap_log import FoxgloveChannels, scene_style, tick_messages


class FoxgloveLiveView:
    """The WebSocket server on ``host:port`` (0: a free port, then ``port`` says which).
    Raises ``RuntimeError`` when the port cannot be bound."""

    def __init__(self, host: str, port: int, arms_m: tuple[float, float]) -> None:
        self._context = foxglove.Context()
        self._channels = FoxgloveChannels(self._context)
        self._style = scene_style({"arms_m": list(arms_m)})
        self._server = foxglove.start_server(
            name="uavbar-supervisor", host=host, port=port, context=self._context
        )
        self.port: int = self._server.port

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None:
        """Stream one tick's messages, stamped with the wall clock (nothing to do while no
        client is subscribed)."""
        if not self._channels.has_sinks():
            return
        log_time_ns = time.time_ns()
        for topic, message in tick_messages(record, notices, log_time_ns, self._style):
            self._channels.write(topic, log_time_ns, message)

    def close(self) -> None:
        self._server.stop()
        self._channels.close()
