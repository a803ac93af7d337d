"""A recorded QTM RT stream: every data packet as it arrived, with its arrival time (pure).

The file is gzip-compressed JSON Lines: a header line (``{"format": "uavbar-qtm-recording",
"version": 1, ...}``: the source's address, the protocol version and component negotiated,
the body names and the ``GetParameters 6D`` XML), then one line per packet,
``{"t_s": arrival time [s] since the recording started, "packet": base64 of the whole RT
packet, header included}``. ``mocap.recorder`` writes it from a live stream,
``sim.qtm_replay`` serves it again.

A file cut short — its gzip stream without its end (a recorder killed, a disk full, a copy
cut off) or its last line without its end — reads up to its last complete packet, and the
``Recording`` says so (``truncation``) for whoever reads it to tell the operator; bytes
changed inside it (gzip's CRC, deflate, a line that does not read) make it refused.
"""

from __future__ import annotations

import base64
import gzip
import json
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mocap.qtm_protocol import (
    COMPONENT_NAMES,
    ComponentType,
    DataPacket,
    MocapFrame,
    Packet,
    QtmProtocolError,
    component_type_from_name,
    decode_datagram,
    frame_from_packet,
)

FORMAT = "uavbar-qtm-recording"
VERSION = 1


@dataclass(frozen=True)
class RecordedPacket:
    """One packet as it arrived: ``arrival_s`` [s] since the recording started, ``data``
    the whole RT packet (header included)."""

    arrival_s: float
    data: bytes


@dataclass(frozen=True)
class Recording:
    """A recorded stream: where it came from, what was negotiated, and every packet."""

    source: str
    protocol_version: str
    component: ComponentType
    body_names: tuple[str, ...]
    parameters_xml: str
    started: str
    clock_start_s: float
    """The recorder's clock when arrival times start (its ``time.monotonic``: on the same
    machine, the flight process's clock, so a recording lines up with a flight log)."""
    packets: tuple[RecordedPacket, ...]
    truncation: str | None = None
    """What shows that the file was cut short (the packets are those before the cut), or
    None for a file that ends as it was written."""

    @property
    def frame_count(self) -> int:
        """How many of the packets are frames (``frames``)."""
        return sum(1 for _ in self.frames())

    @property
    def duration_s(self) -> float:
        """From the first packet's arrival to the last's [s]."""
        if not self.packets:
            return 0.0
        return self.packets[-1].arrival_s - self.packets[0].arrival_s

    def decoded(self) -> Iterator[tuple[RecordedPacket, Packet]]:
        """Every packet with its decoded form (``QtmProtocolError`` for a malformed one,
        which a recorder never keeps)."""
        for packet in self.packets:
            yield packet, decode_datagram(packet.data)

    def frames(self) -> Iterator[MocapFrame]:
        """The data packets as frames, each received at its recorded arrival time."""
        for packet, decoded in self.decoded():
            if isinstance(decoded, DataPacket) and decoded.six_d(self.component) is not None:
                yield frame_from_packet(decoded, self.body_names, packet.arrival_s, self.component)


def header_line(
    source: str,
    protocol_version: str,
    component: ComponentType,
    body_names: tuple[str, ...],
    parameters_xml: str,
    started: str,
    clock_start_s: float,
) -> str:
    """A recording's first line: where the stream came from and what was negotiated."""
    header = {
        "format": FORMAT,
        "version": VERSION,
        "source": source,
        "protocol_version": protocol_version,
        "component": COMPONENT_NAMES[component],
        "body_names": list(body_names),
        "parameters_xml": parameters_xml,
        "started": started,
        "clock_start_s": clock_start_s,
    }
    return json.dumps(header) + "\n"


def packet_line(arrival_s: float, data: bytes) -> str:
    """One packet's line: its arrival time [s] since the recording started, and the packet."""
    return json.dumps({"t_s": arrival_s, "packet": base64.b64encode(data).decode()}) + "\n"


def write_recording(recording: Recording, path: Path) -> None:
    """Write ``recording`` to ``path`` (gzip JSON Lines; created or replaced)."""
    r = recording
    path.parent.mkdir(parents=True, exist_ok=True)
    with gzip.open(path, "wt", encoding="utf-8") as handle:
        handle.write(
            header_line(
                r.source,
                r.protocol_version,
                r.component,
                r.body_names,
                r.parameters_xml,
                r.started,
                r.clock_start_s,
            )
        )
        for packet in r.packets:
            handle.write(packet_line(packet.arrival_s, packet.data))


