"""QTM real-time (RT) protocol core: packets as values, bytes in and out, no I/O.

Everything here follows ``docs/reference/qtm-rt.md`` §1 (the Qualisys "QTM
Real-time Server Protocol Documentation", protocol 1.20, plus the 1.21–1.25 changes seen in
the Qualisys SDKs). Only the little-endian port (base + 1, default 22223) is spoken, and only
protocol ≥ 1.8, where 6D records are float32 (§1.2).

Layers, bottom up:

* packets — ``CommandPacket``, ``ErrorPacket``, ``XmlPacket``, ``EventPacket``,
  ``NoMoreDataPacket``, ``DataPacket`` (with ``SixDComponent`` for 6D, 6DRes, 6DEuler and
  6DEulerRes; other components are kept as ``RawComponent`` bytes) and ``OtherPacket``;
  ``encode_packet`` and ``decode_packet`` convert them (§1.4);
* decoders — ``QtmStreamDecoder`` for the TCP byte stream (feeding it one byte at a time
  gives the same packets as feeding it everything at once) and ``decode_datagram`` for one
  UDP datagram, which always holds exactly one RT packet (§1.3);
* commands and parameters — ``StreamFrames`` and ``Version`` text, the 6D parameters XML
  (body names, §1.4 "Body names"), parsed with the standard library;
* poses — ``BodyPose`` and ``MocapFrame``: a 6D record in SI units and the paper's
  conventions (metres in the arena frame, (w, x, y, z) quaternion, Z-Y-X Euler angles), and
  back. Every unit and rotation conversion goes through ``geometry.frames``.

Malformed input never raises anything but ``QtmProtocolError``. Untracked bodies (QTM sends
NaN, §1.4 "Untracked bodies") decode as untracked, never as zeros.
"""

from __future__ import annotations

import enum
import math
import re
import struct
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Final, TypeAlias

import numpy as np

from geometry import frames
from geometry.arrays import FloatArray


class QtmProtocolError(Exception):
    """Input that does not follow the QTM RT protocol (a malformed packet, XML or command).

    The only exception the decoding functions of this module raise on bad input.
    ``packets`` holds, when ``QtmStreamDecoder.feed`` raises, the well-formed packets that
    preceded the malformed one in that call, so that none is lost.
    """

    packets: tuple[Packet, ...] = ()


# --- Constants (docs/reference/qtm-rt.md §1.1, §1.4) ---------------------------------------

LITTLE_ENDIAN_PORT: Final = 22223
"""Default QTM RT port for little-endian clients, protocol ≥ 1.1 (§1.1)."""

GREETING: Final = "QTM RT Interface connected"
"""The Command packet QTM sends on connect (§1.2). The doc example ends with a ".", but
qtm-rt 3.1.0 compares the whole string (``protocol.py`` ``_on_command``), so a server must
send exactly this or the SDK takes the greeting for the reply to its ``Version`` command."""

MAX_CLIENTS_MESSAGE: Final = "Connection refused. Max number of clients reached."

MAX_PACKET_SIZE_B: Final = 16 * 1024 * 1024
"""Default upper bound on a packet's size field in the TCP stream. QTM's largest packets
(images, C3D files) stay well below; a larger size is taken as a corrupt stream, not as a
reason to buffer gigabytes."""

MAX_DATAGRAM_SIZE_B: Final = 65507
"""Largest UDP payload over IPv4."""

HEADER = struct.Struct("<II")
"""RT packet header: size in bytes *including* these 8, packet type (§1.4)."""
DATA_HEADER = struct.Struct("<qII")
"""After the RT header of a Data packet: timestamp [µs], frame number, component count.
16 bytes, not the 12 of the 1.20 doc's size row (doc erratum, §1.4)."""
COMPONENT_HEADER = struct.Struct("<II")
"""Component size in bytes *including* these 8, component type (§1.4)."""
SIX_D_HEADER = struct.Struct("<IHH")
"""6D component header: body count, 2D drop rate [‰], 2D out-of-sync rate [‰] (§1.4)."""
EVENT_BODY = struct.Struct("<B")


class PacketType(enum.IntEnum):
    """RT packet types (§1.4)."""

    ERROR = 0
    COMMAND = 1
    XML = 2
    DATA = 3
    NO_MORE_DATA = 4
    C3D_FILE = 5
    EVENT = 6
    DISCOVER = 7
    QTM_FILE = 8


class ComponentType(enum.IntEnum):
    """Data component types (§1.4; 19 is in the SDK, not in the 1.20 doc)."""

    THREE_D = 1
    THREE_D_NO_LABELS = 2
    ANALOG = 3
    FORCE = 4
    SIX_D = 5
    SIX_D_EULER = 6
    TWO_D = 7
    TWO_D_LIN = 8
    THREE_D_RES = 9
    THREE_D_NO_LABELS_RES = 10
    SIX_D_RES = 11
    SIX_D_EULER_RES = 12
    ANALOG_SINGLE = 13
    IMAGE = 14
    FORCE_SINGLE = 15
    GAZE_VECTOR = 16
    TIMECODE = 17
    SKELETON = 18
    EYE_TRACKER = 19


