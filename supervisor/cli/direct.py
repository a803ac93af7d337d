"""The terminal client's second path: abort or kill sent straight to the flight process's
listening socket, found through the discovery file ``serve`` writes for its port
(``supervisor.ipc.rendezvous``), for when the API process is dead or does not answer.

It speaks the channel's framing (``supervisor.ipc.channel``: a 4-byte big-endian length,
then one JSON message) on a blocking socket with only the standard library, so that an
abort does not wait for the service stack to be imported.
"""

from __future__ import annotations

import json
import socket
import struct
import time
from typing import Any
from urllib.parse import urlsplit

from supervisor.ipc.rendezvous import read_discovery

DIRECT_TIMEOUT_S = 2.0
HEADER = struct.Struct(">I")


class DirectPathError(Exception):
    """The flight process cannot be reached directly."""


def url_port(url: str) -> int:
    """The TCP port of a service URL (80 when none is given)."""
    return urlsplit(url).port or 80


def _send(sock: socket.socket, message: dict[str, Any]) -> None:
    body = json.dumps(message).encode()
    sock.sendall(HEADER.pack(len(body)) + body)


def _receive_exactly(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise DirectPathError("the flight process closed the connection")
        data += chunk
    return data


def _reply(sock: socket.socket) -> dict[str, Any]:
    """The first reply on the connection (id 0: the hello was refused)."""
    while True:
        (length,) = HEADER.unpack(_receive_exactly(sock, HEADER.size))
        message = json.loads(_receive_exactly(sock, length))
        if message.get("type") == "reply":
            reply: dict[str, Any] = message["reply"]
            return reply


def direct_request(url: str, token: str | None, kind: str) -> tuple[dict[str, Any], float]:
    """Send ``kind`` (abort or kill) to the flight process of the service at ``url`` on this
    computer; returns its reply (outcome, reason, data) and the seconds it took."""
    found = read_discovery(url_port(url))
    if found is None or "operator_socket" not in found:
        raise DirectPathError(f"no service on port {url_port(url)} of this computer")
    started = time.monotonic()
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(DIRECT_TIMEOUT_S)
            sock.connect(str(found["operator_socket"]))
            _send(sock, {"type": "hello", "role": "operator", "token": token})
            _send(sock, {"type": "request", "id": 1, "request": {"kind": kind}})
            return _reply(sock), time.monotonic() - started
    except TimeoutError:
        raise DirectPathError(
            f"no answer from the flight process in {DIRECT_TIMEOUT_S} s"
        ) from None
    except OSError as error:
        raise DirectPathError(f"cannot reach the flight process: {error.strerror}") from None
