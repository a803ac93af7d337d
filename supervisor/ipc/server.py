"""The flight process's side of a channel: answer requests one at a time, in order."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

from supervisor.ipc.channel import Channel

RequestHandler = Callable[[dict[str, Any]], Awaitable[dict[str, Any]]]


async def serve_requests(channel: Channel, handle: RequestHandler) -> None:
    """Receive requests and send each reply until the channel closes (raises
    ``ChannelClosedError`` then). A handler that fails answers ``invalid`` with the error."""
    while True:
        message = await channel.receive()
        try:
            reply = await handle(message)
        except Exception as error:  # a bad request must not take the flight process down
            reply = {
                "id": message.get("id"),
                "outcome": "invalid",
                "reason": f"request failed: {error!r}",
                "data": {},
            }
        channel.send(reply)