class QtmEvent(enum.IntEnum):
    """Event ids carried by Event packets (§1.4); unknown ids are kept as plain ints."""

    CONNECTED = 1
    CONNECTION_CLOSED = 2
    CAPTURE_STARTED = 3
    CAPTURE_STOPPED = 4
    CALIBRATION_STARTED = 6
    CALIBRATION_STOPPED = 7
    RT_FROM_FILE_STARTED = 8
    RT_FROM_FILE_STOPPED = 9
    WAITING_FOR_TRIGGER = 10
    CAMERA_SETTINGS_CHANGED = 11
    QTM_SHUTTING_DOWN = 12
    CAPTURE_SAVED = 13
    TRIGGER = 16


# Per-body record: 3 position floats [mm], then 9 rotation floats or 3 Euler angles [deg],
# then a residual [mm] for the *Res variants (§1.4).
_SIX_D_FLOATS: Final = {
    ComponentType.SIX_D: 12,
    ComponentType.SIX_D_RES: 13,
    ComponentType.SIX_D_EULER: 6,
    ComponentType.SIX_D_EULER_RES: 7,
}
SIX_D_TYPES: Final = frozenset(_SIX_D_FLOATS)
"""The four rigid-body component types this module decodes."""

SIX_D_RECORD_SIZE_B: Final = {kind: 4 * n for kind, n in _SIX_D_FLOATS.items()}
"""Bytes per body: 48 (6D), 52 (6DRes), 24 (6DEuler), 28 (6DEulerRes)."""

COMPONENT_NAMES: Final = {
    ComponentType.SIX_D: "6D",
    ComponentType.SIX_D_RES: "6DRes",
    ComponentType.SIX_D_EULER: "6DEuler",
    ComponentType.SIX_D_EULER_RES: "6DEulerRes",
}
"""Component names as written in ``StreamFrames``/``GetCurrentFrame`` commands (§1.3)."""

_COMPONENTS_BY_NAME: Final = {name.lower(): kind for kind, name in COMPONENT_NAMES.items()}

# QTM marks an untracked body with "all 32 bits set" NaNs (§1.4); we send the same bytes.
_UNTRACKED_FLOAT: Final = b"\xff\xff\xff\xff"


# --- Packet values ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class CommandPacket:
    """A command (client → server) or a command response (server → client), ASCII text."""

    text: str


@dataclass(frozen=True, slots=True)
class ErrorPacket:
    """An error response, e.g. ``"Parse Error"`` or ``"Version NOT supported"``."""

    text: str


@dataclass(frozen=True, slots=True)
class XmlPacket:
    """An XML document: parameters (server → client) or settings (client → server)."""

    text: str


@dataclass(frozen=True, slots=True)
class EventPacket:
    """A one-byte event (a ``QtmEvent`` value, or another id QTM may add)."""

    event: int


@dataclass(frozen=True, slots=True)
class NoMoreDataPacket:
    """Sent instead of data while no measurement is running (§1.3)."""


@dataclass(frozen=True, slots=True)
class OtherPacket:
    """A packet type this module does not interpret (C3D file, Discover, QTM file)."""

    packet_type: PacketType
    payload: bytes


@dataclass(frozen=True, slots=True)
class SixDBody:
    """One rigid-body record of a 6D-family component, in QTM's units and order (§1.4).

    ``position_mm``: (x, y, z) [mm] in the QTM global frame. ``rotation``: the 9 floats of
    the rotation matrix (body → global), column-major as on the wire, for 6D/6DRes.
    ``euler_deg``: (roll, pitch, yaw) [deg], Qualisys standard, for 6DEuler/6DEulerRes.
    ``residual_mm``: for the *Res types. Untracked bodies hold NaN (QTM's marker).
    """

    position_mm: tuple[float, float, float]
    rotation: tuple[float, ...] | None = None
    euler_deg: tuple[float, float, float] | None = None
    residual_mm: float | None = None

    @property
    def tracked(self) -> bool:
        """True when every value is finite (QTM sends NaN for an untracked body, and a NaN
        residual also means the record is unusable, §1.4)."""
        values: list[float] = list(self.position_mm)
        values += self.rotation or ()
        values += self.euler_deg or ()
        if self.residual_mm is not None:
            values.append(self.residual_mm)
        return all(math.isfinite(v) for v in values)

    @staticmethod
    def untracked(component_type: ComponentType) -> SixDBody:
        """The record QTM sends for an untracked body of a component type: all NaN."""
        nan = math.nan
        rotation = (nan,) * 9 if component_type in _MATRIX_TYPES else None
        euler = (nan, nan, nan) if rotation is None else None
        residual = nan if component_type in _RESIDUAL_TYPES else None
        return SixDBody((nan, nan, nan), rotation, euler, residual)


