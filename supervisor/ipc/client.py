"""The API process's handle on the flight process: requests with replies, the latest
telemetry, and a fan-out of telemetry to subscribers (WebSocket clients).

Two connections to the flight process's listening socket: ``commands`` carries ordinary
requests and the telemetry stream; ``urgent`` carries only abort and kill, so that they
never wait behind anything else. ``stay_connected`` connects again whenever the flight
process goes away (``serve`` restarts it), so one client lasts the API process's life.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import time
from pathlib import Path

from supervisor.flight.operator_requests import Outcome, Reply, Request, is_urgent
from supervisor.flight.status import FlightStatus
from supervisor.ipc.channel import Channel, ChannelClosedError
from supervisor.ipc.messages import HelloMessage, ReplyMessage, RequestMessage, TelemetryMessage

# supervisor.vehicles.sequences.arm_for_offboard: 1.2 s of proof of life, then two commands
# of up to 3 × 0.5 s each on a slow link.
ARM_TIMEOUT_S = 8.0
RECONNECT_S = 0.2


async def connect_to_flight(path: Path, token: str) -> tuple[Channel, Channel]:
    """The API process's two connections to the flight process at ``path``."""
    channels = []
    for role in ("commands", "urgent"):
        channel = await Channel.connect(path)
        channel.send(HelloMessage(role=role, token=token))
        channels.append(channel)
    return channels[0], channels[1]


def _unavailable(reason: str) -> Reply:
    return Reply(outcome=Outcome.UNAVAILABLE, reason=reason)


class SubscriptionEndedError(Exception):
    """The API process is stopping: no more telemetry for this subscriber."""


class TelemetrySubscription:
    """Telemetry for one consumer; a slow consumer loses the oldest messages, never
    slows the others."""

    def __init__(self, owner: FlightClient, depth: int) -> None:
        self._owner = owner
        self.queue: asyncio.Queue[FlightStatus | None] = asyncio.Queue(maxsize=depth)
        self.dropped = 0

    def offer(self, message: FlightStatus | None) -> None:
        """Queue ``message`` (None: the end), dropping the oldest when full."""
        if self.queue.full():
            self.queue.get_nowait()
            self.dropped += 1
        self.queue.put_nowait(message)

    async def next(self) -> FlightStatus:
        """The next message; raises ``SubscriptionEndedError`` once the client ends them."""
        message = await self.queue.get()
        if message is None:
            self.queue.put_nowait(None)  # and for any later call
            raise SubscriptionEndedError
        return message

    def close(self) -> None:
        self._owner.unsubscribe(self)


class FlightClient:
    """Requests to, and telemetry from, the flight process."""

    def __init__(
        self, commands: Channel | None, urgent: Channel | None, timeout_s: float = 2.0
    ) -> None:
        self._channels: dict[str, Channel] = {}
        self._timeout_s = timeout_s
        self._ids = itertools.count(1)
        self._pending: dict[int, asyncio.Future[Reply]] = {}
        self._subscribers: set[TelemetrySubscription] = set()
        self.latest: FlightStatus | None = None
        self.latest_at_s = -float("inf")
        self.connected = False
        if commands is not None and urgent is not None:
            self.attach(commands, urgent)

    def attach(self, commands: Channel, urgent: Channel) -> None:
        """Talk to the flight process on these channels from now on."""
        self._channels = {"commands": commands, "urgent": urgent}
        self.connected = True

    async def stay_connected(self, path: Path, token: str) -> None:
        """Connect to the flight process at ``path``, run, and connect again whenever it
        goes away, for ever (cancel to stop)."""
        while True:
            try:
                self.attach(*await connect_to_flight(path, token))
            except ChannelClosedError:
                await asyncio.sleep(RECONNECT_S)
                continue
            await self.run()
            await self.close()
            await asyncio.sleep(RECONNECT_S)

    @property
    def telemetry_age_s(self) -> float:
        return time.monotonic() - self.latest_at_s

    async def run(self) -> None:
        """Receive replies and telemetry until the flight process goes away."""
        try:
            async with asyncio.TaskGroup() as group:
                for channel in self._channels.values():
                    group.create_task(self._receive(channel))
        except* ChannelClosedError:
            pass
        finally:
            self.connected = False
            # What it last said is stale from now on, even once connected again: a new
            # flight process's first telemetry is what freshens it.
            self.latest_at_s = -float("inf")
            for future in self._pending.values():
                if not future.done():
                    future.set_exception(ChannelClosedError("flight process gone"))

    async def _receive(self, channel: Channel) -> None:
        while True:
            message = await channel.receive()
            if isinstance(message, TelemetryMessage):
                self.latest = message.status
                self.latest_at_s = time.monotonic()
                for subscriber in list(self._subscribers):
                    subscriber.offer(message.status)
            elif isinstance(message, ReplyMessage):
                future = self._pending.pop(message.id, None)
                if future is not None and not future.done():
                    future.set_result(message.reply)

    async def request(self, request: Request) -> Reply:
        """Send a request and wait for its reply (abort and kill take the urgent channel)."""
        if not self.connected:
            return _unavailable("the flight process is not running")
        request_id = next(self._ids)
        future: asyncio.Future[Reply] = asyncio.get_running_loop().create_future()
        self._pending[request_id] = future
        channel = self._channels["urgent" if is_urgent(request) else "commands"]
        # Arming answers after the vehicles' sequence: a second of proof of life, then
        # offboard and arm, each retried when an acknowledgement is late.
        timeout_s = ARM_TIMEOUT_S if request.kind == "arm" else self._timeout_s
        try:
            channel.send(RequestMessage(id=request_id, request=request))
            async with asyncio.timeout(timeout_s):
                return await future
        except TimeoutError:
            return _unavailable(f"no answer from the flight process in {timeout_s} s")
        except ChannelClosedError:
            return _unavailable("the flight process is not running")
        finally:
            self._pending.pop(request_id, None)

    def subscribe(self, depth: int = 8) -> TelemetrySubscription:
        subscription = TelemetrySubscription(self, depth)
        self._subscribers.add(subscription)
        if self.latest is not None:
            subscription.offer(self.latest)
        return subscription

    def unsubscribe(self, subscription: TelemetrySubscription) -> None:
        self._subscribers.discard(subscription)

    def end_subscriptions(self) -> None:
        """End every subscription (the API is stopping): each consumer's ``next`` raises
        ``SubscriptionEndedError``, so that a WebSocket closes at once and normally."""
        for subscriber in list(self._subscribers):
            subscriber.offer(None)

    async def close(self) -> None:
        for channel in self._channels.values():
            with contextlib.suppress(ChannelClosedError):
                await channel.close()
