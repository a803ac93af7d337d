"""The gate in front of every route: Host, Origin, token, load and body size, decided on the
request's head before a byte of its body is read (a plain ASGI middleware).

In order (the first refusal answers, nothing behind it runs):

1. **Host** (421): a name must be on the allow-list; an IP address always passes, because
   DNS rebinding — a foreign page whose name now resolves to this machine — always sends
   the foreign *name* as its Host.
2. **Origin** (403): a request that changes something (POST, PUT, PATCH, DELETE) and the
   WebSocket are refused when their ``Origin`` is not this API's own (``null`` included).
   Browsers always send ``Origin`` on those; a client without one is not a web page.
3. **Declared size** (413): a ``Content-Length`` over the limit.
4. **Token** (401), by the route's access: ``token`` routes need ``Authorization: Bearer``;
   ``read`` routes need it when the API listens beyond loopback; ``abort`` takes the token
   *or* the dashboard's own origin — the emergency stop works from the page whatever its
   token (docs/architecture.md, "The API's gate"). The WebSocket's token is the route's
   (a browser cannot set headers on it).
5. **Load** (503, ``Retry-After``): under a flood (the event loop's last turn longer than
   ``shed_lag_s`` while requests arrive faster than ``shed_rate_hz``) or with
   ``max_requests_in_flight`` requests in flight, every request but the urgent ones
   (abort, kill) is shed unread.
6. **Body** (413): only now is the body read, here, counting bytes (a chunked one declares
   no length), and handed on whole, so a route never parses more than the limit.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import secrets
import socket
from collections.abc import Awaitable, Callable, Iterable, Mapping, MutableMapping
from dataclasses import dataclass
from enum import StrEnum
from typing import Any

from supervisor.app.config import listens_beyond_loopback

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

MUTATING_METHODS = frozenset({"POST", "PUT", "PATCH", "DELETE"})
WEBSOCKET = "WEBSOCKET"  # the method the access table files the WebSocket under
DEFAULT_MAX_BODY_BYTES = 65536  # 32 setpoints with every field are about 8 kB
# An abort needs a few turns of the event loop (its request, the flight process's reply,
# its answer), and under a flood each turn serves every request that arrived meanwhile:
# a flood beyond what the process can serve makes each turn longer than the last (measured:
# abort p99 1.2-1.9 s and aborts lost under 1000 requests/s on a busy 2-core machine). So
# while turns take longer than 20 ms *and* requests arrive faster than 250/s — a flood, not
# a busy machine: an operator sends a few a second — the API sheds what is not urgent,
# unread, at a fraction of a request's cost, and the turns shorten again: four stay within
# the abort's 100 ms. An operator's dashboard has a handful of requests in flight; 32 is
# far beyond it.
DEFAULT_SHED_LAG_S = 0.02
DEFAULT_SHED_RATE_HZ = 250.0
DEFAULT_MAX_REQUESTS_IN_FLIGHT = 32
LAG_PERIOD_S = 0.01
RATE_WINDOW_S = 0.1
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


class Access(StrEnum):
    """Who may call a route (its OpenAPI operation carries it as ``x-access``)."""

    OPEN = "open"  # the dashboard's files and the OpenAPI document
    READ = "read"  # the token when the API listens beyond loopback
    TOKEN = "token"  # always the token
    ABORT = "abort"  # the token, or a request from the dashboard's own origin


@dataclass(frozen=True)
class HttpPolicy:
    """What the gate enforces. ``allowed_hosts``: the names a Host header may carry
    (lower case; IP addresses always pass); ``reads_need_token``: the API listens beyond
    loopback; ``max_body_bytes``: the largest request body read;
    ``shed_lag_s``, ``shed_rate_hz``, ``max_requests_in_flight``: with the event loop this
    late while requests arrive this fast, or with this many requests at once, all but the
    urgent ones are answered 503 at once."""

    token: str
    allowed_hosts: frozenset[str] = frozenset(LOOPBACK_NAMES)
    reads_need_token: bool = False
    max_body_bytes: int = DEFAULT_MAX_BODY_BYTES
    shed_lag_s: float = DEFAULT_SHED_LAG_S
    shed_rate_hz: float = DEFAULT_SHED_RATE_HZ
    max_requests_in_flight: int = DEFAULT_MAX_REQUESTS_IN_FLIGHT

    def token_matches(self, authorization: str | None) -> bool:
        """``authorization`` is ``Bearer TOKEN`` with this policy's token."""
        scheme, _, presented = (authorization or "").partition(" ")
        return scheme.lower() == "bearer" and secrets.compare_digest(
            presented.encode(), self.token.encode()
        )