_IDENTITY: Final = np.eye(3)
_MATRIX_TYPES: Final = frozenset({ComponentType.SIX_D, ComponentType.SIX_D_RES})
_RESIDUAL_TYPES: Final = frozenset({ComponentType.SIX_D_RES, ComponentType.SIX_D_EULER_RES})


@dataclass(frozen=True, slots=True)
class SixDComponent:
    """A 6D, 6DRes, 6DEuler or 6DEulerRes component: one record per body, in the order of
    the ``<Body>`` elements of ``GetParameters 6D`` (§1.4)."""

    component_type: ComponentType
    bodies: tuple[SixDBody, ...]
    drop_rate_permille: int = 0
    out_of_sync_rate_permille: int = 0


@dataclass(frozen=True, slots=True)
class RawComponent:
    """A component this module does not interpret, kept as its payload bytes (after the
    8-byte component header) so that it survives a decode → encode round trip."""

    component_type: int
    payload: bytes


DataComponent: TypeAlias = SixDComponent | RawComponent


@dataclass(frozen=True, slots=True)
class DataPacket:
    """One frame of measured data (§1.4).

    ``timestamp_us``: capture time [µs] since the measurement started (int64).
    ``frame_number``: uint32, counts frames of the measurement.
    """

    timestamp_us: int
    frame_number: int
    components: tuple[DataComponent, ...] = ()

    def six_d(self, preferred: ComponentType | None = None) -> SixDComponent | None:
        """The component of type ``preferred`` if present, else the first 6D-family one."""
        found: SixDComponent | None = None
        for component in self.components:
            if isinstance(component, SixDComponent):
                if component.component_type == preferred:
                    return component
                found = found or component
        return found


Packet: TypeAlias = (
    CommandPacket
    | ErrorPacket
    | XmlPacket
    | EventPacket
    | NoMoreDataPacket
    | DataPacket
    | OtherPacket
)


# --- Encoding --------------------------------------------------------------------------------


def _text_payload(text: str) -> bytes:
    # Server → client text is always NUL-terminated (§1.4); it is optional client → server
    # but harmless, and qtm-rt sends it too.
    return text.encode("utf-8") + b"\0"


def _pack_floats(values: Sequence[float]) -> bytes:
    try:
        return struct.pack(f"<{len(values)}f", *values)
    except (struct.error, OverflowError) as error:
        raise ValueError(f"cannot pack {values!r} as float32: {error}") from error


def _encode_body(kind: ComponentType, body: SixDBody) -> bytes:
    values: list[float] = list(body.position_mm)
    if kind in _MATRIX_TYPES:
        if body.rotation is None or len(body.rotation) != 9:
            raise ValueError(f"a {COMPONENT_NAMES[kind]} record needs 9 rotation floats")
        values += body.rotation
    else:
        if body.euler_deg is None or len(body.euler_deg) != 3:
            raise ValueError(f"a {COMPONENT_NAMES[kind]} record needs 3 Euler angles")
        values += body.euler_deg
    if kind in _RESIDUAL_TYPES:
        if body.residual_mm is None:
            raise ValueError(f"a {COMPONENT_NAMES[kind]} record needs a residual")
        values.append(body.residual_mm)
    if len(body.position_mm) != 3:
        raise ValueError("a position has 3 coordinates")
    if all(math.isnan(v) for v in values):
        return _UNTRACKED_FLOAT * len(values)
    return _pack_floats(values)


def _encode_component(component: DataComponent) -> bytes:
    if isinstance(component, RawComponent):
        payload = component.payload
        kind = component.component_type
    else:
        kind = component.component_type
        if kind not in SIX_D_TYPES:
            raise ValueError(f"component type {kind} is not a 6D type")
        payload = SIX_D_HEADER.pack(
            len(component.bodies),
            component.drop_rate_permille,
            component.out_of_sync_rate_permille,
        ) + b"".join(_encode_body(kind, body) for body in component.bodies)
    return COMPONENT_HEADER.pack(COMPONENT_HEADER.size + len(payload), kind) + payload


