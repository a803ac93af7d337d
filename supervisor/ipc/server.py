"""The flight process's side of a connection: who may connect, what each may ask, and
answering requests one at a time, in order."""

from __future__ import annotations

import secrets
from collections.abc import Awaitable, Callable
from dataclasses import dataclass

from supervisor.flight.operator_requests import Outcome, Reply, Request, is_urgent
from supervisor.ipc.channel import Channel
from supervisor.ipc.messages import (
    ChannelMessage,
    ConnectionRole,
    HelloMessage,
    ReplyMessage,
    RequestMessage,
)

RequestHandler = Callable[[Request], Awaitable[Reply]]
HELLO_TIMEOUT_S = 2.0


@dataclass(frozen=True)
class Admission:
    """An accepted connection: its role and whether it presented the API token."""

    role: ConnectionRole
    authenticated: bool


def admit(first: ChannelMessage, token: str) -> Admission | str:
    """The admission of a connection whose first message is ``first``, or why not."""
    if not isinstance(first, HelloMessage):
        return f"a connection must begin with a hello, not a {first.type}"
    authenticated = first.token is not None and secrets.compare_digest(
        first.token.encode(), token.encode()
    )
    if first.role != "operator" and not authenticated:
        return f"the {first.role} connection needs the API token"
    return Admission(first.role, authenticated)


def refusal(admission: Admission, request: Request) -> str | None:
    """Why this connection may not ask ``request`` (None: it may). The direct operator
    path aborts (anyone who can reach the socket may stop a flight) and kills (with the
    token); everything else goes through the API."""
    if admission.role != "operator":
        return None
    if not is_urgent(request):
        return "the direct path takes abort and kill only"
    if request.kind == "kill" and not admission.authenticated:
        return "kill needs the API token"
    return None


async def serve_requests(channel: Channel, handle: RequestHandler) -> None:
    """Receive requests and send each reply until the channel closes (raises
    ``ChannelClosedError`` then). A handler that fails answers ``invalid`` with the error;
    what is not a request is ignored."""
    while True:
        message = await channel.receive()
        if not isinstance(message, RequestMessage):
            continue
        try:
            reply = await handle(message.request)
        except Exception as error:  # a bad request must not take the flight process down
            reply = Reply(outcome=Outcome.INVALID, reason=f"request failed: {error!r}")
        channel.send(ReplyMessage(id=message.id, reply=reply))
