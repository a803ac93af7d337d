"""Bounds on reading a request's head (api/http_limits.py), over real sockets on loopback
against HttpServer: a head must arrive whole within the deadline of the connection's start
or of the previous response, and one over MAX_HEAD_BYTES is answered 431."""

from __future__ import annotations

import asyncio
import contextlib
import ssl
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Literal

import pytest
import websockets
from fastapi import FastAPI, WebSocket

from api.http_limits import MAX_HEAD_BYTES
from api.server import HttpServer, TlsFiles, bind

DEADLINE_S = 1.0
# Functional bounds with a wide margin for a busy 2-core machine.
CLOSED_WITHIN_S = 10.0
ANSWERED_WITHIN_S = 5.0
# asyncio may run a timer up to its clock's resolution early.
EARLY_S = 0.05

Stall = Literal["idle", "stalled", "dribbling"]


def small_app() -> FastAPI:
    app = FastAPI()

    @app.get("/ping")
    async def ping() -> dict[str, bool]:
        return {"ok": True}

    @app.websocket("/echo")
    async def echo(socket: WebSocket) -> None:
        await socket.accept()
        async for text in socket.iter_text():
            await socket.send_text(text)

    return app


@dataclass(frozen=True)
class Served:
    port: int
    tls: ssl.SSLContext | None

    async def connect(self) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
        return await asyncio.open_connection("127.0.0.1", self.port, ssl=self.tls)


@contextlib.asynccontextmanager
async def serving(
    tls: TlsFiles | None = None, deadline_s: float = DEADLINE_S
) -> AsyncIterator[Served]:
    server = HttpServer(small_app(), bind("127.0.0.1", 0), tls, head_read_deadline_s=deadline_s)
    context = None if tls is None else ssl.create_default_context(cafile=tls.cert_file)
    async with asyncio.TaskGroup() as group:
        group.create_task(server.serve())
        try:
            yield Served(server.port, context)
        finally:
            server.stop()


@pytest.fixture
async def served() -> AsyncIterator[Served]:
    async with serving() as running:
        yield running


def head(head_bytes: int = 0) -> bytes:
    """A ``GET /ping`` head of exactly ``head_bytes`` (0: as short as it goes), padded by a
    header field; its last four bytes are the empty line that ends it."""
    start, end = b"GET /ping HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Filler: ", b"\r\n\r\n"
    filler_bytes = max(0, head_bytes - len(start) - len(end))
    whole = start + b"a" * filler_bytes + end
    assert head_bytes in (0, len(whole))
    return whole


async def read_response(reader: asyncio.StreamReader) -> int:
    """One whole response (the API's have a Content-Length); its status."""
    status = int((await reader.readline()).split()[1])
    body_bytes = 0
    while (line := await reader.readline()) not in (b"\r\n", b""):
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            body_bytes = int(value)
    await reader.readexactly(body_bytes)
    return status


async def closed_by_server(reader: asyncio.StreamReader) -> bytes:
    """What arrived before the server closed the connection (a reset counts as closed)."""
    async with asyncio.timeout(CLOSED_WITHIN_S):
        with contextlib.suppress(ConnectionResetError):
            return await reader.read()
    return b""


async def request(served: Served, data: bytes, piece_bytes: int | None = None) -> int:
    """The status answered to ``data`` sent on a new connection, whole or in pieces."""
    step = piece_bytes or len(data)
    reader, writer = await served.connect()
    try:
        for start in range(0, len(data), step):
            writer.write(data[start : start + step])
            await writer.drain()
        async with asyncio.timeout(ANSWERED_WITHIN_S):
            return await read_response(reader)
    finally:
        writer.close()


@pytest.mark.parametrize("piece_bytes", [None, 1024], ids=["whole", "in 1 kB pieces"])
@pytest.mark.parametrize(
    ("head_bytes", "status"),
    [(0, 200), (MAX_HEAD_BYTES, 200), (MAX_HEAD_BYTES + 1, 431)],
    ids=["a short head", "the limit", "one byte over"],
)
async def test_a_head_is_served_up_to_the_limit_and_431_beyond(
    served: Served, head_bytes: int, status: int, piece_bytes: int | None
) -> None:
    assert await request(served, head(head_bytes), piece_bytes) == status


async def test_a_64_kb_head_is_431_and_the_connection_closed(served: Served) -> None:
    reader, writer = await served.connect()
    writer.write(head(64 * 1024))
    assert (await reader.readline()).startswith(b"HTTP/1.1 431 ")
    assert b"connection: close" in await closed_by_server(reader)
    writer.close()


async def test_a_head_never_ended_is_431_past_the_limit(served: Served) -> None:
    """The head's empty line never comes: answered 431 once one byte more than the limit is
    in (the deadline would close the connection without an answer)."""
    reader, writer = await served.connect()
    writer.write(head(MAX_HEAD_BYTES + 4)[:-3])  # MAX_HEAD_BYTES + 1 bytes, no empty line
    async with asyncio.timeout(ANSWERED_WITHIN_S):
        assert await read_response(reader) == 431
    writer.close()