def http_policy(
    token: str,
    api_host: str,
    allowed_hosts: Iterable[str] | None = None,
    max_body_bytes: int = DEFAULT_MAX_BODY_BYTES,
) -> HttpPolicy:
    """The policy for an API bound to ``api_host``. ``allowed_hosts`` unset: localhost,
    this machine's host name and fully qualified name, and ``api_host`` itself."""
    if allowed_hosts is None:
        allowed_hosts = [*LOOPBACK_NAMES, socket.gethostname(), socket.getfqdn(), api_host]
    return HttpPolicy(
        token=token,
        allowed_hosts=frozenset(name.lower().strip("[]") for name in allowed_hosts),
        reads_need_token=listens_beyond_loopback(api_host),
        max_body_bytes=max_body_bytes,
    )


@dataclass(frozen=True)
class Refusal:
    """The gate's answer to a request it stops."""

    status: int
    detail: str
    headers: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class Admission:
    """A request the gate lets through: whether it carried the token, and its origin."""

    authenticated: bool
    origin: str | None


def _host_name(host: str) -> str:
    """The name in a Host header, without its port (IPv6 literals without brackets)."""
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    return host.rsplit(":", 1)[0] if host.count(":") == 1 else host


def _is_ip_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def own_origin(scheme: str, host: str) -> str:
    """This API's origin as a browser writes it, for a request with ``scheme`` and Host."""
    http_scheme = {"ws": "http", "wss": "https"}.get(scheme, scheme)
    return f"{http_scheme}://{host}".lower()


def admit(
    policy: HttpPolicy,
    method: str,
    scheme: str,
    headers: Mapping[str, str],
    access: Access | None,
) -> Admission | Refusal:
    """The gate's decision on a request's head (``headers`` lower-case names; ``method``
    ``WEBSOCKET`` for the WebSocket; ``access`` None for a path no route serves: the
    router answers it, 404 or 405)."""
    host = headers.get("host", "")
    name = _host_name(host).lower()
    if not (_is_ip_address(name) or name in policy.allowed_hosts):
        return Refusal(421, f"this API does not serve the host {host!r} (api.allowed_hosts)")
    origin = headers.get("origin")
    same_origin = origin is not None and origin.lower() == own_origin(scheme, host)
    changes_or_streams = method in MUTATING_METHODS or method == WEBSOCKET
    if changes_or_streams and origin is not None and not same_origin:
        return Refusal(403, f"requests from another origin ({origin}) are refused")
    length = declared_length(headers)
    if length is not None and length > policy.max_body_bytes:
        return _too_large(policy)
    authenticated = policy.token_matches(headers.get("authorization"))
    needs_token = access is Access.TOKEN or (access is Access.READ and policy.reads_need_token)
    if access is Access.ABORT:
        needs_token = not same_origin
    if needs_token and not authenticated and method != WEBSOCKET:
        wrong = headers.get("authorization") is not None
        what = (
            "the token presented is not this service's"
            if wrong
            else "no token: this request needs an 'Authorization: Bearer TOKEN' header"
        )
        return Refusal(401, f"{what}; {WHERE_THE_TOKEN_IS}", (("www-authenticate", "Bearer"),))
    return Admission(authenticated, origin)


WHERE_THE_TOKEN_IS = (
    "the token is the one `serve` printed as it started (its line 'API token', or the "
    "dashboard address's #token=), or the UAVBAR_TOKEN it was started with"
)


class BodyTooLargeError(Exception):
    """A request body beyond the policy's limit."""


def declared_length(headers: Mapping[str, str]) -> int | None:
    """The body length a request declares (None: chunked or unparseable, so counted)."""
    try:
        return int(headers["content-length"])
    except (KeyError, ValueError):
        return None


AccessTable = Mapping[tuple[str, str], Access]


class LoadMeter:
    """How loaded the event loop is: the requests in flight, how late a timer due every
    10 ms last fired (about the length of the loop's last turn) [s], and the requests that
    arrived per second over the last 0.1 s."""

    def __init__(self) -> None:
        self.in_flight = 0
        self.lag_s = 0.0
        self.rate_hz = 0.0
        self._arrivals = 0
        self._window_start_s = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None

    def arrived(self, loop: asyncio.AbstractEventLoop) -> None:
        """A request came (the first one on ``loop`` starts the timing)."""
        self._arrivals += 1
        if loop is not self._loop:
            self._loop = loop
            self._window_start_s = loop.time()
            self._expect(loop)

    def _expect(self, loop: asyncio.AbstractEventLoop) -> None:
        due = loop.time() + LAG_PERIOD_S
        loop.call_at(due, self._fired, loop, due)

    def _fired(self, loop: asyncio.AbstractEventLoop, due: float) -> None:
        if loop is not self._loop:
            return  # a loop of the past (tests): let its timer end
        now = loop.time()
        self.lag_s = now - due
        if now - self._window_start_s >= RATE_WINDOW_S:
            self.rate_hz = self._arrivals / (now - self._window_start_s)
            self._arrivals, self._window_start_s = 0, now
        self._expect(loop)

    def overloaded(self, policy: HttpPolicy) -> bool:
        """A flood the loop cannot keep up with, or too many requests at once."""
        flooded = self.lag_s > policy.shed_lag_s and self.rate_hz > policy.shed_rate_hz
        return flooded or self.in_flight >= policy.max_requests_in_flight


