"""Simulated Qualisys QTM real-time server (asyncio), speaking the RT protocol on loopback.

What it implements (docs/reference/qtm-rt.md §1; byte layouts from ``mocap.qtm_protocol``):

* TCP on the little-endian port (default 22223; port 0 picks a free one, see ``port``), the
  greeting ``"QTM RT Interface connected"`` (exactly: qtm-rt compares the whole string),
  ``"Connection refused. Max number of clients reached."`` past ``max_clients``;
* ``Version`` (bare: ``Version is n.n``; ``Version n.n`` within [``min_version``,
  ``max_version``], default 1.8–1.25: ``Version set to n.n``, else an Error packet
  ``Version NOT supported``), ``QTMVersion``, ``ByteOrder``, ``GetState`` (an Event packet),
  ``GetParameters 6D|General|All`` (XML with the body names), ``GetCurrentFrame <components>``,
  ``StreamFrames AllFrames|Frequency:n|FrequencyDivisor:n [UDP[:addr]:port] <components>``
  (over UDP, or over this TCP connection without ``UDP:``, as qtm-rt does; no reply on
  success), ``StreamFrames Stop``, ``TakeControl``, ``ReleaseControl``, ``Start``, ``Stop``;
  anything else gets the Error packet ``Parse Error``. Commands are case-insensitive.
* components 6D (rotation matrix), 6DRes, 6DEuler (Qualisys-standard Euler angles), 6DEulerRes;
  positions in mm; untracked bodies as all-NaN records; No-More-Data packets while
  ``measuring`` is False.

Poses come from a ``PoseSource`` called with the frame's capture time [s since start], or are
pushed with ``publish``; with ``rate_hz=None`` every ``publish`` sends one frame at once (the
fast simulator's mode), otherwise frames go out on absolute deadlines t0 + k/rate. Bodies a
source leaves out, or marks untracked, are sent as NaN. This module may import ``mocap`` but
never ``supervisor``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import TracebackType
from typing import Final, Self

from mocap.qtm_protocol import (
    GREETING,
    LITTLE_ENDIAN_PORT,
    MAX_CLIENTS_MESSAGE,
    BodyPose,
    CommandPacket,
    ComponentType,
    ErrorPacket,
    EventPacket,
    NoMoreDataPacket,
    Packet,
    ProtocolVersion,
    QtmEvent,
    QtmProtocolError,
    QtmStreamDecoder,
    XmlPacket,
    build_6d_parameters_xml,
    component_type_from_name,
    encode_packet,
    format_version,
    packet_from_poses,
    parse_stream_frames,
    parse_version,
)

PoseSource = Callable[[float], Mapping[str, BodyPose]]
"""Poses of the named bodies at a capture time [s since the server started]."""

_MAX_TCP_BACKLOG_B: Final = 1 << 20
"""Frames are dropped for a TCP client whose unsent data exceeds this: a slow reader must
not grow the server's memory without bound (QTM drops frames too)."""
_MAX_COMMAND_PACKET_B: Final = 1 << 20


@dataclass
class _Stream:
    components: tuple[ComponentType, ...]
    divisor: int
    udp_target: tuple[str, int] | None  # None: stream over the TCP connection


@dataclass(eq=False)  # identity semantics: connections live in a set
class _Connection:
    writer: asyncio.StreamWriter
    peer_host: str
    version: ProtocolVersion = (1, 1)  # QTM's default if the client never sends Version (§1.2)
    stream: _Stream | None = None
    dropped_frames: int = 0
    stream_requests: list[str] = field(default_factory=list)

    def send(self, packet: Packet) -> None:
        if not self.writer.is_closing():
            self.writer.write(encode_packet(packet))


