"""Messages between the API process and the flight process: length-prefixed JSON over a
local stream socket (a ``socketpair`` made by ``serve``).

Each message is a 4-byte big-endian length and a UTF-8 JSON object. Requests carry an
``id`` that the reply repeats; the flight process also pushes telemetry (``{"kind":
"telemetry", ...}``) unprompted. JSON cannot carry NaN: non-finite numbers travel as null.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import socket
import struct
from typing import Any

from supervisor.logs.flight_log import finite_or_none

HEADER = struct.Struct(">I")
MAX_MESSAGE_BYTES = 1 << 20


class ChannelClosedError(ConnectionError):
    """The other process closed its end (or it sent something that is not a message)."""


def encode(message: dict[str, Any]) -> bytes:
    """One framed message."""
    body = json.dumps(finite_or_none(message), separators=(",", ":"), allow_nan=False).encode()
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

    async def receive(self) -> dict[str, Any]:
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
            message = json.loads(body)
        except ValueError as error:
            raise ChannelClosedError(f"not a JSON message: {error}") from error
        if not isinstance(message, dict):
            raise ChannelClosedError("a message must be a JSON object")
        return message

    def send(self, message: dict[str, Any]) -> None:
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
