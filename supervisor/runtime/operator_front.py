"""The operators' side of a process that flies (the flight process, or the agents' ground
station): each connection to its listening socket, admitted by its hello, its requests
answered in order, and for the API's commands connection the telemetry stream."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
import time
from collections.abc import Callable

from supervisor.flight.operator_requests import Outcome, Reply, Request, SetpointsQuery
from supervisor.flight.status import FlightStatus
from supervisor.ipc.channel import Channel, ChannelClosedError, ChannelServer
from supervisor.ipc.messages import ReplyMessage, TelemetryMessage
from supervisor.ipc.server import (
    HELLO_TIMEOUT_S,
    Admission,
    RequestHandler,
    admit,
    refusal,
    serve_requests,
)
from supervisor.runtime.scheduler import DeadlineTicker

log = logging.getLogger(__name__)

TELEMETRY_PERIOD_S = 0.04
TELEMETRY_BACKLOG_BYTES = 1 << 20


class OperatorFront:
    """Answers the connections with ``token`` by ``handle``, and streams ``telemetry()``
    (None: nothing to say yet) to each commands connection every ``TELEMETRY_PERIOD_S``."""

    def __init__(
        self,
        token: str,
        handle: RequestHandler,
        telemetry: Callable[[], FlightStatus | None],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self._token = token
        self._handle = handle
        self._telemetry = telemetry
        self._clock = clock
        self._server = ChannelServer()
        self._telemetry_channels: set[Channel] = set()

    async def start(self, listener: socket.socket) -> None:
        await self._server.start(listener, Channel, self._connection)

    async def close(self) -> None:
        await self._server.close()

    async def _connection(self, channel: Channel) -> None:
        """One connection: its hello, then its requests (and, for the API's commands
        connection, the telemetry stream) until it closes."""
        try:
            async with asyncio.timeout(HELLO_TIMEOUT_S):
                hello = await channel.receive()
            admission = admit(hello, self._token)
            if isinstance(admission, str):
                channel.send(
                    ReplyMessage(id=0, reply=Reply(outcome=Outcome.REFUSED, reason=admission))
                )
                await channel.drain()
                log.warning("connection refused: %s", admission)
                return
            log.info("%s connection opened", admission.role)
            publisher = None
            if admission.role == "commands":
                publisher = asyncio.create_task(self._publish(channel))
                self._telemetry_channels.add(channel)
            try:
                await serve_requests(channel, lambda r: self._admitted(admission, r))
            finally:
                if publisher is not None:
                    publisher.cancel()
                self._telemetry_channels.discard(channel)
                log.info("%s connection closed", admission.role)
        except (ChannelClosedError, TimeoutError):
            return

    async def _admitted(self, admission: Admission, request: Request) -> Reply:
        refused = refusal(admission, request)
        if refused is not None:
            return Reply(outcome=Outcome.REFUSED, reason=refused)
        reply = await self._handle(request)
        status = self._telemetry()
        if reply.ok and not isinstance(request, SetpointsQuery) and status is not None:
            # The status the request left, ahead of its reply on the API's commands
            # connection: a status read, or a ``wait_s``, after the reply never sees the
            # state before it (a query changes nothing).
            message = TelemetryMessage(status=status)
            for channel in self._telemetry_channels:
                with contextlib.suppress(ChannelClosedError):
                    channel.send(message)
        return reply

    async def _publish(self, channel: Channel) -> None:
        ticker = DeadlineTicker(TELEMETRY_PERIOD_S, clock=self._clock)
        try:
            async for _ in ticker:
                if channel.buffered_bytes >= TELEMETRY_BACKLOG_BYTES:  # a stuck reader: skip
                    continue
                status = self._telemetry()
                if status is None:
                    continue
                try:
                    channel.send(TelemetryMessage(status=status))
                except ChannelClosedError:
                    return
        finally:
            ticker.close()
