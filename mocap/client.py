"""Asyncio QTM RT client: commands over TCP, 6D frames over UDP or over the same TCP
connection (docs/reference/qtm-rt.md §1).

Two layers, as in aioquic:

* ``FrameReceiver`` — sans-IO. Takes UDP datagrams (with their source port) or packets read
  from the TCP stream, and the receive time, decodes them (``mocap.qtm_protocol``), counts
  frame-number gaps, out-of-order and duplicate datagrams, malformed packets and stream
  restarts, refuses datagrams from any port but the server's stream port and frame numbers
  further ahead than the elapsed time allows, converts accepted frames to SI units through
  ``geometry.frames`` (``frame_from_packet``) and keeps them in a bounded store.
* ``QtmClient`` — the thin asyncio shell, an async context manager. Per session it connects
  to the little-endian port, reads the greeting, negotiates the protocol version (asks 1.25,
  falls back one minor version at a time down to 1.8, below which 6D is sent as doubles,
  §1.2), reads the body names with ``GetParameters 6D``, binds a UDP socket on the address
  the TCP connection uses, and sends ``StreamFrames AllFrames UDP:<port> 6D`` (or
  ``6DEuler``/…; QTM answers nothing on success, §1.3); with ``transport="tcp"`` it sends
  ``StreamFrames AllFrames 6D`` and reads the frames from the command connection, which a
  sender off the path between QTM and us cannot inject into. A lost connection, a server
  error or a silent server (keep-alive unanswered) ends the session; the client reconnects with
  exponential back-off until the context exits.

``MocapSource`` is the small protocol the supervisor depends on; the sim or a test can supply
any other implementation.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import socket
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Final, Literal, Protocol, Self

from mocap.qtm_protocol import (
    GREETING,
    LITTLE_ENDIAN_PORT,
    BodyPose,
    CommandPacket,
    ComponentType,
    DataPacket,
    ErrorPacket,
    EventPacket,
    MocapFrame,
    NoMoreDataPacket,
    Packet,
    ProtocolVersion,
    QtmProtocolError,
    QtmStreamDecoder,
    XmlPacket,
    component_type_from_name,
    decode_datagram,
    encode_command,
    format_version,
    frame_from_packet,
    parse_6d_parameters,
    stream_frames_command,
)
from mocap.stream_recorder import StreamRecorder, StreamSession

__all__ = [
    "BodyPose",
    "FrameReceiver",
    "MocapFrame",
    "MocapSource",
    "MocapStats",
    "QtmClient",
    "QtmServerError",
]

log = logging.getLogger(__name__)
# While no QTM answers, one warning in this many failed connections (every few seconds).
CONNECT_FAILURES_PER_WARNING = 3

_FRAME_NUMBER_MODULUS: Final = 2**32
MIN_PROTOCOL_VERSION: Final[ProtocolVersion] = (1, 8)
"""Below 1.8, 6D records are doubles (§1.2); this client never goes there."""


class QtmServerError(Exception):
    """The server answered but refused: connection refused, no common protocol version, an
    Error packet in reply to a command, or parameters the client cannot use."""


@dataclass(frozen=True)
class MocapStats:
    """Counters of a mocap source since it was created (snapshots; never reset).

    Datagram counters: ``datagrams`` of the server's UDP stream (from its host, and from
    its port once known), ``frames`` accepted (over UDP or TCP),
    ``gaps`` (forward jumps in the frame number) and ``frames_missed`` (frame numbers skipped
    in total), ``out_of_order`` (older than the newest accepted), ``duplicates`` (same frame
    number again), ``malformed`` (not a valid RT packet, or a corrupt record),
    ``no_more_data`` (QTM not measuring), ``ignored`` (valid but not a usable data packet),
    ``body_count_mismatches`` (the data has a different number of bodies than the 6D
    parameters), ``stream_restarts`` (frame numbers restarted: a new measurement),
    ``foreign_datagrams`` (from another host, dropped), ``foreign_port_datagrams`` (from the
    server's host but not the port its stream comes from, dropped), ``frame_number_jumps``
    (numbered further ahead than the time since the last frame allows, refused),
    ``queue_overflows`` (frames pushed out of the bounded store before ``drain``).
    Connection: ``sessions`` (successful stream starts), ``connect_failures``,
    ``connected``, ``protocol_version``, ``body_names``, ``transport`` ("udp" or "tcp"),
    ``server`` (the QTM server's "host:port" tried), ``udp_port`` (local),
    ``server_udp_port`` (the port the server's stream comes from: configured, or learned
    from the session's first frame). ``last_receive_time_s`` is on
    the client's clock.
    """

    connected: bool = False
    server: str = ""
    sessions: int = 0
    connect_failures: int = 0
    protocol_version: str | None = None
    body_names: tuple[str, ...] = ()
    transport: str = "udp"
    udp_port: int | None = None
    server_udp_port: int | None = None
    datagrams: int = 0
    frames: int = 0
    gaps: int = 0
    frames_missed: int = 0
    out_of_order: int = 0
    duplicates: int = 0
    malformed: int = 0
    no_more_data: int = 0
    ignored: int = 0
    body_count_mismatches: int = 0
    stream_restarts: int = 0
    foreign_datagrams: int = 0
    foreign_port_datagrams: int = 0
    frame_number_jumps: int = 0
    queue_overflows: int = 0
    last_frame_number: int | None = None
    last_receive_time_s: float | None = None
    last_error: str | None = None

    @property
    def reconnects(self) -> int:
        """Sessions after the first."""
        return max(self.sessions - 1, 0)

    def refused(self) -> dict[str, int]:
        """What was dropped as not the server's stream, by reason (the ones seen)."""
        counts = {
            "foreign_host": self.foreign_datagrams,
            "foreign_port": self.foreign_port_datagrams,
            "frame_number_jump": self.frame_number_jumps,
        }
        return {reason: n for reason, n in counts.items() if n}


class MocapSource(Protocol):
    """What the supervisor needs from motion capture (a QTM client, or a fake in tests)."""

    def latest(self) -> MocapFrame | None:
        """The newest frame, or None before the first."""
        ...

    def drain(self) -> list[MocapFrame]:
        """Every frame received since the last call, oldest first (bounded)."""
        ...

    def stats(self) -> MocapStats:
        """Counters and connection state."""
        ...

    def on_frame(self, listener: Callable[[], None] | None) -> None:
        """Call ``listener`` (on the event loop) whenever a frame is accepted; None: stop."""
        ...

    def record(self, path: Path | None) -> dict[str, Any] | None:
        """Record the stream as received into ``path`` (a QTM recording); None: stop. The
        receiving sequence where the recording starts (``FrameReceiver.sequence``), or None
        when it starts with the next session."""
        ...

    def recording_failure(self) -> OSError | None:
        """The write error that ended the recording by itself (a full disk), else None."""
        ...


class FrameReceiver:
    """Sans-IO receiving side of the client: datagram bytes (or TCP packets) and receive
    time in, frames out.

    ``restart_after_backwards`` consecutive datagrams behind the newest frame, or one more
    than ``restart_threshold_frames`` behind, mean QTM restarted its frame numbering (a new
    measurement) rather than reordering: the sequence restarts from that frame.

    A frame numbered further ahead of the newest than ``max_frame_rate_hz`` × the receive
    time elapsed since it, plus ``frame_number_slack``, cannot come from the stream (a
    sender raising the numbers to make the real frames look old): it is refused and counted
    (``frame_number_jumps``), and the real stream goes on. As many such frames in a row as
    ``restart_after_backwards``, with no frame of the old numbering between them, are a
    restart (QTM renumbered while the stream was stalled) and the sequence restarts there.

    ``server_port``: the UDP port the server's stream comes from; None learns it from the
    first frame accepted in a session (``reset`` forgets a learned one). Datagrams given
    with another ``source_port`` are dropped and counted (``foreign_port_datagrams``).
    """

    def __init__(
        self,
        body_names: Sequence[str] = (),
        component: ComponentType = ComponentType.SIX_D,
        max_queue: int = 256,
        restart_threshold_frames: int = 1000,
        restart_after_backwards: int = 20,
        *,
        server_port: int | None = None,
        max_frame_rate_hz: float = 1000.0,
        frame_number_slack: int = 10,
    ) -> None:
        self.body_names: tuple[str, ...] = tuple(body_names)
        self.component = component
        self.restart_threshold_frames = restart_threshold_frames
        self.restart_after_backwards = restart_after_backwards
        self.configured_server_port = server_port
        self.server_port = server_port
        self.max_frame_rate_hz = max_frame_rate_hz
        self.frame_number_slack = frame_number_slack
        self._queue: deque[MocapFrame] = deque(maxlen=max_queue)
        self._latest: MocapFrame | None = None
        self._last_frame_number: int | None = None
        self._last_frame_time_s = -math.inf
        self._backwards_in_a_row = 0
        self._jumps_in_a_row = 0
        self.consecutive_mismatches = 0
        self.last_receive_time_s: float | None = None
        self.tap: Callable[[bytes, float], None] | None = None
        """Given every datagram of the stream (from its port) as received, before it is
        decoded: a ``StreamRecorder``'s ``packet``."""
        self.counts: dict[str, int] = dict.fromkeys(
            (
                "datagrams",
                "frames",
                "gaps",
                "frames_missed",
                "out_of_order",
                "duplicates",
                "malformed",
                "no_more_data",
                "ignored",
                "body_count_mismatches",
                "stream_restarts",
                "foreign_datagrams",
                "foreign_port_datagrams",
                "frame_number_jumps",
                "queue_overflows",
            ),
            0,
        )

    def reset(self, body_names: Sequence[str], component: ComponentType) -> None:
        """Start a new stream (after a reconnect): new names, sequence and learned server
        port forgotten, counters kept."""
        self.body_names = tuple(body_names)
        self.component = component
        self.server_port = self.configured_server_port
        self._last_frame_number = None
        self._last_frame_time_s = -math.inf
        self._backwards_in_a_row = 0
        self._jumps_in_a_row = 0
        self.consecutive_mismatches = 0

    def latest(self) -> MocapFrame | None:
        """The newest accepted frame (kept across reconnects)."""
        return self._latest

    def drain(self) -> list[MocapFrame]:
        """Accepted frames since the last drain, oldest first."""
        frames = list(self._queue)
        self._queue.clear()
        return frames

    @property
    def last_frame_number(self) -> int | None:
        """Frame number of the newest accepted frame of the current stream."""
        return self._last_frame_number

    def sequence(self) -> dict[str, Any]:
        """Where the stream's sequence stands, as JSON values: a receiver resumed from it
        takes or refuses the next datagrams as this one would."""
        return {
            "last_frame_number": self._last_frame_number,
            "last_frame_time_s": self._last_frame_time_s,
            "in_a_row": [self._backwards_in_a_row, self._jumps_in_a_row],
            "consecutive_mismatches": self.consecutive_mismatches,
        }

    def resume(self, sequence: dict[str, Any]) -> None:
        """Continue the sequence ``sequence`` describes."""
        number = sequence["last_frame_number"]
        self._last_frame_number = None if number is None else int(number)
        self._last_frame_time_s = float(sequence["last_frame_time_s"])
        self._backwards_in_a_row, self._jumps_in_a_row = (int(n) for n in sequence["in_a_row"])
        self.consecutive_mismatches = int(sequence["consecutive_mismatches"])

    def count_foreign(self) -> None:
        """A datagram from a host other than the server's arrived (and was dropped)."""
        self.counts["foreign_datagrams"] += 1

    def _classify(self, frame_number: int, now_s: float) -> str:
        """'first', 'next', 'gap', 'jump', 'duplicate', 'old' or 'restart' (no state
        change)."""
        last = self._last_frame_number
        if last is None:
            return "first"
        ahead = (frame_number - last) % _FRAME_NUMBER_MODULUS  # uint32 wraps (§1.4)
        if ahead == 0:
            return "duplicate"
        if ahead < _FRAME_NUMBER_MODULUS // 2:
            if ahead == 1:
                return "next"
            elapsed_s = max(now_s - self._last_frame_time_s, 0.0)
            reachable = self.frame_number_slack + self.max_frame_rate_hz * elapsed_s
            if ahead <= reachable:
                return "gap"
            if self._jumps_in_a_row + 1 >= self.restart_after_backwards:
                return "restart"
            return "jump"
        behind = _FRAME_NUMBER_MODULUS - ahead
        if (
            behind > self.restart_threshold_frames
            or self._backwards_in_a_row + 1 >= self.restart_after_backwards
        ):
            return "restart"
        return "old"

    def receive_datagram(
        self, data: bytes, now_s: float, source_port: int | None = None
    ) -> MocapFrame | None:
        """Process one datagram received at ``now_s`` [s] from the server's host (from
        ``source_port``, when the transport knows it); the frame if it was accepted."""
        counts = self.counts
        if (
            source_port is not None
            and self.server_port is not None
            and source_port != self.server_port
        ):
            counts["foreign_port_datagrams"] += 1
            return None
        counts["datagrams"] += 1
        self.last_receive_time_s = now_s
        if self.tap is not None:
            self.tap(data, now_s)
        try:
            packet: Packet = decode_datagram(data)
        except QtmProtocolError:
            counts["malformed"] += 1
            return None
        frame = self.receive_packet(packet, now_s)
        if frame is not None and self.server_port is None:
            self.server_port = source_port  # the stream's port, from its first frame
        return frame

    def receive_packet(self, packet: Packet, now_s: float) -> MocapFrame | None:
        """Process one decoded packet received at ``now_s`` [s] (a datagram's, or one read
        from the TCP stream); the frame if it was accepted."""
        counts = self.counts
        self.last_receive_time_s = now_s
        if isinstance(packet, NoMoreDataPacket):
            counts["no_more_data"] += 1
            return None
        if not isinstance(packet, DataPacket):
            counts["ignored"] += 1
            return None
        component = packet.six_d(self.component)
        if component is None:
            # e.g. the part of a frame QTM split over several datagrams that has no 6D (§1.3).
            counts["ignored"] += 1
            return None
        if len(component.bodies) != len(self.body_names):
            counts["body_count_mismatches"] += 1
            self.consecutive_mismatches += 1
            return None
        self.consecutive_mismatches = 0
        verdict = self._classify(packet.frame_number, now_s)
        if verdict == "duplicate":
            counts["duplicates"] += 1
            return None
        if verdict == "old":
            counts["out_of_order"] += 1
            self._backwards_in_a_row += 1
            return None
        if verdict == "jump":
            counts["frame_number_jumps"] += 1
            self._jumps_in_a_row += 1
            return None
        try:
            frame = frame_from_packet(packet, self.body_names, now_s, self.component)
        except QtmProtocolError:
            counts["malformed"] += 1
            return None
        if verdict == "gap":
            assert self._last_frame_number is not None
            counts["gaps"] += 1
            counts["frames_missed"] += (
                packet.frame_number - self._last_frame_number
            ) % _FRAME_NUMBER_MODULUS - 1
        elif verdict == "restart":
            counts["stream_restarts"] += 1
        self._backwards_in_a_row = 0
        self._jumps_in_a_row = 0
        self._last_frame_number = packet.frame_number
        self._last_frame_time_s = now_s
        counts["frames"] += 1
        if len(self._queue) == self._queue.maxlen:
            counts["queue_overflows"] += 1
        self._queue.append(frame)
        self._latest = frame
        return frame


class _DatagramProtocol(asyncio.DatagramProtocol):
    def __init__(self, client: QtmClient, server_host: str) -> None:
        self._client = client
        self._server_host = server_host

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        self._client._on_datagram(data, addr, self._server_host)

    def error_received(self, exc: Exception) -> None:
        # ICMP errors (port unreachable after a server restart, …) are not fatal for UDP:
        # the TCP connection decides whether the session is alive.
        self._client._last_error = f"UDP: {exc}"


async def cancel_for_good(task: asyncio.Task[None]) -> None:
    """Cancel ``task`` and wait until it has ended. Before Python 3.12 ``asyncio.wait_for``
    loses a cancellation that arrives as its inner wait completes (CPython gh-86296), and the
    sessions wait that way many times a second: a single ``cancel`` then left ``__aexit__``
    waiting for ever (seen under load in the test suite)."""
    while not task.done():
        task.cancel()
        await asyncio.wait({task}, timeout=0.1)
    with contextlib.suppress(asyncio.CancelledError):
        task.result()


class QtmClient:
    """QTM RT client over TCP (commands) and UDP (frames); an async context manager.

    ``async with QtmClient("127.0.0.1", port) as client:`` starts a background task that
    connects, streams and reconnects until the block exits. ``component`` is ``"6D"``
    (default, the rotation matrix: immune to QTM's Euler settings, §1.4), ``"6DRes"``,
    ``"6DEuler"`` or ``"6DEulerRes"`` (Euler assumes QTM's default "Qualisys standard").
    ``transport`` is ``"udp"`` (frames to a local UDP port, ``udp_port``; 0 lets the OS
    pick) or ``"tcp"`` (frames over the command connection). Over UDP only datagrams from
    the server's host and from the port its stream comes from are taken:
    ``server_udp_port``, or learned from the session's first frame. ``clock`` [s] stamps
    each frame's receive time.
    Back-off between attempts doubles from ``reconnect_min_s`` to ``reconnect_max_s`` and
    resets after a session that streamed. With no datagram for ``keepalive_s``, a
    ``Version`` command probes the TCP connection; no answer in ``command_timeout_s`` ends
    the session.
    """

    def __init__(
        self,
        host: str,
        port: int = LITTLE_ENDIAN_PORT,
        *,
        component: str | ComponentType = ComponentType.SIX_D,
        transport: Literal["udp", "tcp"] = "udp",
        udp_port: int = 0,
        server_udp_port: int | None = None,
        version: ProtocolVersion = (1, 25),
        clock: Callable[[], float] = time.monotonic,
        connect_timeout_s: float = 2.0,
        command_timeout_s: float = 2.0,
        reconnect_min_s: float = 0.05,
        reconnect_max_s: float = 2.0,
        keepalive_s: float = 1.0,
        max_queue: int = 256,
    ) -> None:
        if version < MIN_PROTOCOL_VERSION:
            raise ValueError(f"protocol {format_version(version)} < 1.8 sends 6D as doubles")
        if transport not in ("udp", "tcp"):
            raise ValueError(f'transport must be "udp" or "tcp", got {transport!r}')
        self.host = host
        self.transport = transport
        self.port = port
        self.component = (
            component
            if isinstance(component, ComponentType)
            else component_type_from_name(component)
        )
        self._udp_port_request = udp_port
        self._version_request = version
        self._clock = clock
        self.connect_timeout_s = connect_timeout_s
        self.command_timeout_s = command_timeout_s
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.keepalive_s = keepalive_s
        self.receiver = FrameReceiver(
            component=self.component, max_queue=max_queue, server_port=server_udp_port
        )
        self._task: asyncio.Task[None] | None = None
        self._connected = asyncio.Event()
        self._frame_arrived = asyncio.Event()
        self._frame_listener: Callable[[], None] | None = None
        self._sessions = 0
        self._connect_failures = 0
        self._protocol_version: ProtocolVersion | None = None
        self._udp_port: int | None = None
        self._last_error: str | None = None
        self._last_datagram_s = -math.inf  # loop time, for the keep-alive only
        self._streamed = False
        self._stream_session: StreamSession | None = None
        self._recording_path: Path | None = None
        self._recorder: StreamRecorder | None = None
        self.last_event: int | None = None
        """The last Event packet's id seen on the command channel."""

    # --- MocapSource -----------------------------------------------------------------------

    def latest(self) -> MocapFrame | None:
        """The newest frame, or None before the first."""
        return self.receiver.latest()

    def drain(self) -> list[MocapFrame]:
        """Frames received since the last call, oldest first (at most ``max_queue``)."""
        return self.receiver.drain()

    def stats(self) -> MocapStats:
        """A snapshot of the counters and the connection state."""
        return MocapStats(
            connected=self._connected.is_set(),
            server=f"{self.host}:{self.port}",
            sessions=self._sessions,
            connect_failures=self._connect_failures,
            protocol_version=(
                format_version(self._protocol_version) if self._protocol_version else None
            ),
            body_names=self.receiver.body_names,
            transport=self.transport,
            udp_port=self._udp_port,
            server_udp_port=self.receiver.server_port,
            last_frame_number=self.receiver.last_frame_number,
            last_receive_time_s=self.receiver.last_receive_time_s,
            last_error=self._last_error,
            **self.receiver.counts,
        )

    def on_frame(self, listener: Callable[[], None] | None) -> None:
        """Call ``listener`` whenever a frame is accepted, right from the datagram callback
        (keep it short); None removes it."""
        self._frame_listener = listener

    def record(self, path: Path | None) -> dict[str, Any] | None:
        """Record the stream as received into ``path`` (a QTM recording, which ``mocap
        replay`` serves), from now, or from the next session while none streams; None
        stops and closes the file. Over TCP the frames are no datagrams: nothing is
        recorded. Returns the receiving sequence where the recording starts
        (``FrameReceiver.sequence``), or None when it does not start now."""
        if self._recorder is not None:
            self.receiver.tap = None
            self._recorder.close()
            self._recorder = None
        self._recording_path = path
        self._start_recording()
        return self.receiver.sequence() if self._recorder is not None else None

    def recording_failure(self) -> OSError | None:
        """The write error that ended the recording by itself (a full disk), else None."""
        return self._recorder.failure if self._recorder is not None else None

    def _start_recording(self) -> None:
        path, session = self._recording_path, self._stream_session
        if path is None or session is None or self._recorder is not None:
            return
        if self.transport == "tcp":
            log.warning("mocap over TCP: %s not recorded (only UDP datagrams are)", path)
            self._recording_path = None
            return
        self._recorder = StreamRecorder(path, session, self._clock())
        self.receiver.tap = self._recorder.packet

    def _new_session(self, session: StreamSession) -> None:
        """A session set up: its recording starts, or goes on while the stream is the same."""
        recorder = self._recorder
        if recorder is not None and (
            recorder.session.body_names,
            recorder.session.component,
        ) != (session.body_names, session.component):
            log.warning("the mocap's bodies changed: %s ends here", recorder.path)
            self.record(None)
        self._stream_session = session
        self._start_recording()

    # --- Lifecycle -------------------------------------------------------------------------

    async def __aenter__(self) -> Self:
        self._task = asyncio.create_task(self._run(), name=f"qtm-client {self.host}:{self.port}")
        return self

    async def __aexit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        task, self._task = self._task, None
        if task is not None:
            await cancel_for_good(task)
        self.record(None)

    @property
    def connected(self) -> bool:
        """True while a stream is set up (TCP alive, StreamFrames sent)."""
        return self._connected.is_set()

    @property
    def udp_port(self) -> int | None:
        """The local UDP port frames arrive on (None when not connected)."""
        return self._udp_port

    async def wait_connected(self) -> None:
        """Return once a stream is set up (wrap in ``asyncio.timeout``)."""
        await self._connected.wait()

    async def wait_frame(self) -> MocapFrame:
        """Return the next accepted frame (wrap in ``asyncio.timeout``)."""
        self._frame_arrived.clear()
        await self._frame_arrived.wait()
        frame = self.receiver.latest()
        assert frame is not None
        return frame

    # --- Sessions --------------------------------------------------------------------------

    async def _run(self) -> None:
        delay = self.reconnect_min_s
        while True:
            self._streamed = False
            try:
                await self._session()
            except (OSError, TimeoutError, QtmProtocolError, QtmServerError) as error:
                self._last_error = f"{type(error).__name__}: {error}"
            if self._streamed:
                delay = self.reconnect_min_s
            else:
                self._connect_failures += 1
                if self._connect_failures % CONNECT_FAILURES_PER_WARNING == 1:
                    log.warning(
                        "no QTM RT server at %s:%d (%s): trying again every %g s",
                        self.host,
                        self.port,
                        self._last_error,
                        self.reconnect_max_s,
                    )
            await asyncio.sleep(delay)
            delay = min(2.0 * delay, self.reconnect_max_s)

    async def _session(self) -> None:
        """One connection, from connect to loss: always ends with an exception. Sets
        ``_streamed`` once the stream is set up (the back-off then starts afresh)."""
        reader, writer = await asyncio.wait_for(
            asyncio.open_connection(self.host, self.port), self.connect_timeout_s
        )
        transport: asyncio.DatagramTransport | None = None
        try:
            sock = writer.get_extra_info("socket")
            if sock is not None:
                # Commands are tiny and latency matters more than packet count (§1.2).
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            channel = _CommandChannel(reader, writer, self.command_timeout_s, self)
            greeting = await channel.read()
            if not (isinstance(greeting, CommandPacket) and greeting.text.startswith(GREETING)):
                raise QtmServerError(f"unexpected greeting {greeting!r}")
            self._protocol_version = await self._negotiate(channel)
            reply = await channel.request("GetParameters 6D")
            if not isinstance(reply, XmlPacket):
                raise QtmServerError(f"GetParameters 6D answered with {reply!r}")
            parameters = parse_6d_parameters(reply.text)
            self._new_session(
                StreamSession(
                    source=f"{self.host}:{self.port}",
                    protocol_version=format_version(self._protocol_version),
                    component=self.component,
                    body_names=tuple(parameters.names),
                    parameters_xml=reply.text,
                )
            )
            local_host: str = writer.get_extra_info("sockname")[0]
            server_host: str = writer.get_extra_info("peername")[0]
            loop = asyncio.get_running_loop()
            self.receiver.reset(parameters.names, self.component)
            if self.transport == "udp":
                transport, _ = await loop.create_datagram_endpoint(
                    lambda: _DatagramProtocol(self, server_host),
                    local_addr=(local_host, self._udp_port_request),
                )
                self._udp_port = transport.get_extra_info("sockname")[1]
            # QTM replies nothing to StreamFrames on success; an Error packet if it fails.
            # Without UDP:<port> it streams over this connection (§1.3).
            channel.send(stream_frames_command([self.component], udp_port=self._udp_port))
            channel.streaming_over_tcp = self.transport == "tcp"
            self._sessions += 1
            self._last_datagram_s = loop.time()
            self._connected.set()
            self._streamed = True
            await self._supervise(channel)
        finally:
            self._connected.clear()
            self._udp_port = None
            if transport is not None:
                transport.close()
            if self._streamed:
                with contextlib.suppress(OSError):
                    writer.write(encode_command("StreamFrames Stop"))
            writer.close()
            with contextlib.suppress(OSError, TimeoutError):
                await asyncio.wait_for(writer.wait_closed(), 0.5)

    async def _negotiate(self, channel: _CommandChannel) -> ProtocolVersion:
        """Ask for the preferred version, then each lower minor down to 1.8 (§1.2)."""
        major, minor = self._version_request
        for candidate in range(minor, MIN_PROTOCOL_VERSION[1] - 1, -1):
            text = format_version((major, candidate))
            reply = await channel.request(f"Version {text}")
            if isinstance(reply, CommandPacket) and reply.text.lower().startswith("version set"):
                return major, candidate
            if not isinstance(reply, (CommandPacket, ErrorPacket)):
                raise QtmServerError(f"Version {text} answered with {reply!r}")
        raise QtmServerError("no common protocol version ≥ 1.8")

    async def _supervise(self, channel: _CommandChannel) -> None:
        """Watch the command channel while frames flow (over UDP, or through ``read`` over
        this channel); return never, raise on loss."""
        loop = asyncio.get_running_loop()
        while True:
            try:
                packet = await asyncio.wait_for(channel.read(), self.keepalive_s)
            except TimeoutError:
                if loop.time() - self._last_datagram_s >= self.keepalive_s:
                    await channel.request("Version")  # raises TimeoutError if QTM is gone
                continue
            self._check_streaming_packet(packet)
            if self.receiver.consecutive_mismatches >= 10:
                # QTM's rigid-body set changed: reconnect to read the new names.
                raise QtmServerError("body count differs from the 6D parameters")

    def _check_streaming_packet(self, packet: Packet) -> None:
        if isinstance(packet, ErrorPacket):
            raise QtmServerError(f"server error while streaming: {packet.text}")
        # Events and late replies are not needed; frames went to ``_on_tcp_packet``.

    def _on_datagram(self, data: bytes, addr: tuple[str | int, ...], server_host: str) -> None:
        if addr[0] != server_host:
            # Only the QTM host may inject frames: on a shared lab network anything else
            # reaching this port is a misdirected stream or worse.
            self.receiver.count_foreign()
            return
        port = addr[1] if len(addr) > 1 and isinstance(addr[1], int) else None
        self._last_datagram_s = asyncio.get_running_loop().time()
        self._accepted(self.receiver.receive_datagram(data, self._clock(), port))

    def _on_tcp_packet(self, packet: Packet) -> None:
        """A data or No-More-Data packet read from the command connection while streaming
        over it."""
        self._last_datagram_s = asyncio.get_running_loop().time()
        self._accepted(self.receiver.receive_packet(packet, self._clock()))

    def _accepted(self, frame: MocapFrame | None) -> None:
        if frame is not None:
            self._frame_arrived.set()
            if self._frame_listener is not None:
                self._frame_listener()
        if self.receiver.consecutive_mismatches >= 10:
            self._last_error = "body count differs from the 6D parameters"


class _CommandChannel:
    """The TCP command connection of one session: send commands, read packets."""

    def __init__(
        self,
        reader: asyncio.StreamReader,
        writer: asyncio.StreamWriter,
        timeout_s: float,
        client: QtmClient,
    ) -> None:
        self._reader = reader
        self._writer = writer
        self._timeout_s = timeout_s
        self._client = client
        self._decoder = QtmStreamDecoder()
        self.streaming_over_tcp = False
        """Set once StreamFrames asked for frames on this connection: its data packets then
        go to the client's receiver, whoever reads them (a command's reply may wait behind
        frames)."""

    def send(self, command: str) -> None:
        self._writer.write(encode_command(command))

    async def read(self) -> Packet:
        """The next packet; raises ``ConnectionError`` at end of stream."""
        while (packet := self._decoder.next_packet()) is None:
            data = await self._reader.read(65536)
            if not data:
                raise ConnectionError("QTM closed the connection")
            self._decoder.receive_data(data)
        if isinstance(packet, EventPacket):
            self._client.last_event = packet.event
        elif self.streaming_over_tcp and isinstance(packet, (DataPacket, NoMoreDataPacket)):
            self._client._on_tcp_packet(packet)
        return packet

    async def request(self, command: str) -> Packet:
        """Send a command and return its reply (Command, Error or XML packet), skipping
        events and data that may be interleaved (§1.3)."""
        self.send(command)
        async with asyncio.timeout(self._timeout_s):
            while True:
                packet = await self.read()
                if isinstance(packet, (CommandPacket, ErrorPacket, XmlPacket)):
                    if isinstance(packet, ErrorPacket) and command.lower().startswith("getparam"):
                        raise QtmServerError(f"{command}: {packet.text}")
                    return packet