def encode_packet(packet: Packet) -> bytes:
    """The bytes of one RT packet, header included (§1.4, little-endian).

    Raises ``ValueError`` for a value that cannot be represented (a caller's bug, not a
    protocol error): a float outside float32, a record without its rotation, and so on.
    """
    payload: bytes
    match packet:
        case CommandPacket(text):
            kind, payload = PacketType.COMMAND, _text_payload(text)
        case ErrorPacket(text):
            kind, payload = PacketType.ERROR, _text_payload(text)
        case XmlPacket(text):
            kind, payload = PacketType.XML, _text_payload(text)
        case EventPacket(event):
            kind, payload = PacketType.EVENT, EVENT_BODY.pack(event)
        case NoMoreDataPacket():
            kind, payload = PacketType.NO_MORE_DATA, b""
        case OtherPacket(packet_type, raw):
            kind, payload = packet_type, raw
        case DataPacket(timestamp_us, frame_number, components):
            kind = PacketType.DATA
            payload = DATA_HEADER.pack(timestamp_us, frame_number, len(components)) + b"".join(
                _encode_component(c) for c in components
            )
    return HEADER.pack(HEADER.size + len(payload), kind) + payload


def encode_command(text: str) -> bytes:
    """A client command such as ``"Version 1.25"`` as a Command packet (§1.2)."""
    return encode_packet(CommandPacket(text))


# --- Decoding --------------------------------------------------------------------------------


def decode_header(
    data: bytes | bytearray | memoryview, max_size: int = MAX_PACKET_SIZE_B
) -> tuple[int, int]:
    """(size, type) of the RT header at the start of ``data`` (at least 8 bytes).

    Raises ``QtmProtocolError`` if the size cannot hold the header, exceeds ``max_size``,
    or the type is not one of §1.4's.
    """
    if len(data) < HEADER.size:
        raise QtmProtocolError(f"{len(data)} bytes cannot hold an 8-byte RT header")
    size, kind = HEADER.unpack_from(data, 0)
    if size < HEADER.size:
        raise QtmProtocolError(f"packet size {size} is smaller than its 8-byte header")
    if size > max_size:
        raise QtmProtocolError(f"packet size {size} exceeds the limit of {max_size} bytes")
    if kind not in _PACKET_TYPES:
        raise QtmProtocolError(f"unknown packet type {kind}")
    return size, kind


_PACKET_TYPES: Final = frozenset(int(t) for t in PacketType)


def _decode_text(payload: bytes) -> str:
    # C-string semantics: the text ends at the first NUL (server → client always has one).
    end = payload.find(b"\0")
    raw = payload if end < 0 else payload[:end]
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        # Body names typed on a Windows machine may arrive in a legacy code page; latin-1
        # maps every byte, so a name is never the reason to drop the connection.
        return raw.decode("latin-1")


def _decode_six_d(kind: ComponentType, payload: memoryview) -> SixDComponent:
    if len(payload) < SIX_D_HEADER.size:
        raise QtmProtocolError(f"{COMPONENT_NAMES[kind]} component shorter than its header")
    count, drop, out_of_sync = SIX_D_HEADER.unpack_from(payload, 0)
    n = _SIX_D_FLOATS[kind]
    expected = SIX_D_HEADER.size + count * 4 * n
    if len(payload) != expected:
        raise QtmProtocolError(
            f"{COMPONENT_NAMES[kind]} component of {len(payload)} bytes cannot hold "
            f"{count} bodies ({expected} bytes expected)"
        )
    bodies: list[SixDBody] = []
    for record in struct.iter_unpack(f"<{n}f", payload[SIX_D_HEADER.size :]):
        position = (record[0], record[1], record[2])
        if kind in _MATRIX_TYPES:
            rotation: tuple[float, ...] | None = tuple(record[3:12])
            euler: tuple[float, float, float] | None = None
        else:
            rotation, euler = None, (record[3], record[4], record[5])
        residual = record[-1] if kind in _RESIDUAL_TYPES else None
        bodies.append(SixDBody(position, rotation, euler, residual))
    return SixDComponent(kind, tuple(bodies), drop, out_of_sync)


def _decode_data(payload: memoryview) -> DataPacket:
    if len(payload) < DATA_HEADER.size:
        raise QtmProtocolError(f"data packet payload of {len(payload)} bytes has no frame header")
    timestamp_us, frame_number, count = DATA_HEADER.unpack_from(payload, 0)
    position = DATA_HEADER.size
    # Every component takes at least its 8-byte header: bound the loop before running it.
    if count > (len(payload) - position) // COMPONENT_HEADER.size:
        raise QtmProtocolError(f"{count} components cannot fit in {len(payload)} bytes")
    components: list[DataComponent] = []
    for _ in range(count):
        if position + COMPONENT_HEADER.size > len(payload):
            raise QtmProtocolError("component header runs past the end of the packet")
        size, kind = COMPONENT_HEADER.unpack_from(payload, position)
        if size < COMPONENT_HEADER.size or position + size > len(payload):
            raise QtmProtocolError(f"component size {size} does not fit the packet")
        body = payload[position + COMPONENT_HEADER.size : position + size]
        if kind in _SIX_D_FLOATS:
            components.append(_decode_six_d(ComponentType(kind), body))
        else:
            components.append(RawComponent(kind, bytes(body)))
        position += size
    if position != len(payload):
        raise QtmProtocolError(f"{len(payload) - position} bytes after the last component")
    return DataPacket(timestamp_us, frame_number, tuple(components))