class Gate:
    """The ASGI middleware applying ``admit`` and the body limit to every request; ``routes``
    maps (method, path) to each route's access; ``urgent`` are the paths never shed under
    load (abort, kill). A known path asked with another method
    is answered 405 with every method it has in ``Allow`` (RFC 9110 §15.5.6). What the
    gate admitted is in the scope's state: ``authenticated`` and ``origin``."""

    def __init__(
        self, app: ASGIApp, policy: HttpPolicy, routes: AccessTable, urgent: frozenset[str]
    ) -> None:
        self.app = app
        self.policy = policy
        self.routes = routes
        self.urgent = urgent
        self.load = LoadMeter()
        self.methods: dict[str, set[str]] = {}
        for method, path in routes:
            if method != WEBSOCKET:
                self.methods.setdefault(path, set()).add(method)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        self.load.arrived(asyncio.get_running_loop())
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        method = scope["method"] if scope["type"] == "http" else WEBSOCKET
        access = self.routes.get((method, scope["path"]))
        decision = admit(self.policy, method, scope["scheme"], headers, access)
        if isinstance(decision, Refusal):
            await _refuse(scope, send, decision)
            return
        scope.setdefault("state", {}).update(
            authenticated=decision.authenticated, origin=decision.origin
        )
        if scope["type"] == "websocket":
            await self.app(scope, receive, send)
            return
        allowed = self.methods.get(scope["path"])
        if access is None and allowed:
            allow = ", ".join(sorted(allowed))
            await _refuse(scope, send, Refusal(405, "Method Not Allowed", (("allow", allow),)))
            return
        if scope["path"] not in self.urgent and self.load.overloaded(self.policy):
            await _refuse(scope, send, BUSY)
            return
        self.load.in_flight += 1
        try:
            body = await _read_body(receive, self.policy.max_body_bytes)
        except BodyTooLargeError:
            await _refuse(scope, send, _too_large(self.policy))
            return
        else:
            await self.app(scope, _replay(body, receive), send)
        finally:
            self.load.in_flight -= 1


BUSY = Refusal(
    503, "busy: too many requests at once (an abort is still served)", (("retry-after", "1"),)
)


def _too_large(policy: HttpPolicy) -> Refusal:
    return Refusal(
        413,
        f"the request body is larger than {policy.max_body_bytes} bytes (api.max_body_bytes)",
        # The unread rest of the body would otherwise be taken as the next request.
        (("connection", "close"),),
    )


async def _read_body(receive: Receive, limit: int) -> bytes:
    chunks: list[bytes] = []
    size = 0
    while True:
        message = await receive()
        if message["type"] != "http.request":
            break  # the client went away: the route sees an empty body and answers no one
        chunk = message.get("body", b"")
        size += len(chunk)
        if size > limit:
            raise BodyTooLargeError
        chunks.append(chunk)
        if not message.get("more_body", False):
            break
    return b"".join(chunks)


def _replay(body: bytes, receive: Receive) -> Receive:
    """The body read, as one message; after it, the connection's own (disconnects)."""
    delivered = False

    async def replayed() -> Message:
        nonlocal delivered
        if delivered:
            return await receive()
        delivered = True
        return {"type": "http.request", "body": body, "more_body": False}

    return replayed


async def _refuse(scope: Scope, send: Send, refusal: Refusal) -> None:
    body = json.dumps({"detail": refusal.detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", b"%d" % len(body))]
    headers += [(k.encode(), v.encode()) for k, v in refusal.headers]
    start = "http.response.start"
    if scope["type"] == "websocket":
        # The WebSocket denial response (ASGI's websocket.http.response extension):
        # the handshake is answered with the status, the socket never opens.
        if "websocket.http.response" not in scope.get("extensions", {}):
            await send({"type": "websocket.close", "code": 1008})
            return
        start = "websocket.http.response.start"
    await send({"type": start, "status": refusal.status, "headers": headers})
    body_type = (
        "websocket.http.response.body" if scope["type"] == "websocket" else "http.response.body"
    )
    await send({"type": body_type, "body": body})
