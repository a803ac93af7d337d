"""Running the API under uvicorn inside our own event loop (one TaskGroup owns it)."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path

import uvicorn
from fastapi import FastAPI

from api.http_limits import HEAD_READ_DEADLINE_S, head_bounded_protocol

# The only message a client sends on the telemetry WebSocket is its token.
WS_MAX_MESSAGE_BYTES = 4096


@dataclass(frozen=True)
class TlsFiles:
    """A PEM certificate (chain) and its private key: the API then serves HTTPS and WSS."""

    cert_file: Path
    key_file: Path


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket (port 0: a free one), so the address is known before serving."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind((host, port))
    sock.listen(128)
    sock.setblocking(False)
    return sock


class _ServerWithoutSignals(uvicorn.Server):
    """Signals belong to the service, which stops the server itself."""

    @contextlib.contextmanager
    def capture_signals(self) -> Generator[None, None, None]:
        yield


class HttpServer:
    """uvicorn serving ``app`` on an already bound socket, over TLS when ``tls`` is given;
    ``serve`` returns after ``stop`` (graceful: open requests finish, WebSockets are
    closed). A request head must arrive whole within ``head_read_deadline_s`` of the
    connection's start or of the previous response, or the connection is closed; one over
    ``api.http_limits.MAX_HEAD_BYTES`` is answered 431."""

    def __init__(
        self,
        app: FastAPI,
        sock: socket.socket,
        tls: TlsFiles | None = None,
        head_read_deadline_s: float = HEAD_READ_DEADLINE_S,
    ) -> None:
        self.sock = sock
        self.scheme = "http" if tls is None else "https"
        config = uvicorn.Config(
            app,
            http=head_bounded_protocol(head_read_deadline_s),
            log_level="warning",
            lifespan="off",
            timeout_graceful_shutdown=2,
            ws_max_size=WS_MAX_MESSAGE_BYTES,
            ssl_certfile=None if tls is None else str(tls.cert_file),
            ssl_keyfile=None if tls is None else str(tls.key_file),
        )
        self._server = _ServerWithoutSignals(config)

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    async def serve(self) -> None:
        await self._server.serve(sockets=[self.sock])

    def stop(self) -> None:
        self._server.should_exit = True