def _decode_payload(kind: int, payload: memoryview) -> Packet:
    match kind:
        case PacketType.COMMAND:
            return CommandPacket(_decode_text(bytes(payload)))
        case PacketType.ERROR:
            return ErrorPacket(_decode_text(bytes(payload)))
        case PacketType.XML:
            return XmlPacket(_decode_text(bytes(payload)))
        case PacketType.EVENT:
            if len(payload) != EVENT_BODY.size:
                raise QtmProtocolError(f"event packet with {len(payload)} payload bytes, not 1")
            return EventPacket(payload[0])
        case PacketType.NO_MORE_DATA:
            if len(payload):
                raise QtmProtocolError(f"no-more-data packet with {len(payload)} payload bytes")
            return NoMoreDataPacket()
        case PacketType.DATA:
            return _decode_data(payload)
        case _:
            return OtherPacket(PacketType(kind), bytes(payload))


def decode_packet(
    data: bytes | bytearray | memoryview, max_size: int = MAX_PACKET_SIZE_B
) -> Packet:
    """The packet that ``data`` holds exactly: header size must equal ``len(data)``.

    Raises ``QtmProtocolError`` (and nothing else) for anything malformed: bad header, short
    or trailing bytes, component sizes that do not add up, 6D body counts that do not match
    the component size, event or no-more-data packets with the wrong payload length.
    """
    view = memoryview(data).cast("B")
    size, kind = decode_header(view, max_size)
    if size != len(view):
        raise QtmProtocolError(f"header says {size} bytes, got {len(view)}")
    return _decode_payload(kind, view[HEADER.size :])


def decode_datagram(datagram: bytes) -> Packet:
    """The RT packet in one UDP datagram. Each datagram is one whole packet with its own
    header, even when QTM splits a large frame over several (§1.3); a datagram that is not
    exactly one packet raises ``QtmProtocolError``."""
    return decode_packet(datagram, MAX_DATAGRAM_SIZE_B)


class QtmStreamDecoder:
    """Incremental decoder for the TCP byte stream: feed bytes, take packets (§1.4).

    Splitting the input anywhere, down to single bytes, gives the same packets in the same
    order. The first malformed packet raises ``QtmProtocolError``, after which the decoder
    is *failed* and raises again on every call: on a reliable stream a corrupt packet means
    the framing can no longer be trusted, so the right response is to drop the connection.
    """

    def __init__(self, max_packet_size: int = MAX_PACKET_SIZE_B) -> None:
        self._buffer = bytearray()
        self._max_packet_size = max_packet_size
        self._error: QtmProtocolError | None = None

    @property
    def buffered(self) -> int:
        """Bytes received but not yet part of a complete packet."""
        return len(self._buffer)

    @property
    def failed(self) -> bool:
        """True after a malformed packet; the decoder then refuses all input."""
        return self._error is not None

    def receive_data(self, data: bytes) -> None:
        """Append received bytes; nothing is parsed until ``next_packet``."""
        if self._error is not None:
            raise QtmProtocolError(f"stream already failed: {self._error}")
        self._buffer += data

    def next_packet(self) -> Packet | None:
        """The next complete packet, or None if more bytes are needed."""
        if self._error is not None:
            raise QtmProtocolError(f"stream already failed: {self._error}")
        if len(self._buffer) < HEADER.size:
            return None
        try:
            size, kind = decode_header(self._buffer, self._max_packet_size)
            if len(self._buffer) < size:
                return None
            # Decode from a copy: views into the bytearray would pin it against resizing.
            raw = bytes(self._buffer[HEADER.size : size])
            packet = _decode_payload(kind, memoryview(raw))
        except QtmProtocolError as error:
            self._error = error
            raise
        del self._buffer[:size]
        return packet

    def feed(self, data: bytes) -> list[Packet]:
        """``receive_data`` then every complete packet. On a malformed packet this raises
        ``QtmProtocolError`` with the packets that preceded it in ``error.packets``."""
        self.receive_data(data)
        packets: list[Packet] = []
        try:
            while (packet := self.next_packet()) is not None:
                packets.append(packet)
        except QtmProtocolError as error:
            error.packets = tuple(packets)
            raise
        return packets


# --- Commands (§1.2, §1.3) -------------------------------------------------------------------

ProtocolVersion: TypeAlias = tuple[int, int]

_VERSION_RE: Final = re.compile(r"(\d+)\.(\d+)")


def format_version(version: ProtocolVersion) -> str:
    """``(1, 25)`` → ``"1.25"``."""
    return f"{version[0]}.{version[1]}"


