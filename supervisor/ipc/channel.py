"""The streams between ``serve``'s processes: length-prefixed JSON messages over a local
stream socket (a connection to a process's listening Unix socket,
``supervisor.ipc.rendezvous``, or one end of a ``socketpair``). Each frame is a 4-byte big-endian
length and one UTF-8 JSON object, one of a typed union: ``Channel`` carries the API ⇄
flight process messages (``supervisor.ipc.messages``), ``WorldChannel`` the API ⇄ world
ones (``supervisor.ipc.world_messages``).
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Generic, TypeVar

from pydantic import BaseModel, TypeAdapter, ValidationError

from supervisor.errors import RemoteError
from supervisor.ipc.messages import CHANNEL_MESSAGE, ChannelMessage
from supervisor.ipc.world_messages import WORLD_MESSAGE, WorldMessage

HEADER = struct.Struct(">I")
MAX_MESSAGE_BYTES = 1 << 20

M = TypeVar("M", bound=BaseModel)
C = TypeVar("C", bound="FramedChannel")  # type: ignore[type-arg]


class ChannelClosedError(RemoteError, ConnectionError):
    """The other process closed its end (or it sent something that is not a message)."""


def encode(message: BaseModel) -> bytes:
    """One framed message."""
    body = message.model_dump_json().encode()
    if len(body) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message of {len(body)} bytes exceeds {MAX_MESSAGE_BYTES}")
    return HEADER.pack(len(body)) + body


STREAM_LIMIT = MAX_MESSAGE_BYTES + HEADER.size


async def _streams(sock: socket.socket) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    return await asyncio.open_connection(sock=sock, limit=STREAM_LIMIT)


async def _unix_streams(path: Path) -> tuple[asyncio.StreamReader, asyncio.StreamWriter]:
    try:
        return await asyncio.open_unix_connection(str(path), limit=STREAM_LIMIT)
    except OSError as error:
        raise ChannelClosedError(f"cannot connect to {path}: {error.strerror}") from error


class FramedChannel(Generic[M]):
    """One end of a stream of ``messages``, used from a single event loop."""

    def __init__(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, messages: TypeAdapter[M]
    ) -> None:
        self._reader = reader
        self._writer = writer
        self._messages = messages

    async def receive(self) -> M:
        """The next message; raises ``ChannelClosedError`` at the end of the stream."""
        try:
            header = await self._reader.readexactly(HEADER.size)
            (length,) = HEADER.unpack(header)
            if length > MAX_MESSAGE_BYTES:
                raise ChannelClosedError(f"message of {length} bytes exceeds {MAX_MESSAGE_BYTES}")
            body = await self._reader.readexactly(length)
        except (asyncio.IncompleteReadError, ConnectionError) as error:
            raise ChannelClosedError(str(error)) from error
        try:
            return self._messages.validate_json(body)
        except ValidationError as error:
            raise ChannelClosedError(f"not a channel message: {error}") from error

    def send(self, message: M) -> None:
        """Queue a message for sending (never blocks; see ``drain``)."""
        if self._writer.is_closing():
            raise ChannelClosedError("channel is closed")
        self._writer.write(encode(message))

    async def drain(self) -> None:
        """Wait until the send buffer is below its high-water mark."""
        try:
            await self._writer.drain()
        except ConnectionError as error:
            raise ChannelClosedError(str(error)) from error

    @property
    def buffered_bytes(self) -> int:
        """Bytes queued but not yet written to the socket."""
        return self._writer.transport.get_write_buffer_size()

    async def close(self) -> None:
        self._writer.close()
        with contextlib.suppress(ConnectionError):
            await self._writer.wait_closed()


class Channel(FramedChannel[ChannelMessage]):
    """API process ⇄ flight process."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        super().__init__(reader, writer, CHANNEL_MESSAGE)

    @classmethod
    async def open(cls, sock: socket.socket) -> Channel:
        """Wrap a connected stream socket (one end of a ``socketpair``)."""
        return cls(*await _streams(sock))

    @classmethod
    async def connect(cls, path: Path) -> Channel:
        """Connect to the flight process's listening socket."""
        return cls(*await _unix_streams(path))


class WorldChannel(FramedChannel[WorldMessage]):
    """API process ⇄ simulated world's process."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        super().__init__(reader, writer, WORLD_MESSAGE)

    @classmethod
    async def open(cls, sock: socket.socket) -> WorldChannel:
        """Wrap a connected stream socket (one end of a ``socketpair``)."""
        return cls(*await _streams(sock))

    @classmethod
    async def connect(cls, path: Path) -> WorldChannel:
        """Connect to the world process's listening socket."""
        return cls(*await _unix_streams(path))


class ChannelServer:
    """The connections accepted on a listening Unix socket, each served as a channel."""

    def __init__(self) -> None:
        self._server: asyncio.Server | None = None
        self._open: dict[asyncio.Task[None], FramedChannel] = {}  # type: ignore[type-arg]

    async def start(
        self,
        listener: socket.socket,
        channel_type: Callable[[asyncio.StreamReader, asyncio.StreamWriter], C],
        on_channel: Callable[[C], Awaitable[None]],
    ) -> None:
        """Serve every connection to ``listener`` as a channel of ``channel_type``, handled
        by ``on_channel`` until it returns (the channel is closed then). ``on_channel`` must
        not raise: a bad peer ends its own connection only."""

        async def connected(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            channel = channel_type(reader, writer)
            task = asyncio.current_task()
            assert task is not None
            self._open[task] = channel
            try:
                await on_channel(channel)
            finally:
                del self._open[task]
                with contextlib.suppress(ChannelClosedError, ConnectionError):
                    await channel.close()

        self._server = await asyncio.start_unix_server(connected, sock=listener, limit=STREAM_LIMIT)

    async def close(self, timeout_s: float = 1.0) -> None:
        """Accept no more, close every open channel and let its handler finish."""
        if self._server is not None:
            self._server.close()
        handlers = list(self._open)
        for channel in list(self._open.values()):
            with contextlib.suppress(ChannelClosedError, ConnectionError):
                await channel.close()
        if handlers:
            await asyncio.wait(handlers, timeout=timeout_s)
