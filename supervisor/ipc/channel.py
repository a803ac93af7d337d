"""The stream between the API process and the flight process: length-prefixed JSON
messages (``supervisor.ipc.messages``) over a local stream socket (a ``socketpair`` made by
``serve``). Each frame is a 4-byte big-endian length and one UTF-8 JSON object.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import struct

from pydantic import ValidationError

from supervisor.errors import RemoteError
from supervisor.ipc.messages import CHANNEL_MESSAGE, ChannelMessage

HEADER = struct.Struct(">I")
MAX_MESSAGE_BYTES = 1 << 20


class ChannelClosedError(RemoteError, ConnectionError):
    """The other process closed its end (or it sent something that is not a message)."""


def encode(message: ChannelMessage) -> bytes:
    """One framed message."""
    body = message.model_dump_json().encode()
    if len(body) > MAX_MESSAGE_BYTES:
        raise ValueError(f"message of {len(body)} bytes exceeds {MAX_MESSAGE_BYTES}")
    return HEADER.pack(len(body)) + body


class Channel:
    """One end of the stream, used from a single event loop."""

    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._reader = reader
        self._writer = writer

    @classmethod
    async def open(cls, sock: socket.socket) -> Channel:
        """Wrap a connected stream socket (one end of a ``socketpair``)."""
        reader, writer = await asyncio.open_connection(sock=sock, limit=MAX_MESSAGE_BYTES + 8)
        return cls(reader, writer)

    async def receive(self) -> ChannelMessage:
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
            return CHANNEL_MESSAGE.validate_json(body)
        except ValidationError as error:
            raise ChannelClosedError(f"not a channel message: {error}") from error

    def send(self, message: ChannelMessage) -> None:
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