def parse_version(text: str) -> ProtocolVersion:
    """The first ``major.minor`` in ``text`` (``"1.25"``, ``"Version set to 1.25"``)."""
    match = _VERSION_RE.search(text)
    if match is None:
        raise QtmProtocolError(f"no protocol version in {text!r}")
    return int(match.group(1)), int(match.group(2))


def component_type_from_name(name: str) -> ComponentType:
    """``"6deuler"`` (any case) → ``ComponentType.SIX_D_EULER``; only the 6D family."""
    try:
        return _COMPONENTS_BY_NAME[name.lower()]
    except KeyError:
        raise QtmProtocolError(f"unsupported component {name!r}") from None


@dataclass(frozen=True, slots=True)
class StreamFramesRequest:
    """A parsed ``StreamFrames`` command (§1.3).

    ``rate``: ``"allframes"``, ``"frequency"`` or ``"frequencydivisor"``; ``rate_value`` is
    the n of the last two. ``udp_port`` None means stream over the TCP connection;
    ``udp_address`` None means the address the command came from. ``components`` are
    names as sent, lower-cased.
    """

    stop: bool = False
    rate: str = "allframes"
    rate_value: int | None = None
    udp_address: str | None = None
    udp_port: int | None = None
    components: tuple[str, ...] = ()


def stream_frames_command(
    components: Iterable[ComponentType | str],
    *,
    udp_port: int | None = None,
    udp_address: str | None = None,
    rate: str = "AllFrames",
) -> str:
    """``StreamFrames AllFrames UDP:6734 6D`` and the like (§1.3). ``rate`` is
    ``"AllFrames"``, ``"Frequency:n"`` or ``"FrequencyDivisor:n"``."""
    words = ["StreamFrames", rate]
    if udp_port is not None:
        if not 1 <= udp_port <= 65535:
            raise ValueError(f"UDP port {udp_port} out of range")
        words.append(f"UDP:{udp_address}:{udp_port}" if udp_address else f"UDP:{udp_port}")
    for component in components:
        words.append(
            COMPONENT_NAMES[component] if isinstance(component, ComponentType) else component
        )
    return " ".join(words)


def parse_stream_frames(arguments: str) -> StreamFramesRequest:
    """The arguments after ``StreamFrames`` (case-insensitive, space-separated, §1.3).

    Raises ``QtmProtocolError`` for a missing or bad rate, a bad UDP port, or no components.
    UDP ports below 1023 are accepted: the doc's "valid 1023–65535" is a QTM GUI rule, and
    tests want ephemeral ports anyway.
    """
    words = arguments.split()
    if len(words) == 1 and words[0].lower() == "stop":
        return StreamFramesRequest(stop=True)
    if not words:
        raise QtmProtocolError("StreamFrames needs a rate and components")
    rate_word, *rest = words
    rate, _, value_text = rate_word.lower().partition(":")
    rate_value: int | None = None
    if rate == "allframes" and not value_text:
        pass
    elif rate in ("frequency", "frequencydivisor") and value_text.isdigit():
        rate_value = int(value_text)
        if rate_value < 1:
            raise QtmProtocolError(f"bad rate {rate_word!r}")
    else:
        raise QtmProtocolError(f"bad rate {rate_word!r}")
    udp_address: str | None = None
    udp_port: int | None = None
    components: list[str] = []
    for word in rest:
        if word.lower().startswith("udp:"):
            address, _, port_text = word[4:].rpartition(":")
            if not port_text.isdigit() or not 1 <= int(port_text) <= 65535:
                raise QtmProtocolError(f"bad UDP port in {word!r}")
            udp_address, udp_port = address or None, int(port_text)
        else:
            components.append(word.lower())
    if not components:
        raise QtmProtocolError("StreamFrames without components")
    return StreamFramesRequest(False, rate, rate_value, udp_address, udp_port, tuple(components))


# --- 6D parameters XML (§1.4 "Body names") ---------------------------------------------------


@dataclass(frozen=True, slots=True)
class SixDParameters:
    """The rigid bodies of ``GetParameters 6D``, in data order (body i of a 6D component is
    ``names[i]``). Disabled bodies keep their index (§1.4, inference), so they are listed."""

    names: tuple[str, ...]
    enabled: tuple[bool, ...]