class QtmServer:
    """A simulated QTM RT server for the bodies ``body_names`` (data order = this order).

    Use as ``async with QtmServer([...], source) as server:`` or ``start()``/``close()``.
    ``clock`` [s] gives capture timestamps; ``residual_mm`` fills the *Res components when a
    pose carries no residual of its own.
    """

    def __init__(
        self,
        body_names: Sequence[str],
        source: PoseSource | None = None,
        *,
        host: str = "127.0.0.1",
        port: int = LITTLE_ENDIAN_PORT,
        rate_hz: float | None = 100.0,
        clock: Callable[[], float] = time.monotonic,
        min_version: ProtocolVersion = (1, 8),
        max_version: ProtocolVersion = (1, 25),
        max_clients: int = 10,
        residual_mm: float = 0.5,
    ) -> None:
        if len(set(body_names)) != len(body_names):
            raise ValueError(f"duplicate body names in {body_names}")
        if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz must be > 0 or None, got {rate_hz}")
        self.body_names = tuple(body_names)
        self.source = source
        self.host = host
        self._requested_port = port
        self.rate_hz = rate_hz
        self._clock = clock
        self.min_version = min_version
        self.max_version = max_version
        self.max_clients = max_clients
        self.residual_mm = residual_mm
        self.measuring = True
        """While False, streams get No-More-Data packets instead of frames (§1.3)."""
        self.frame_number = 0
        """Number of the last frame produced (the first is 1)."""
        self.frames_sent = 0
        """Data packets sent, over TCP and UDP together."""
        self.commands: list[str] = []
        """Every command received, in order (for tests and logs)."""
        self.packet_filter: Callable[[bool], bool] | None = None
        """Asked for every data packet (frame or No-More-Data) about to go to a streaming
        client, with whether it travels over UDP; False drops it — the simulated world's
        fault injection (``sim.faults``). The frame number counts the frame either way."""
        self._published: Mapping[str, BodyPose] = {}
        self._published_at_s: float | None = None
        self._connections: set[_Connection] = set()
        self._handlers: set[asyncio.Task[None]] = set()
        self._server: asyncio.Server | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self._ticker: asyncio.Task[None] | None = None
        self._t0_clock = 0.0

    # --- Lifecycle -------------------------------------------------------------------------

    async def start(self) -> None:
        """Bind TCP (``port``) and the UDP sending socket, start the frame clock."""
        loop = asyncio.get_running_loop()
        self._server = await asyncio.start_server(self._handle, self.host, self._requested_port)
        self._udp, _ = await loop.create_datagram_endpoint(
            asyncio.DatagramProtocol, local_addr=(self.host, 0)
        )
        self._t0_clock = self._clock()
        if self.rate_hz is not None:
            self._ticker = asyncio.create_task(self._tick_forever(self.rate_hz), name="qtm-sim")

    async def close(self) -> None:
        """Stop streaming, drop every client, release the ports."""
        if self._ticker is not None:
            self._ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._ticker
            self._ticker = None
        for connection in list(self._connections):
            connection.writer.close()
        if self._handlers:
            # Each handler ends on its closed connection; one left running would be
            # cancelled at the loop's end and logged as an error (Python 3.11's streams).
            await asyncio.wait(self._handlers, timeout=1.0)
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
        if self._udp is not None:
            self._udp.close()
            self._udp = None

    async def __aenter__(self) -> Self:
        await self.start()
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        await self.close()

    @property
    def port(self) -> int:
        """The bound TCP port (the real one when constructed with port 0)."""
        if self._server is None:
            raise RuntimeError("server not started")
        port: int = self._server.sockets[0].getsockname()[1]
        return port

    @property
    def udp_port(self) -> int:
        """The local port UDP frames are sent from."""
        if self._udp is None:
            raise RuntimeError("server not started")
        port: int = self._udp.get_extra_info("sockname")[1]
        return port

    @property
    def clients(self) -> int:
        """TCP clients connected now."""
        return len(self._connections)

    # --- Frames ----------------------------------------------------------------------------

    def publish(self, bodies: Mapping[str, BodyPose], at_s: float | None = None) -> None:
        """Push the current poses. With ``rate_hz=None`` this sends a frame now; otherwise
        the next tick sends them (unless a ``source`` is set, which takes precedence).
        ``at_s``: when they were measured, on ``clock`` (default: now); a caller that
        publishes several frames at once, catching up, stamps each with its own time, as a
        camera system does."""
        self._published = dict(bodies)
        self._published_at_s = at_s
        if self.rate_hz is None:
            self._emit_frame()

    async def _tick_forever(self, rate_hz: float) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / rate_hz
        start = loop.time()
        k = 0
        while True:
            k += 1
            # Absolute deadlines: late ticks do not accumulate drift; a stall skips frames
            # (as a real camera system would) instead of bursting to catch up.
            deadline = start + k * period
            delay = deadline - loop.time()
            if delay < -period:
                k += int(-delay / period)
                continue
            await asyncio.sleep(max(delay, 0.0))
            self._emit_frame()

    def _capture(self) -> tuple[int, Mapping[str, BodyPose]]:
        measured_at_s = self._published_at_s
        if self.source is not None or measured_at_s is None:
            measured_at_s = self._clock()
        timestamp_us = round((measured_at_s - self._t0_clock) * 1e6)
        # The source sees exactly the time the packet carries, so a client can recompute it.
        poses = self.source(timestamp_us * 1e-6) if self.source else self._published
        return timestamp_us, poses

    def _emit_frame(self) -> None:
        self.frame_number = (self.frame_number + 1) & 0xFFFFFFFF
        streaming = [c for c in self._connections if c.stream is not None]
        if not streaming:
            return
        if not self.measuring:
            encoded_nmd = encode_packet(NoMoreDataPacket())
            for connection in streaming:
                if self._passes(connection):
                    self._send(connection, encoded_nmd)
            return
        timestamp_us, poses = self._capture()
        cache: dict[tuple[ComponentType, ...], bytes] = {}
        for connection in streaming:
            stream = connection.stream
            assert stream is not None
            if self.frame_number % stream.divisor or not self._passes(connection):
                continue
            data = cache.get(stream.components)
            if data is None:
                packet = packet_from_poses(
                    self.frame_number,
                    timestamp_us,
                    self.body_names,
                    poses,
                    stream.components,
                    self.residual_mm,
                )
                data = cache[stream.components] = encode_packet(packet)
            self._send(connection, data)
            self.frames_sent += 1

    def _passes(self, connection: _Connection) -> bool:
        stream = connection.stream
        udp = stream is not None and stream.udp_target is not None
        return self.packet_filter is None or self.packet_filter(udp)

    def _send(self, connection: _Connection, data: bytes) -> None:
        stream = connection.stream
        if stream is not None and stream.udp_target is not None:
            if self._udp is not None:
                self._udp.sendto(data, stream.udp_target)
            return
        writer = connection.writer
        if writer.is_closing() or writer.transport.get_write_buffer_size() > _MAX_TCP_BACKLOG_B:
            connection.dropped_frames += 1
            return
        writer.write(data)

    # --- Commands --------------------------------------------------------------------------

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = writer.get_extra_info("peername")
        connection = _Connection(writer, str(peer[0]) if peer else self.host)
        handler = asyncio.current_task()
        assert handler is not None
        self._handlers.add(handler)
        try:
            if len(self._connections) >= self.max_clients:
                connection.send(CommandPacket(MAX_CLIENTS_MESSAGE))
                return
            self._connections.add(connection)
            connection.send(CommandPacket(GREETING))
            decoder = QtmStreamDecoder(_MAX_COMMAND_PACKET_B)
            while data := await reader.read(65536):
                for packet in decoder.feed(data):
                    self._handle_packet(connection, packet)
        except QtmProtocolError:
            # The client's stream cannot be framed any more: say so and hang up.
            connection.send(ErrorPacket("Parse Error"))
        except ConnectionError:
            pass
        finally:
            self._handlers.discard(handler)
            self._connections.discard(connection)
            writer.close()
            with contextlib.suppress(OSError):
                await writer.wait_closed()

    def _handle_packet(self, connection: _Connection, packet: Packet) -> None:
        if isinstance(packet, CommandPacket):
            self.commands.append(packet.text)
            reply = self._command_reply(connection, packet.text)
            if reply is not None:
                connection.send(reply)
        elif isinstance(packet, XmlPacket):
            connection.send(ErrorPacket("Setting parameters failed"))
        else:
            connection.send(ErrorPacket("Parse Error"))

    def _command_reply(self, connection: _Connection, text: str) -> Packet | None:
        words = text.split()
        command = words[0].lower() if words else ""
        arguments = words[1:]
        match command:
            case "version":
                return self._version_reply(connection, arguments)
            case "qtmversion":
                return CommandPacket("QTM Version is uavbar-sim (RT protocol 1.25)")
            case "byteorder":
                return CommandPacket("Byte order is little endian")
            case "getstate":
                state = QtmEvent.CONNECTED if self.measuring else QtmEvent.CONNECTION_CLOSED
                return EventPacket(state)
            case "getparameters":
                return self._parameters_reply(connection, arguments)
            case "getcurrentframe":
                return self._current_frame(arguments)
            case "streamframes":
                return self._stream_frames(connection, " ".join(arguments))
            case "takecontrol":
                return CommandPacket("You are now master")
            case "releasecontrol":
                return CommandPacket("You are now a regular client")
            case "start":
                self.measuring = True
                return CommandPacket("Starting measurement")
            case "stop":
                self.measuring = False
                return CommandPacket("Stopping measurement")
        return ErrorPacket("Parse Error")

    def _version_reply(self, connection: _Connection, arguments: list[str]) -> Packet:
        if not arguments:
            return CommandPacket(f"Version is {format_version(connection.version)}")
        try:
            version = parse_version(arguments[0])
        except QtmProtocolError:
            return ErrorPacket("Parse Error")
        if not self.min_version <= version <= self.max_version:
            return ErrorPacket("Version NOT supported")
        connection.version = version
        return CommandPacket(f"Version set to {format_version(version)}")

    def _parameters_reply(self, connection: _Connection, arguments: list[str]) -> Packet:
        wanted = {a.lower() for a in arguments} or {"all"}
        known = {"all", "general", "3d", "6d", "analog", "force", "image", "skeleton"}
        if not wanted <= known:
            return ErrorPacket("Parse Error")
        root = ET.fromstring(build_6d_parameters_xml(self.body_names, connection.version))
        if not wanted & {"all", "6d"}:
            root.remove(root[0])
        if wanted & {"all", "general"}:
            general = ET.Element("General")
            frequency = self.rate_hz if self.rate_hz is not None else 100.0
            ET.SubElement(general, "Frequency").text = str(round(frequency))
            root.insert(0, general)
        return XmlPacket(ET.tostring(root, encoding="unicode"))

    def _components(self, names: Sequence[str]) -> tuple[ComponentType, ...]:
        return tuple(component_type_from_name(name) for name in names)

    def _current_frame(self, arguments: list[str]) -> Packet:
        try:
            components = self._components(arguments)
        except QtmProtocolError:
            return ErrorPacket("Parse Error")
        if not components:
            return ErrorPacket("Parse Error")
        if not self.measuring:
            return NoMoreDataPacket()
        timestamp_us, poses = self._capture()
        return packet_from_poses(
            self.frame_number,
            timestamp_us,
            self.body_names,
            poses,
            components,
            self.residual_mm,
        )

    def _stream_frames(self, connection: _Connection, arguments: str) -> Packet | None:
        try:
            request = parse_stream_frames(arguments)
            components = () if request.stop else self._components(request.components)
        except QtmProtocolError:
            return ErrorPacket("Parse Error")
        connection.stream_requests.append(arguments)
        if request.stop:
            connection.stream = None
            return None
        divisor = 1
        if request.rate == "frequencydivisor" and request.rate_value:
            divisor = request.rate_value
        elif request.rate == "frequency" and request.rate_value and self.rate_hz:
            divisor = max(1, round(self.rate_hz / request.rate_value))
        target = None
        if request.udp_port is not None:
            target = (request.udp_address or connection.peer_host, request.udp_port)
        connection.stream = _Stream(components, divisor, target)
        return None  # QTM sends nothing on success (§1.3)
