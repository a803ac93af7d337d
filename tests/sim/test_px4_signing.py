"""The simulated PX4 enforcing MAVLink 2 signing after SETUP_SIGNING, on loopback: the
supervisor's link gives it the key, then unsigned commands (and an unsigned new key) from
anyone are refused and the link's signed ones obeyed."""

from __future__ import annotations

import asyncio
import contextlib
import secrets
import socket
from collections.abc import AsyncIterator, Iterator

import pytest

from px4_mavlink.codec import MavlinkCodec
from sim.px4_endpoint import Px4Endpoint
from supervisor.mavlink.link import LinkConfig, MavlinkLink
from tests.mocap.test_client import wait_until
from tests.sim.test_px4_endpoint import Resting

KEY = secrets.token_bytes(32)


@contextlib.asynccontextmanager
async def running_px4() -> AsyncIterator[Px4Endpoint]:
    """A simulated PX4 on loopback, stepped in real time."""
    px4 = Px4Endpoint(0, Resting(), local_port=0, client_port=9)  # until a client talks
    await px4.start()
    loop = asyncio.get_running_loop()
    start_s = loop.time()

    async def run() -> None:
        while True:
            px4.step(loop.time() - start_s)
            await asyncio.sleep(0.005)

    stepping = asyncio.create_task(run())
    try:
        yield px4
    finally:
        stepping.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await stepping
        await px4.close()


@pytest.fixture
def rogue() -> Iterator[socket.socket]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.setblocking(False)
    yield sock
    sock.close()


def unsigned(build: str, *args: object) -> bytes:
    codec = MavlinkCodec(255, 190)  # the supervisor's ids, without its key
    getattr(codec.messages, build)(*args)
    [frame] = codec.outgoing()
    return frame


def drain(sock: socket.socket) -> int:
    received = 0
    with contextlib.suppress(BlockingIOError):
        while True:
            sock.recvfrom(65535)
            received += 1
    return received


async def test_after_setup_signing_only_signed_commands_are_obeyed(rogue: socket.socket) -> None:
    async with running_px4() as px4:
        settings = LinkConfig(
            system_id=1, local_port=0, vehicle_address=("127.0.0.1", px4.local_port),
            ack_timeout_s=0.2, signing_key=KEY,
        )  # fmt: skip
        link = MavlinkLink(settings)
        await link.start()
        try:
            await wait_until(lambda: link.connected)
            assert px4.signing and link.counters.setup_signing_sent >= 1
            assert link.counters.messages > 0  # its telemetry, signed with the key
            address = ("127.0.0.1", px4.local_port)
            refused = px4.counters.unsigned
            arm = unsigned("command_long_send", 1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0)
            new_key = unsigned("setup_signing_send", 1, 1, list(secrets.token_bytes(32)), 1)
            rogue.sendto(arm, address)
            rogue.sendto(new_key, address)
            await wait_until(lambda: px4.counters.unsigned == refused + 2)
            await asyncio.sleep(0.1)
            assert not px4.armed and drain(rogue) == 0  # not obeyed, not answered
            assert px4.signing and link.connected  # the key is still ours
            await link.arm()  # signed: accepted
            await wait_until(lambda: px4.armed)
            await link.disarm()
            await wait_until(lambda: not px4.armed)
        finally:
            await link.close()


async def test_without_a_key_the_simulated_px4_takes_anything(rogue: socket.socket) -> None:
    """As PX4 with no key on its SD card: unsigned commands are obeyed."""
    async with running_px4() as px4:
        arm = unsigned("command_long_send", 1, 1, 400, 0, 1.0, 0, 0, 0, 0, 0, 0)
        rogue.sendto(arm, ("127.0.0.1", px4.local_port))
        await wait_until(lambda: px4.armed)
        assert not px4.signing and px4.counters.unsigned == 0
