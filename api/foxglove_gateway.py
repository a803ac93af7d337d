"""The live Foxglove view's public port: a WebSocket gateway in the API process.

The flight process runs foxglove-sdk's server on a loopback port of its own; that server
speaks only ``foxglove.sdk.v1``, the SDK's name for Foxglove's ``foxglove.websocket.v1``
(the same messages), and refuses a client offering only the old name (Lichtblick and
other foxglove.websocket.v1 clients). The gateway listens on ``foxglove.port``, accepts
either name and passes every frame through unchanged, both ways, to the flight process's
server. It runs here, not in the flight process, because passing frames takes the Python
interpreter, which a tick must never wait for.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable

from websockets import ConnectionClosed, Subprotocol
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve

log = logging.getLogger(__name__)

SDK_PROTOCOL = Subprotocol("foxglove.sdk.v1")
FOXGLOVE_PROTOCOL = Subprotocol("foxglove.websocket.v1")
# A client offering both gets the SDK's name, as the SDK itself would answer it.
ACCEPTED_PROTOCOLS = [SDK_PROTOCOL, FOXGLOVE_PROTOCOL]
TRY_AGAIN_LATER = 1013  # WebSocket close code: the view is not running now
UPSTREAM_OPEN_TIMEOUT_S = 5.0
# How long a client waits for the flight process's view (serve starting, the flight
# process restarting) before it is told to try again later.
VIEW_WAIT_S = 5.0
VIEW_POLL_S = 0.1

UpstreamPort = Callable[[], int | None]


class FoxgloveGateway:
    """Serves Foxglove clients on ``host:port`` (0: a free port, then ``port`` says which)
    from the flight process's view, found at each connection by ``upstream_port`` (None:
    the flight process has no view now; after ``view_wait_s`` without one the client is
    told to try again later)."""

    def __init__(self, upstream_port: UpstreamPort, view_wait_s: float = VIEW_WAIT_S) -> None:
        self._upstream_port = upstream_port
        self._view_wait_s = view_wait_s
        self._server: Server | None = None
        self.port = 0

    async def start(self, host: str, port: int) -> None:
        """Listen; raises ``OSError`` when the port cannot be bound."""
        self._server = await serve(
            self._relay,
            host,
            port,
            subprotocols=ACCEPTED_PROTOCOLS,
            compression=None,
            max_size=None,
        )
        self.port = self._server.sockets[0].getsockname()[1]

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    async def _view_port(self) -> int | None:
        deadline = asyncio.get_running_loop().time() + self._view_wait_s
        while (port := self._upstream_port()) is None:
            if asyncio.get_running_loop().time() >= deadline:
                return None
            await asyncio.sleep(VIEW_POLL_S)
        return port

    async def _relay(self, client: ServerConnection) -> None:
        port = await self._view_port()
        if port is None:
            await client.close(TRY_AGAIN_LATER, "the flight process has no live view now")
            return
        try:
            async with connect(
                f"ws://127.0.0.1:{port}",
                subprotocols=[SDK_PROTOCOL],
                compression=None,
                max_size=None,
                open_timeout=UPSTREAM_OPEN_TIMEOUT_S,
            ) as upstream:
                await _pipe_both_ways(client, upstream)
        except (OSError, TimeoutError, ConnectionClosed) as error:
            log.info(
                "Foxglove client at %s: the view cannot be reached (%s)",
                client.remote_address,
                error,
            )
        await client.close(TRY_AGAIN_LATER, "the flight process's live view closed")


async def _pipe_both_ways(client: ServerConnection, upstream: ClientConnection) -> None:
    """Until either side closes. A client that does not read makes ``send`` wait, so this
    stops reading the view, whose server then drops that client's oldest messages (its
    backlog is bounded): nothing piles up here."""

    async def pipe(
        source: ServerConnection | ClientConnection, sink: ServerConnection | ClientConnection
    ) -> None:
        with contextlib.suppress(ConnectionClosed):
            async for frame in source:
                await sink.send(frame)

    tasks = {
        asyncio.create_task(pipe(client, upstream)),
        asyncio.create_task(pipe(upstream, client)),
    }
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
