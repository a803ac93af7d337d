"""A small JSON-over-HTTP client on the standard library's ``http.client``, for the
terminal client: importing httpx alone takes longer than everything else ``status`` does
(0.2 s of 0.45 s measured, benchmarks/cli_startup.py). One connection, kept alive between
the polls of ``--wait``, opened again when the server closed it."""

from __future__ import annotations

import http.client
import json
from dataclasses import dataclass
from types import TracebackType
from typing import Any
from urllib.parse import urlsplit


class UnreachableError(Exception):
    """No HTTP answer: refused, timed out, reset, or not a server at that address."""


@dataclass(frozen=True)
class Response:
    """An HTTP answer: its status code and its body (parsed JSON, else the text)."""

    status: int
    body: Any


class JsonClient:
    """Requests to one service (``base_url``: ``http[s]://host[:port]``)."""

    def __init__(
        self,
        base_url: str,
        headers: dict[str, str],
        timeout_s: float,
        cafile: str | None = None,
    ) -> None:
        """Over HTTPS the server's certificate is checked against ``cafile`` (a PEM file;
        None: the system's CAs)."""
        parts = urlsplit(base_url)
        if parts.scheme not in ("http", "https") or not parts.hostname:
            raise ValueError(f"{base_url!r} is not an http:// or https:// address")
        self._https = parts.scheme == "https"
        self._host = parts.hostname
        self._port = parts.port
        self._prefix = parts.path.rstrip("/")
        self._headers = {"Accept": "application/json", **headers}
        self._timeout_s = timeout_s
        self._cafile = cafile
        self._connection: http.client.HTTPConnection | None = None

    def _connect(self) -> http.client.HTTPConnection:
        if self._connection is None:
            if self._https:
                import ssl  # only over HTTPS: it adds to every command's start otherwise

                try:
                    context = ssl.create_default_context(cafile=self._cafile)
                except OSError as error:
                    raise UnreachableError(
                        f"cannot read the certificate {self._cafile}: {error.strerror or error}"
                    ) from None
                self._connection = http.client.HTTPSConnection(
                    self._host, self._port, timeout=self._timeout_s, context=context
                )
            else:
                self._connection = http.client.HTTPConnection(
                    self._host, self._port, timeout=self._timeout_s
                )
        return self._connection

    def close(self) -> None:
        if self._connection is not None:
            self._connection.close()
            self._connection = None

    def request(self, method: str, path: str, body: Any = None) -> Response:
        """Send one request (``body``: JSON, or None); raises ``UnreachableError``."""
        headers = dict(self._headers)
        payload = None
        if body is not None:
            payload = json.dumps(body, allow_nan=False).encode()
            headers["Content-Type"] = "application/json"
        for attempt in range(2):
            connection = self._connect()
            try:
                connection.request(method, self._prefix + path, payload, headers)
                answer = connection.getresponse()
                data = answer.read()
                break
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError) as e:
                self.close()  # a kept-alive connection the server closed: once more afresh
                if attempt == 1:
                    raise UnreachableError(str(e) or type(e).__name__) from None
            except TimeoutError:
                self.close()
                raise UnreachableError(f"no answer within {self._timeout_s:g} s") from None
            except (OSError, http.client.HTTPException) as error:
                self.close()
                text = str(error) or type(error).__name__
                if "CERTIFICATE_VERIFY_FAILED" in text:
                    text += (
                        " (--cafile or $UAVBAR_CA_FILE names the certificate to trust: a "
                        "self-signed one is its own)"
                    )
                raise UnreachableError(text) from None
        text = data.decode(errors="replace")
        try:
            parsed: Any = json.loads(text)
        except ValueError:
            parsed = text
        return Response(answer.status, parsed)

    def __enter__(self) -> JsonClient:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        self.close()