def _header(line: bytes, path: Path) -> dict[str, Any]:
    try:
        header = json.loads(line.decode("utf-8"))
    except ValueError as error:  # JSON's and UTF-8's
        raise ValueError(f"{path}: not a QTM recording ({error})") from error
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{path}: not a QTM recording (no {FORMAT} header)")
    if header.get("version") != VERSION:
        raise ValueError(f"{path}: recording version {header.get('version')}, not {VERSION}")
    return header


GZIP_MAGIC = b"\x1f\x8b"


def _complete_lines(path: Path) -> tuple[list[bytes], str | None]:
    """The file's complete lines (without their newline), and what shows that it was cut
    short (None when it ends as written: the gzip stream's end, its CRC, a last newline)."""
    with path.open("rb") as handle:
        magic = handle.read(len(GZIP_MAGIC))
    if not GZIP_MAGIC.startswith(magic):
        raise ValueError(f"{path}: not a QTM recording (not gzip-compressed)")
    if magic and magic != GZIP_MAGIC:
        return [], "its gzip stream ends early"
    lines: list[bytes] = []
    truncation: str | None = None
    try:
        with gzip.open(path, "rb") as handle:
            lines.extend(handle)  # what was read before an EOFError stays
    except EOFError:
        truncation = "its gzip stream ends early"
        # Unless the file ends with the trailer of what it held (RFC 1952: CRC-32, size):
        # then its writer finished it, and a changed bit kept the stream from ending.
        held = b"".join(lines)
        trailer = struct.pack("<II", zlib.crc32(held), len(held) & 0xFFFFFFFF)
        with path.open("rb") as handle:
            handle.seek(max(0, path.stat().st_size - len(trailer)))
            if handle.read() == trailer:
                raise ValueError(f"{path}: corrupt (its gzip stream runs past its end)") from None
    except (gzip.BadGzipFile, zlib.error) as error:
        raise ValueError(f"{path}: corrupt ({error}), found after {len(lines)} lines") from error
    if lines and not lines[-1].endswith(b"\n"):
        lines.pop()
        truncation = truncation or "its last line is cut"
    return [line.rstrip(b"\n") for line in lines], truncation


def truncation_warning(path: Path, recording: Recording) -> str | None:
    """One line for the operator when ``recording`` (read from ``path``) was cut short:
    what shows it and what it holds; None when it was not."""
    if recording.truncation is None:
        return None
    return (
        f"{path}: truncated ({recording.truncation}): it holds {recording.frame_count} "
        f"frames over {recording.duration_s:.2f} s"
    )


def read_recording(path: Path) -> Recording:
    """Read a recording. A file cut short is read up to its last complete packet, its
    ``truncation`` saying what shows the cut. Raises ``ValueError`` naming the file (and
    the line) for a file that is not a recording or is corrupt: gzip's CRC or deflate
    stream, a packet that does not decode, arrival times that go backwards."""
    lines, truncation = _complete_lines(path)
    if not lines:
        if truncation is not None:
            raise ValueError(f"{path}: truncated before its header ended ({truncation})")
        raise ValueError(f"{path}: empty file, not a QTM recording")
    header = _header(lines[0], path)
    packets: list[RecordedPacket] = []
    for number, line in enumerate(lines[1:], start=2):
        try:
            entry = json.loads(line.decode("utf-8"))
            data = base64.b64decode(entry["packet"], validate=True)
            packet = RecordedPacket(float(entry["t_s"]), data)
            decode_datagram(packet.data)
        except (ValueError, KeyError, TypeError, QtmProtocolError) as error:
            raise ValueError(f"{path}:{number}: not a recorded packet ({error})") from error
        if packets and packet.arrival_s < packets[-1].arrival_s:
            raise ValueError(f"{path}:{number}: arrival time goes backwards")
        packets.append(packet)
    try:
        return Recording(
            source=str(header["source"]),
            protocol_version=str(header["protocol_version"]),
            component=component_type_from_name(str(header["component"])),
            body_names=tuple(str(name) for name in header["body_names"]),
            parameters_xml=str(header["parameters_xml"]),
            started=str(header["started"]),
            clock_start_s=float(header["clock_start_s"]),
            packets=tuple(packets),
            truncation=truncation,
        )
    except (KeyError, QtmProtocolError) as error:
        raise ValueError(f"{path}: the recording's header lacks {error}") from error
    except (ValueError, TypeError) as error:
        raise ValueError(f"{path}: the recording's header does not read ({error})") from error
