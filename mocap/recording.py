"""A recorded QTM RT stream: every data packet as it arrived, with its arrival time (pure).

The file is gzip-compressed JSON Lines: a header line (``{"format": "uavbar-qtm-recording",
"version": 1, ...}``: the source's address, the protocol version and component negotiated,
the body names and the ``GetParameters 6D`` XML), then one line per packet,
``{"t_s": arrival time [s] since the recording started, "packet": base64 of the whole RT
packet, header included}``. ``mocap.recorder`` writes it from a live stream,
``sim.qtm_replay`` serves it again.
"""

from __future__ import annotations

import base64
import gzip
import json
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


def _header(line: str, path: Path) -> dict[str, Any]:
    try:
        header = json.loads(line)
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not a QTM recording ({error})") from error
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise ValueError(f"{path}: not a QTM recording (no {FORMAT} header)")
    if header.get("version") != VERSION:
        raise ValueError(f"{path}: recording version {header.get('version')}, not {VERSION}")
    return header


def _complete_lines(path: Path) -> list[str]:
    """The file's lines; of a file cut short (its writer killed: ``StreamRecorder``), the
    lines before the cut."""
    lines: list[str] = []
    try:
        with gzip.open(path, "rt", encoding="utf-8") as handle:
            for line in handle:
                lines.append(line)
    except EOFError:
        if lines and not lines[-1].endswith("\n"):
            lines.pop()
    except (gzip.BadGzipFile, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not a QTM recording ({error})") from error
    return [line.rstrip("\n") for line in lines]


def read_recording(path: Path) -> Recording:
    """Read a recording. Raises ``ValueError`` for a file that is not one, or a packet that
    does not decode, or arrival times that go backwards. A file cut short is read up to its
    last complete packet."""
    lines = _complete_lines(path)
    if not lines:
        raise ValueError(f"{path}: empty")
    header = _header(lines[0], path)
    packets: list[RecordedPacket] = []
    for number, line in enumerate(lines[1:], start=2):
        try:
            entry = json.loads(line)
            packet = RecordedPacket(float(entry["t_s"]), base64.b64decode(entry["packet"]))
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
        )
    except (KeyError, QtmProtocolError) as error:
        raise ValueError(f"{path}: the recording's header lacks {error}") from error
