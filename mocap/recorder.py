"""Records a live QTM RT stream (a real QTM or the simulator's server) into a ``Recording``.

The asyncio shell around ``mocap.qtm_protocol``: connect to the little-endian port, read
the greeting, negotiate the version (1.25 down to 1.8, as ``QtmClient``), read the body
names with ``GetParameters 6D``, bind a UDP socket on the address the TCP connection uses,
``StreamFrames AllFrames UDP:<port> <component>``, and keep every datagram from the QTM
host with its arrival time on ``clock`` until ``duration_s`` has passed; then
``StreamFrames Stop``. Datagrams from any other host are dropped (and counted), as the
client does.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable
from datetime import UTC, datetime

from mocap.qtm_protocol import (
    GREETING,
    CommandPacket,
    ComponentType,
    ErrorPacket,
    Packet,
    QtmStreamDecoder,
    XmlPacket,
    encode_command,
    format_version,
    parse_6d_parameters,
    stream_frames_command,
)
from mocap.recording import RecordedPacket, Recording


class RecordingError(Exception):
    """The server could not be recorded from (refused, no common version, no 6D)."""


class _Datagrams(asyncio.DatagramProtocol):
    def __init__(self, server_host: str, clock: Callable[[], float], started_s: float) -> None:
        self.server_host = server_host
        self.clock = clock
        self.started_s = started_s
        self.packets: list[RecordedPacket] = []
        self.foreign = 0

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        if addr[0] != self.server_host:
            self.foreign += 1
            return
        self.packets.append(RecordedPacket(self.clock() - self.started_s, data))


class _Commands:
    def __init__(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.reader, self.writer = reader, writer
        self.decoder = QtmStreamDecoder()

    async def read(self) -> Packet:
        while (packet := self.decoder.next_packet()) is None:
            data = await self.reader.read(65536)
            if not data:
                raise RecordingError("QTM closed the connection")
            self.decoder.receive_data(data)
        return packet

    async def request(self, command: str, timeout_s: float = 5.0) -> Packet:
        self.writer.write(encode_command(command))
        async with asyncio.timeout(timeout_s):
            while not isinstance(
                packet := await self.read(), CommandPacket | ErrorPacket | XmlPacket
            ):
                pass  # events interleave with replies (§1.3)
        return packet


async def _negotiate(commands: _Commands) -> str:
    for minor in range(25, 7, -1):
        version = format_version((1, minor))
        reply = await commands.request(f"Version {version}")
        if isinstance(reply, CommandPacket) and reply.text.lower().startswith("version set"):
            return version
    raise RecordingError("no common protocol version ≥ 1.8")


async def record_stream(
    host: str,
    port: int,
    duration_s: float,
    component: ComponentType = ComponentType.SIX_D,
    clock: Callable[[], float] = time.monotonic,
) -> Recording:
    """Record ``duration_s`` seconds of ``host:port``'s stream."""
    reader, writer = await asyncio.wait_for(asyncio.open_connection(host, port), 5.0)
    transport: asyncio.DatagramTransport | None = None
    try:
        commands = _Commands(reader, writer)
        greeting = await asyncio.wait_for(commands.read(), 5.0)
        if not (isinstance(greeting, CommandPacket) and greeting.text.startswith(GREETING)):
            raise RecordingError(f"{host}:{port} greeted with {greeting!r}")
        version = await _negotiate(commands)
        parameters = await commands.request("GetParameters 6D")
        if not isinstance(parameters, XmlPacket):
            raise RecordingError(f"GetParameters 6D answered with {parameters!r}")
        names = parse_6d_parameters(parameters.text).names
        local_host: str = writer.get_extra_info("sockname")[0]
        server_host: str = writer.get_extra_info("peername")[0]
        started = datetime.now(UTC).isoformat()
        clock_start_s = clock()
        datagrams = _Datagrams(server_host, clock, clock_start_s)
        transport, _ = await asyncio.get_running_loop().create_datagram_endpoint(
            lambda: datagrams, local_addr=(local_host, 0)
        )
        udp_port: int = transport.get_extra_info("sockname")[1]
        writer.write(encode_command(stream_frames_command([component], udp_port=udp_port)))
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(duration_s):
                while True:  # QTM answers StreamFrames only when it fails (§1.3)
                    if isinstance(packet := await commands.read(), ErrorPacket):
                        raise RecordingError(f"StreamFrames refused: {packet.text}")
        writer.write(encode_command("StreamFrames Stop"))
        return Recording(
            source=f"{host}:{port}",
            protocol_version=version,
            component=component,
            body_names=tuple(names),
            parameters_xml=parameters.text,
            started=started,
            clock_start_s=clock_start_s,
            packets=tuple(datagrams.packets),
        )
    finally:
        if transport is not None:
            transport.close()
        writer.close()
        with contextlib.suppress(OSError, TimeoutError):
            await asyncio.wait_for(writer.wait_closed(), 0.5)