async def test_pipelined_heads_are_measured_each(served: Served) -> None:
    """Three requests in one write: each head is measured from the end of the one before."""
    reader, writer = await served.connect()
    writer.write(head() + head(MAX_HEAD_BYTES) + head(MAX_HEAD_BYTES + 1))
    async with asyncio.timeout(ANSWERED_WITHIN_S):
        assert [await read_response(reader) for _ in range(3)] == [200, 200, 431]
    writer.close()


async def slowloris(
    connection: tuple[asyncio.StreamReader, asyncio.StreamWriter], how: Stall
) -> tuple[float, bytes]:
    """Holds a connection open sending nothing (``idle``), half a head and nothing more
    (``stalled``) or a head a byte every 0.2 s (``dribbling``): when (``time.perf_counter``)
    the server closed it, and what the server sent before."""
    reader, writer = connection
    data = head(MAX_HEAD_BYTES)[:-2]

    async def send() -> None:
        if how == "stalled":
            writer.write(data[: len(data) // 2])
        elif how == "dribbling":
            with contextlib.suppress(OSError):  # the server closed it
                for byte in data:
                    writer.write(bytes([byte]))
                    await writer.drain()
                    await asyncio.sleep(0.2)

    async with asyncio.TaskGroup() as group:
        sending = group.create_task(send())
        answer = await closed_by_server(reader)
        closed_at = time.perf_counter()
        sending.cancel()
    writer.close()
    return closed_at, answer


async def test_100_slowloris_connections_are_closed_at_the_deadline_and_requests_served() -> None:
    """The deadline is 2 s here, so that the request made meanwhile has the time to be
    answered on a busy machine before the first of them is closed."""
    deadline_s = 2.0
    async with serving(deadline_s=deadline_s) as served:
        started = time.perf_counter()
        connections = await asyncio.gather(*(served.connect() for _ in range(100)))
        ways: tuple[Stall, ...] = ("idle", "stalled", "dribbling")
        attackers = [
            asyncio.create_task(slowloris(connection, ways[n % 3]))
            for n, connection in enumerate(connections)
        ]
        assert await request(served, head()) == 200
        answered_at = time.perf_counter()
        outcomes = await asyncio.gather(*attackers)
    closed_at = [at for at, _ in outcomes]
    assert all(answer == b"" for _, answer in outcomes)
    assert answered_at < min(closed_at)
    assert started + deadline_s - EARLY_S <= min(closed_at)
    assert max(closed_at) < started + CLOSED_WITHIN_S


async def test_a_kept_alive_connection_has_the_deadline_again_after_each_response(
    served: Served,
) -> None:
    """Eight requests 0.2 s apart: 1.6 s on one connection, each head well within the
    deadline of the previous response."""
    reader, writer = await served.connect()
    for _ in range(8):
        writer.write(head())
        assert await read_response(reader) == 200
        await asyncio.sleep(DEADLINE_S / 5)
    writer.write(head())
    assert await read_response(reader) == 200
    writer.close()


@pytest.mark.parametrize("how", ["idle", "dribbling"])
async def test_a_kept_alive_connection_is_closed_at_the_deadline_after_its_response(
    served: Served, how: Stall
) -> None:
    """Chosen: an idle kept-alive connection is closed ``DEADLINE_S`` after its last
    response, as is one whose next head has not arrived whole by then; a client opens a new
    one."""
    reader, writer = await served.connect()
    sent_at = time.perf_counter()
    writer.write(head())
    assert await read_response(reader) == 200
    closed_at, answer = await slowloris((reader, writer), how)
    assert answer == b""
    assert sent_at + DEADLINE_S - EARLY_S <= closed_at < sent_at + CLOSED_WITHIN_S
    assert await request(served, head()) == 200


async def test_a_websocket_outlives_the_deadline(served: Served) -> None:
    async with websockets.connect(f"ws://127.0.0.1:{served.port}/echo") as socket:
        await asyncio.sleep(2 * DEADLINE_S)
        await socket.send("still here")
        async with asyncio.timeout(ANSWERED_WITHIN_S):
            assert await socket.recv() == "still here"


async def test_over_tls_the_limit_and_the_deadline_hold(certificate: TlsFiles) -> None:
    async with serving(certificate) as served:
        assert await request(served, head()) == 200
        assert await request(served, head(64 * 1024)) == 431
        started = time.perf_counter()
        closed_at, answer = await slowloris(await served.connect(), "dribbling")
        assert answer == b""
        assert started + DEADLINE_S - EARLY_S <= closed_at < started + CLOSED_WITHIN_S
