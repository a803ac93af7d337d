"""The live Foxglove view's public port: a WebSocket gateway in the API process.

**Admission.** A client must present the API token, checked at the handshake: a client
without it is answered 401 and never gets a WebSocket, so no frame passes either way. A
Foxglove app cannot set a header on its WebSocket (a browser's ``WebSocket`` has no way to),
but it opens the URL it is given as it is, query included, so the token comes in the URL:
``ws://HOST:PORT/?token=TOKEN`` (percent-encoded where the token needs it; in the Foxglove
app: "Open connection", "Foxglove WebSocket", that URL). A client that can set headers may
send ``Authorization: Bearer TOKEN`` instead. The check is the API gate's own
(``HttpPolicy.token_matches``: a constant-time compare). There is no origin check: the
Foxglove web app is another origin by nature, and a page that does not know the token is
refused all the same.

**Upstream.** The flight process runs foxglove-sdk's server on a loopback port of its own;
that server speaks only ``foxglove.sdk.v1``, the SDK's name for Foxglove's
``foxglove.websocket.v1`` (the same messages), and refuses a client offering only the old
name (Lichtblick and other foxglove.websocket.v1 clients). The gateway listens on
``foxglove.port``, accepts either name and passes every frame through, both ways, opening
each message's sealed payload (``supervisor.logs.view_seal``) on its way to the client: the
SDK's server authenticates no one, so what it sends is readable only with the token's keys.
It runs here, not in the flight process, because passing frames takes the Python
interpreter, which a tick must never wait for.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from http import HTTPStatus
from urllib.parse import parse_qs, urlsplit

from websockets import ConnectionClosed, Data, Subprotocol
from websockets.asyncio.client import ClientConnection, connect
from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.http11 import Request, Response

from api.guard import HttpPolicy
from supervisor.logs.view_seal import ViewKeys, unseal, view_keys

log = logging.getLogger(__name__)

SDK_PROTOCOL = Subprotocol("foxglove.sdk.v1")
FOXGLOVE_PROTOCOL = Subprotocol("foxglove.websocket.v1")
# A client offering both gets the SDK's name, as the SDK itself would answer it.
ACCEPTED_PROTOCOLS = [SDK_PROTOCOL, FOXGLOVE_PROTOCOL]
TOKEN_PARAMETER = "token"  # ws://HOST:PORT/?token=TOKEN
TRY_AGAIN_LATER = 1013  # WebSocket close code: the view is not running now
UPSTREAM_OPEN_TIMEOUT_S = 5.0
# How long a client waits for the flight process's view (serve starting, the flight
# process restarting) before it is told to try again later.
VIEW_WAIT_S = 5.0
VIEW_POLL_S = 0.1
# foxglove.websocket.v1, "Message Data" (server → client, binary): opcode 0x01, then the
# subscription id (uint32) and the log time (uint64), little-endian, then the payload.
MESSAGE_DATA = 0x01
MESSAGE_DATA_HEADER_BYTES = 13

UpstreamPort = Callable[[], int | None]


def presented_token(request: Request) -> str | None:
    """The token a handshake carries: the URL's ``token`` parameter, else the bearer of its
    ``Authorization`` header."""
    values = parse_qs(urlsplit(request.path).query).get(TOKEN_PARAMETER)
    if values:
        return values[0]
    scheme, _, token = request.headers.get("Authorization", "").partition(" ")
    return token if scheme.lower() == "bearer" else None


def opened(keys: ViewKeys, frame: Data) -> Data | None:
    """A frame of the view as the client gets it: a Message Data frame with its payload
    opened (None: not sealed with ``keys``), any other frame unchanged."""
    if not isinstance(frame, bytes) or frame[:1] != bytes([MESSAGE_DATA]):
        return frame
    payload = unseal(keys, frame[MESSAGE_DATA_HEADER_BYTES:])
    return None if payload is None else frame[:MESSAGE_DATA_HEADER_BYTES] + payload


class FoxgloveGateway:
    """Serves Foxglove clients that present ``policy``'s token on ``host:port`` (0: a free
    port, then ``port`` says which) from the flight process's view, found at each
    connection by ``upstream_port`` (None: the flight process has no view now; after
    ``view_wait_s`` without one the client is told to try again later), opening its
    messages with the keys of ``policy``'s token."""

    def __init__(
        self, upstream_port: UpstreamPort, policy: HttpPolicy, view_wait_s: float = VIEW_WAIT_S
    ) -> None:
        self._upstream_port = upstream_port
        self._policy = policy
        self._keys = view_keys(policy.token)
        self._view_wait_s = view_wait_s
        self._server: Server | None = None
        self.port = 0

    async def start(self, host: str, port: int) -> None:
        """Listen; raises ``OSError`` when the port cannot be bound."""
        self._server = await serve(
            self._relay,
            host,
            port,
            process_request=self._admit,
            subprotocols=ACCEPTED_PROTOCOLS,
            compression=None,
            max_size=None,
        )
        self.port = self._server.sockets[0].getsockname()[1]

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()

    def _admit(self, connection: ServerConnection, request: Request) -> Response | None:
        """The handshake's answer: None (go on) with the token, else 401."""
        token = presented_token(request)
        if token is not None and self._policy.token_matches(f"Bearer {token}"):
            return None
        # The peer only: the URL may carry a wrong token, which is not logged.
        log.info("Foxglove client at %s refused: no valid token", connection.remote_address)
        response = connection.respond(
            HTTPStatus.UNAUTHORIZED,
            "the API token is required: ws://HOST:PORT/?token=TOKEN "
            "(or 'Authorization: Bearer TOKEN')\n",
        )
        response.headers["WWW-Authenticate"] = "Bearer"
        return response

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
                await _pipe_both_ways(client, upstream, self._keys)
        except (OSError, TimeoutError, ConnectionClosed) as error:
            log.info(
                "Foxglove client at %s: the view cannot be reached (%s)",
                client.remote_address,
                error,
            )
        await client.close(TRY_AGAIN_LATER, "the flight process's live view closed")


async def _pipe_both_ways(
    client: ServerConnection, upstream: ClientConnection, keys: ViewKeys
) -> None:
    """Until either side closes; the view's messages opened on the way (one that does not
    open, sealed with another key, is dropped and said once). A client that does not read
    makes ``send`` wait, so this stops reading the view, whose server then drops that
    client's oldest messages (its backlog is bounded): nothing piles up here."""

    async def to_upstream() -> None:
        with contextlib.suppress(ConnectionClosed):
            async for frame in client:
                await upstream.send(frame)

    async def to_client() -> None:
        warned = False
        with contextlib.suppress(ConnectionClosed):
            async for frame in upstream:
                out = opened(keys, frame)
                if out is not None:
                    await client.send(out)
                elif not warned:
                    warned = True
                    log.warning("the live view's messages do not open with this API's token")

    tasks = {asyncio.create_task(to_upstream()), asyncio.create_task(to_client())}
    try:
        await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
    finally:
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