def parse_6d_parameters(xml_text: str) -> SixDParameters:
    """Body names and enabled flags of a ``GetParameters 6D`` reply, 1.20 or 1.25 layout.

    Raises ``QtmProtocolError`` for XML that does not parse, has no ``<The_6D>``, a body
    without a name, or duplicate names (they would collide in a name-keyed frame).
    """
    # QTM never sends a DTD; refusing them keeps entity expansion out of the parser.
    if "<!DOCTYPE" in xml_text or "<!ENTITY" in xml_text:
        raise QtmProtocolError("6D parameters XML with a DTD")
    try:
        root = ET.fromstring(xml_text)
    except (ET.ParseError, ValueError) as error:
        raise QtmProtocolError(f"6D parameters are not XML: {error}") from error
    six_d = root if root.tag == "The_6D" else root.find("The_6D")
    if six_d is None:
        raise QtmProtocolError("no <The_6D> element in the 6D parameters")
    names: list[str] = []
    enabled: list[bool] = []
    for body in six_d.findall("Body"):
        name = body.findtext("Name")
        if name is None or not name.strip():
            raise QtmProtocolError("a <Body> without a <Name>")
        names.append(name.strip())
        enabled.append((body.findtext("Enabled") or "true").strip().lower() == "true")
    if len(set(names)) != len(names):
        raise QtmProtocolError(f"duplicate body names in {names}")
    return SixDParameters(tuple(names), tuple(enabled))


def build_6d_parameters_xml(names: Sequence[str], version: ProtocolVersion = (1, 25)) -> str:
    """A ``GetParameters 6D`` reply for these bodies: the 1.25 layout (Qualisys' C++ SDK
    test data), plus the 1.20 ``<Bodies>`` count for versions ≤ 1.20 (§1.4)."""
    root = ET.Element(f"QTM_Parameters_Ver_{format_version(version)}")
    six_d = ET.SubElement(root, "The_6D")
    if version <= (1, 20):
        ET.SubElement(six_d, "Bodies").text = str(len(names))
    palette = ((255, 0, 0), (0, 255, 0), (0, 0, 255), (255, 255, 0), (0, 255, 255))
    for index, name in enumerate(names):
        body = ET.SubElement(six_d, "Body")
        ET.SubElement(body, "Name").text = name
        ET.SubElement(body, "Enabled").text = "true"
        r, g, b = palette[index % len(palette)]
        ET.SubElement(body, "Color", R=str(r), G=str(g), B=str(b))
        ET.SubElement(body, "Points")
    return ET.tostring(root, encoding="unicode")


# --- Poses in SI units and the paper's conventions -------------------------------------------

# A 6D rotation further than this from orthonormal (float32 rounding is ~1e-7) is corrupt.
_ORTHONORMAL_TOLERANCE: Final = 1e-3


def _nan_array(n: int) -> FloatArray:
    return np.full(n, math.nan)


@dataclass(frozen=True, eq=False)
class BodyPose:
    """One rigid body's pose in one frame, in SI units.

    ``position_m``: shape (3,), arena frame (= the QTM global frame, z up), metres.
    ``quaternion``: shape (4,), (w, x, y, z) with w ≥ 0, rotating body (FLU) vectors into
    the arena frame. ``euler_zyx_rad``: shape (3,), the paper's (roll φ, pitch θ, yaw ψ),
    R = Rz(ψ)·Ry(θ)·Rx(φ), eq. (2). ``residual_mm``: QTM's fit residual if streamed.
    An untracked body has ``tracked`` False and NaN arrays — never zeros.
    """

    name: str
    tracked: bool
    position_m: FloatArray = field(default_factory=lambda: _nan_array(3))
    quaternion: FloatArray = field(default_factory=lambda: _nan_array(4))
    euler_zyx_rad: FloatArray = field(default_factory=lambda: _nan_array(3))
    residual_mm: float | None = None

    @staticmethod
    def untracked(name: str) -> BodyPose:
        """A body QTM could not track in this frame."""
        return BodyPose(name, False)

    @staticmethod
    def from_rotation(
        name: str, position_m: FloatArray, R: FloatArray, residual_mm: float | None = None
    ) -> BodyPose:
        """A tracked pose from a position [m], shape (3,), and a rotation body → arena,
        shape (3, 3)."""
        q = frames.quaternion_from_rotation(R)
        return BodyPose(
            name,
            True,
            np.array(position_m, dtype=float),
            q,
            frames.euler_zyx_from_quaternion(q),
            residual_mm,
        )

    @staticmethod
    def from_quaternion(
        name: str, position_m: FloatArray, quaternion: FloatArray, residual_mm: float | None = None
    ) -> BodyPose:
        """A tracked pose from a position [m], shape (3,), and a (w, x, y, z) quaternion."""
        return BodyPose.from_rotation(
            name, position_m, frames.rotation_from_quaternion(quaternion), residual_mm
        )

    def rotation(self) -> FloatArray:
        """Rotation matrix body → arena, shape (3, 3) (NaN when untracked)."""
        if not self.tracked:
            return np.full((3, 3), math.nan)
        return frames.rotation_from_quaternion(self.quaternion)


