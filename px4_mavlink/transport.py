"""One UDP socket on asyncio for a MAVLink endpoint: datagrams in, with their sender, to a
callback; frames out to the current peer. The only MAVLink code that touches a socket; the
supervisor's link and the simulated PX4 both use it."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Callable, Iterable

Address = tuple[str, int]
DatagramHandler = Callable[[bytes, Address], None]


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, on_datagram: DatagramHandler) -> None:
        self.on_datagram = on_datagram

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        self.on_datagram(data, (str(addr[0]), int(addr[1])))


class UdpTransport:
    """A bound UDP socket; ``peer`` is where ``send`` goes (nothing is sent without one)."""

    def __init__(self, transport: asyncio.DatagramTransport, peer: Address | None) -> None:
        self._transport = transport
        self.peer = peer

    @classmethod
    async def open(
        cls,
        local: Address,
        on_datagram: DatagramHandler,
        peer: Address | None = None,
        sock: socket.socket | None = None,
    ) -> UdpTransport:
        """Bind ``local`` (port 0: any free port) — or take ``sock``, already bound — and
        deliver what arrives to ``on_datagram``."""
        loop = asyncio.get_running_loop()
        if sock is not None:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(on_datagram), sock=sock
            )
        else:
            transport, _ = await loop.create_datagram_endpoint(
                lambda: _Protocol(on_datagram), local_addr=local
            )
        return cls(transport, peer)

    @property
    def local_port(self) -> int:
        return int(self._transport.get_extra_info("sockname")[1])

    def send(self, frames: Iterable[bytes]) -> None:
        """One datagram per frame, to ``peer`` (never blocks)."""
        if self.peer is None or self._transport.is_closing():
            return
        for frame in frames:
            self._transport.sendto(frame, self.peer)

    def close(self) -> None:
        self._transport.close()


def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``host``:``port`` (0: any free port), non-blocking, to hand to
    ``UdpTransport.open`` in this or another process."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host, port))
    except OSError:
        sock.close()
        raise
    sock.setblocking(False)
    return sock
