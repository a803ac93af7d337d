"""Both ends of the world channel: the API process's ``WorldClient`` (requests with
replies) and the world process's ``serve_world_requests`` (answers them in order)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
from collections.abc import Callable

from supervisor.flight.operator_requests import Outcome, Reply
from supervisor.ipc.channel import ChannelClosedError, WorldChannel
from supervisor.ipc.world_messages import WorldReplyMessage, WorldRequest, WorldRequestMessage

WORLD_GONE = "the simulated world's process is not running"


class WorldClient:
    """Requests to the simulated world's process (fault injection, reset)."""

    def __init__(self, channel: WorldChannel | None, timeout_s: float = 2.0) -> None:
        """``channel`` None: the world could not be reached (every request is answered
        ``unavailable``)."""
        self._channel = channel
        self._timeout_s = timeout_s
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[Reply]] = {}
        self.connected = channel is not None

    async def run(self) -> None:
        """Receive replies until the world process goes away."""
        if self._channel is None:
            return
        try:
            while True:
                message = await self._channel.receive()
                if isinstance(message, WorldReplyMessage):
                    future = self._pending.pop(message.id, None)
                    if future is not None and not future.done():
                        future.set_result(message.reply)
        except ChannelClosedError:
            pass
        finally:
            self.connected = False
            for future in self._pending.values():
                if not future.done():
                    future.set_exception(ChannelClosedError(WORLD_GONE))

    async def request(self, request: WorldRequest) -> Reply:
        """Send a request and wait for its reply (``unavailable`` when no world answers)."""
        if not self.connected or self._channel is None:
            return Reply(outcome=Outcome.UNAVAILABLE, reason=WORLD_GONE)
        request_id = next(self._ids)
        future: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        self._pending[request_id] = future
        try:
            self._channel.send(WorldRequestMessage(id=request_id, request=request))
            async with asyncio.timeout(self._timeout_s):
                return await future
        except TimeoutError:
            reason = f"no answer from the simulated world in {self._timeout_s} s"
            return Reply(outcome=Outcome.UNAVAILABLE, reason=reason)
        except ChannelClosedError:
            return Reply(outcome=Outcome.UNAVAILABLE, reason=WORLD_GONE)
        finally:
            self._pending.pop(request_id, None)

    async def close(self) -> None:
        if self._channel is not None:
            with contextlib.suppress(ChannelClosedError):
                await self._channel.close()


WorldRequestHandler = Callable[[WorldRequest], Reply]


async def serve_world_requests(channel: WorldChannel, handle: WorldRequestHandler) -> None:
    """Answer requests until the channel closes (raises ``ChannelClosedError`` then). A
    handler that fails answers ``invalid`` with the error, and the world goes on."""
    while True:
        message = await channel.receive()
        if not isinstance(message, WorldRequestMessage):
            continue
        try:
            reply = handle(message.request)
        except Exception as error:  # a bad request must not take the world down
            reply = Reply(outcome=Outcome.INVALID, reason=f"request failed: {error!r}")
        channel.send(WorldReplyMessage(id=message.id, reply=reply))