@dataclass(frozen=True, eq=False)
class MocapFrame:
    """One motion-capture frame: every rigid body's pose, keyed by QTM body name in the
    order of ``GetParameters 6D``.

    ``frame_number`` and ``timestamp_us`` are QTM's (capture time since the measurement
    started, µs). ``receive_time_s`` is when the client received it, on its injectable
    clock (NaN for frames not received over the network).
    """

    frame_number: int
    timestamp_us: int
    bodies: Mapping[str, BodyPose]
    receive_time_s: float = math.nan


def pose_from_body(name: str, body: SixDBody) -> BodyPose:
    """A 6D record (mm, QTM rotation) as a ``BodyPose`` (m, quaternion, Z-Y-X Euler).

    Raises ``QtmProtocolError`` when a tracked 6D/6DRes record's rotation matrix is not a
    rotation (a corrupt packet rather than a measurement).
    """
    if not body.tracked:
        return BodyPose.untracked(name)
    if body.rotation is not None:
        # Bound the entries first: a corrupt record with huge floats would overflow R.T @ R.
        if any(abs(v) > 1.0 + _ORTHONORMAL_TOLERANCE for v in body.rotation):
            raise QtmProtocolError(f"body {name!r}: rotation matrix entries outside [-1, 1]")
        R = frames.rotation_from_qtm_matrix(body.rotation)
        error = float(np.max(np.abs(R.T @ R - _IDENTITY)))
        # det R as the triple product of its columns (np.linalg.det costs ten times more)
        c0, c1, c2 = R.T.tolist()
        det = (
            c0[0] * (c1[1] * c2[2] - c1[2] * c2[1])
            - c0[1] * (c1[0] * c2[2] - c1[2] * c2[0])
            + c0[2] * (c1[0] * c2[1] - c1[1] * c2[0])
        )
        if error > _ORTHONORMAL_TOLERANCE or det < 0.0:
            raise QtmProtocolError(f"body {name!r}: rotation matrix is not a rotation")
    elif body.euler_deg is not None:
        R = frames.rotation_from_qtm_euler_deg(*body.euler_deg)
    else:
        raise QtmProtocolError(f"body {name!r}: record without rotation")
    position_m = frames.mm_to_m(np.array(body.position_mm))
    return BodyPose.from_rotation(name, position_m, R, body.residual_mm)


def body_from_pose(
    pose: BodyPose | None, component_type: ComponentType, residual_mm: float = 0.0
) -> SixDBody:
    """The 6D record QTM would send for ``pose`` (None or untracked → NaN record)."""
    if pose is None or not pose.tracked:
        return SixDBody.untracked(component_type)
    position = tuple(float(v) for v in frames.m_to_mm(pose.position_m))
    R = pose.rotation()
    rotation: tuple[float, ...] | None = None
    euler: tuple[float, float, float] | None = None
    if component_type in _MATRIX_TYPES:
        rotation = frames.qtm_matrix_from_rotation(R)
    else:
        a1, a2, a3 = (float(v) for v in frames.qtm_euler_deg_from_rotation(R))
        euler = (a1, a2, a3)
    residual = None
    if component_type in _RESIDUAL_TYPES:
        residual = pose.residual_mm if pose.residual_mm is not None else residual_mm
    return SixDBody((position[0], position[1], position[2]), rotation, euler, residual)


def frame_from_packet(
    packet: DataPacket,
    names: Sequence[str],
    receive_time_s: float = math.nan,
    preferred: ComponentType | None = None,
) -> MocapFrame:
    """The ``MocapFrame`` of a data packet, bodies named by ``names`` (from the 6D
    parameters, same order).

    Raises ``QtmProtocolError`` if the packet has no 6D-family component, its body count
    differs from ``len(names)``, or a record is corrupt (see ``pose_from_body``).
    """
    component = packet.six_d(preferred)
    if component is None:
        raise QtmProtocolError("data packet without a 6D component")
    if len(component.bodies) != len(names):
        raise QtmProtocolError(
            f"{len(component.bodies)} bodies in the data, {len(names)} in the 6D parameters"
        )
    bodies = {
        name: pose_from_body(name, body) for name, body in zip(names, component.bodies, strict=True)
    }
    return MocapFrame(packet.frame_number, packet.timestamp_us, bodies, receive_time_s)


def packet_from_poses(
    frame_number: int,
    timestamp_us: int,
    names: Sequence[str],
    poses: Mapping[str, BodyPose],
    component_types: Iterable[ComponentType],
    residual_mm: float = 0.0,
) -> DataPacket:
    """A data packet with one component per requested type; bodies in ``names`` order,
    any name missing from ``poses`` sent as untracked (NaN)."""
    components = tuple(
        SixDComponent(kind, tuple(body_from_pose(poses.get(n), kind, residual_mm) for n in names))
        for kind in component_types
    )
    return DataPacket(timestamp_us, frame_number & 0xFFFFFFFF, components)
