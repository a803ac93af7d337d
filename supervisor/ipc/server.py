"""The flight process's side of a channel: answer requests one at a time, in order."""

from __future__ import annotations

from collections.abc import Awaitable, Callable

from supervisor.flight.operator_requests import Outcome, Reply, Request
from supervisor.ipc.channel import Channel
from supervisor.ipc.messages import ReplyMessage, RequestMessage

RequestHandler = Callable[[Request], Awaitable[Reply]]


async def serve_requests(channel: Channel, handle: RequestHandler) -> None:
    """Receive requests and send each reply until the channel closes (raises
    ``ChannelClosedError`` then). A handler that fails answers ``invalid`` with the error;
    what is not a request (the API process sends nothing else) is ignored."""
    while True:
        message = await channel.receive()
        if not isinstance(message, RequestMessage):
            continue
        try:
            reply = await handle(message.request)
        except Exception as error:  # a bad request must not take the flight process down
            reply = Reply(outcome=Outcome.INVALID, reason=f"request failed: {error!r}")
        channel.send(ReplyMessage(id=message.id, reply=reply))
