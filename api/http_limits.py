"""Bounds on reading a request's head, in uvicorn's h11 protocol: a deadline for its
arrival (slow or stalled clients are closed) and a size limit (431).

uvicorn bounds neither: its keep-alive timer is not armed on a new connection and is
stopped by the first byte after a response, httptools (its default parser) has no head size
limit, and h11's ``max_incomplete_event_size`` bounds a head still incomplete, not one that
arrives whole in one read. h11 is the parser here because, being sans-IO, it tells exactly
where a head ends, pipelined or not (its buffer before and after the ``Request`` event);
httptools tells no offsets.
"""

from __future__ import annotations

import asyncio
from http import HTTPStatus
from typing import Any

import h11
from uvicorn.config import Config
from uvicorn.protocols.http.h11_impl import H11Protocol
from uvicorn.server import ServerState

# Precedents: uvicorn's keep-alive timeout (5 s), Apache's RequestReadTimeout (20 s for a
# head, more for a client sending 500 B/s). Every client of this API (browsers, httpx,
# http.client, websockets) sends its head in one write: a few seconds leave room for a slow
# network, not for a connection held open.
HEAD_READ_DEADLINE_S = 5.0
# Precedents: h11's and Node's limit (16 KiB), nginx's large_client_header_buffers
# (4 x 8 KiB). A browser sends every localhost cookie, whatever the port, to the dashboard,
# so the larger of them.
MAX_HEAD_BYTES = 32 * 1024

_TOO_LARGE = HTTPStatus.REQUEST_HEADER_FIELDS_TOO_LARGE


class HeadLimitedConnection(h11.Connection):
    """h11's server side, refusing (``RemoteProtocolError``, status hint 431) a request
    head — request line and header fields, up to its empty line — over ``max_head_bytes``,
    whether it arrives whole or in pieces. ``head_too_large`` tells why it refused."""

    def __init__(self, max_head_bytes: int) -> None:
        # h11 itself refuses an incomplete head once its buffer holds more than this.
        super().__init__(h11.SERVER, max_incomplete_event_size=max_head_bytes)
        self.max_head_bytes = max_head_bytes
        self.head_too_large = False
        # The receive buffer's length while a head is awaited (their state IDLE).
        self._buffered_bytes = 0

    def receive_data(self, data: bytes) -> None:
        super().receive_data(data)
        self._buffered_bytes += len(data)

    def start_next_cycle(self) -> None:
        super().start_next_cycle()
        # What a pipelining client sent after its previous request is already buffered.
        self._buffered_bytes = len(self.trailing_data[0])

    def next_event(self) -> h11.Event | type[h11.NEED_DATA] | type[h11.PAUSED]:
        awaiting_head = self.their_state is h11.IDLE
        try:
            event = super().next_event()
        except h11.RemoteProtocolError as error:
            self.head_too_large = awaiting_head and error.error_status_hint == _TOO_LARGE
            raise
        if isinstance(event, h11.Request):
            head_bytes = self._buffered_bytes - len(self.trailing_data[0])
            if head_bytes > self.max_head_bytes:
                self.head_too_large = True
                raise h11.RemoteProtocolError(
                    f"request head of {head_bytes} bytes", error_status_hint=_TOO_LARGE
                )
        return event


class HeadBoundedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol, answering a head over ``MAX_HEAD_BYTES`` with 431 (and
    closing), and closing a connection whose next request head has not arrived whole
    ``head_read_deadline_s`` after the connection began or the previous request's response
    was written. Bytes arriving meanwhile do not postpone it; a request being served, its
    body and a WebSocket it upgraded to are not under it."""

    head_read_deadline_s = HEAD_READ_DEADLINE_S

    def __init__(
        self,
        config: Config,
        server_state: ServerState,
        app_state: dict[str, Any],
        _loop: asyncio.AbstractEventLoop | None = None,
    ) -> None:
        super().__init__(config, server_state, app_state, _loop)
        self.conn: HeadLimitedConnection = HeadLimitedConnection(MAX_HEAD_BYTES)
        self._head_deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._follow_head_state()

    def connection_lost(self, exc: Exception | None) -> None:
        super().connection_lost(exc)
        self._run_head_deadline(False)

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._follow_head_state()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._follow_head_state()

    def send_400_response(self, msg: str) -> None:
        """uvicorn's answer to any ``RemoteProtocolError``: 431 when the head was too large."""
        if not self.conn.head_too_large:
            super().send_400_response(msg)
            return
        body = _TOO_LARGE.phrase.encode()
        headers = [
            (b"content-type", b"text/plain; charset=utf-8"),
            (b"content-length", str(len(body)).encode()),
            (b"connection", b"close"),
        ]
        for event in (
            h11.Response(status_code=_TOO_LARGE, headers=headers, reason=body),
            h11.Data(data=body),
            h11.EndOfMessage(),
        ):
            self.transport.write(self.conn.send(event))
        self.transport.close()

    def _follow_head_state(self) -> None:
        """The deadline runs from entering h11's IDLE (awaiting a request head) until leaving
        it; it is set once per head, not moved by bytes that arrive."""
        self._run_head_deadline(
            self.conn.their_state is h11.IDLE and not self.transport.is_closing()
        )

    def _run_head_deadline(self, running: bool) -> None:
        if running and self._head_deadline is None:
            self._head_deadline = self.loop.call_later(
                self.head_read_deadline_s, self._head_deadline_passed
            )
        elif not running and self._head_deadline is not None:
            self._head_deadline.cancel()
            self._head_deadline = None

    def _head_deadline_passed(self) -> None:
        self._head_deadline = None
        self.transport.close()


def head_bounded_protocol(deadline_s: float) -> type[HeadBoundedH11Protocol]:
    """The protocol class for ``uvicorn.Config(http=...)``, with this head read deadline."""

    class Protocol(HeadBoundedH11Protocol):
        head_read_deadline_s = deadline_s

    return Protocol
