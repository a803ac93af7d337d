"""Both ends of the world channel: the API process's ``WorldClient`` (requests with
replies) and the world process's ``serve_world_requests`` (answers them in order)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import logging
from collections.abc import Callable
from typing import Any

from pydantic import ValidationError

from supervisor.flight.operator_requests import Outcome, Reply
from supervisor.flight.status import WorldStatus
from supervisor.ipc.channel import ChannelClosedError, WorldChannel
from supervisor.ipc.world_messages import (
    ListFaults,
    WorldReplyMessage,
    WorldRequest,
    WorldRequestMessage,
)

log = logging.getLogger(__name__)

WORLD_GONE = "the simulated world's process is not running"
WATCH_PERIOD_S = 0.5


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
        self.watched = WorldStatus(embedded=True)
        """What ``keep_watch`` last saw (not ``reachable``: ``view`` says that)."""

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

    async def keep_watch(self, period_s: float = WATCH_PERIOD_S) -> None:
        """Ask the world for its faults and its stalls every ``period_s``, for the status
        (``view``): a mocap gap while this computer stalled the world is not the lab's."""
        while self.connected:
            reply = await self.request(ListFaults())
            if reply.ok:
                self._watch(reply.data)
            await asyncio.sleep(period_s)

    def _watch(self, data: dict[str, Any]) -> None:
        """Keep what a ``ListFaults`` answer says; one that does not fit the status is
        logged and the last view kept (the status goes on without it)."""
        try:
            self.watched = WorldStatus(
                embedded=True,
                time_s=data["world_time_s"],
                faults=data["faults"],
                stalls=data["stalls"],
            )
        except (KeyError, ValidationError) as error:
            log.warning("the simulated world's faults and stalls do not fit the status: %s", error)

    def view(self) -> WorldStatus:
        """The world as the status shows it: reachable, and what ``keep_watch`` last saw."""
        seen = self.watched
        return WorldStatus(
            embedded=True,
            reachable=self.connected,
            time_s=seen.time_s,
            faults=seen.faults,
            stalls=seen.stalls,
        )

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
