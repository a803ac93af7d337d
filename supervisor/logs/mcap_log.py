"""The flight log as MCAP: Foxglove's and our own channels (``flight_messages``), crash-safe.

Every tick's messages go into the current chunk; the chunk is finished and handed to the
OS at least once a second of the log's time (``FLUSH_INTERVAL_S``), and a thread fsyncs the
file after each (an fsync can take tens of ms on a busy disk: never on the tick's path). A
writer killed at any moment leaves a file without a summary whose complete chunks
``read_mcap_records`` recovers, losing at most the last second; bytes changed anywhere else
(the CRCs and LZ4's checksums tell) make it refuse the file, saying where.

Two libraries can write it, with the same channels, schemas and messages: ``foxglove`` (the
SDK's own writer, in Rust: the default) and ``mcap`` (the ``mcap`` package's writer in
Python, messages encoded by ``foxglove-sdk``). ``python -m benchmarks.flight_log`` measures
what each costs a tick: the SDK's costs less, the flush most of all. Chunks are LZ4: zstd
packs them about a third smaller but doubles the flush's cost.
"""

from __future__ import annotations

import contextlib
import io
import json
import struct
import zlib
from collections import defaultdict
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal, Protocol

import foxglove
import foxglove.channels
import foxglove.messages as fg
import pydantic_core
from foxglove.mcap import MCAPCompression, MCAPWriteOptions
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.records import Channel as McapChannel
from mcap.records import Chunk, DataEnd, Footer, McapRecord, Message, Metadata
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, Writer

from geometry.formation import FormationLayout
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.background_sync import BackgroundSync
from supervisor.logs.flight_log import logged_attachments_m, logged_layout
from supervisor.logs.flight_messages import (
    NOTICES_TOPIC,
    PER_TICK_TOPICS,
    SceneStyle,
    json_messages,
    json_schemas,
    record_from_messages,
    well_known,
    well_known_messages,
)

FLUSH_INTERVAL_S = 1.0
# Larger than a second of ticks (about 150 kB), so that only the flush finishes a chunk.
CHUNK_BYTES = 8 * 1024 * 1024
HEADER_METADATA = "uavbar.header"
McapLibrary = Literal["mcap", "foxglove"]


class _Sink(Protocol):
    def write(self, topic: str, log_time_ns: int, message: bytes | Any) -> None: ...
    def flush(self) -> None: ...
    def close(self) -> None: ...


def _json_schema_bytes(schema: dict[str, Any]) -> bytes:
    return json.dumps(schema).encode()


class _McapPackageSink:
    """The ``mcap`` package's writer; Foxglove's messages encoded by the SDK."""

    def __init__(self, path: Path, metadata: dict[str, str], layout: FormationLayout) -> None:
        self._file: IO[bytes] = path.open("wb")
        self._writer = Writer(self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.LZ4)
        self._writer.start(profile="", library="uavbar-supervisor (mcap)")
        self._channels: dict[str, int] = {}
        for topic, (name, schema) in json_schemas(layout).items():
            schema_id = self._writer.register_schema(name, "jsonschema", _json_schema_bytes(schema))
            self._channels[topic] = self._writer.register_channel(topic, "json", schema_id)
        for topic, kind in well_known(layout).items():
            fox = kind.get_schema()
            schema_id = self._writer.register_schema(fox.name, fox.encoding, fox.data)
            self._channels[topic] = self._writer.register_channel(topic, "protobuf", schema_id)
        self._writer.add_metadata(HEADER_METADATA, metadata)
        self._writer.flush()  # type: ignore[no-untyped-call]

    def write(self, topic: str, log_time_ns: int, message: bytes | Any) -> None:
        data = message if isinstance(message, bytes) else message.encode()
        self._writer.add_message(self._channels[topic], log_time_ns, data, log_time_ns)

    def flush(self) -> None:
        self._writer.flush()  # type: ignore[no-untyped-call]

    def close(self) -> None:
        self._writer.finish()  # type: ignore[no-untyped-call]
        self._file.close()


class FoxgloveChannels:
    """Every channel of a flight log of ``layout``'s formation (``json_schemas``,
    ``well_known``) on a ``foxglove.Context``: what is written to them reaches every sink of
    the context (an MCAP file, a WebSocket server)."""

    def __init__(self, context: foxglove.Context, layout: FormationLayout) -> None:
        self._channels: dict[str, Any] = {}
        for topic, (name, schema) in json_schemas(layout).items():
            self._channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=name, encoding="jsonschema", data=_json_schema_bytes(schema)
                ),
                message_encoding="json",
                context=context,
            )
        for topic, kind in well_known(layout).items():
            channel_type = getattr(foxglove.channels, f"{kind.__name__}Channel")
            self._channels[topic] = channel_type(topic, context=context)

    def write(self, topic: str, log_time_ns: int, message: bytes | Any) -> None:
        self._channels[topic].log(message, log_time=log_time_ns)

    def has_sinks(self) -> bool:
        """Whether anything (a file, a subscribed WebSocket client) takes any channel."""
        return any(channel.has_sinks() for channel in self._channels.values())

    def close(self) -> None:
        for channel in self._channels.values():
            channel.close()


class _FoxgloveSdkSink:
    """``foxglove-sdk``'s writer, on a context of its own (no other sink sees it)."""

    def __init__(self, path: Path, metadata: dict[str, str], layout: FormationLayout) -> None:
        self._context = foxglove.Context()
        options = MCAPWriteOptions(
            compression=MCAPCompression.Lz4, chunk_size=CHUNK_BYTES, compression_threads=0
        )
        self._writer = foxglove.open_mcap(
            path, allow_overwrite=True, context=self._context, writer_options=options
        )
        self._channels = FoxgloveChannels(self._context, layout)
        try:
            self._writer.write_metadata(HEADER_METADATA, metadata)
            self._writer.flush()
        except RuntimeError:
            with contextlib.suppress(RuntimeError):
                self._writer.close()  # a writer dropped open panics at the interpreter's exit
            raise

    def write(self, topic: str, log_time_ns: int, message: bytes | Any) -> None:
        self._channels.write(topic, log_time_ns, message)

    def flush(self) -> None:
        self._writer.flush()

    def close(self) -> None:
        self._writer.close()


def tick_messages(
    record: TickRecord,
    notices: tuple[str, ...],
    log_time_ns: int,
    layout: FormationLayout,
    style: SceneStyle | None,
) -> Iterator[tuple[str, bytes | Any]]:
    """Every message of one tick of ``layout``'s formation, by topic: our JSON (encoded)
    and, with a ``style`` to draw with, Foxglove's (to be encoded by the sink)."""
    for topic, payload in json_messages(record, layout):
        yield topic, pydantic_core.to_json(payload, inf_nan_mode="null")
    for text in notices:
        notice = {"t_s": record.t_s, "text": text}
        yield NOTICES_TOPIC, pydantic_core.to_json(notice, inf_nan_mode="null")
    if style is not None:
        stamp = fg.Timestamp(log_time_ns // 1_000_000_000, log_time_ns % 1_000_000_000)
        yield from well_known_messages(record, stamp, style)


class McapFlightLogWriter:
    """Appends tick records to an MCAP file (created or replaced); a context manager.

    ``header`` is kept as the metadata record ``uavbar.header`` (each value JSON); its
    ``attachments_m`` (``flight_log.formation_header``) name the formation's UAVs, and let
    ``/scene`` draw the payload and the cables (without: the paper's two UAVs, no scene).
    Raises ``ValueError`` for a header whose attachments do not read.
    """

    def __init__(
        self,
        path: Path,
        header: dict[str, Any],
        started: datetime | None = None,
        library: McapLibrary = "foxglove",
    ) -> None:
        started = started or datetime.now(UTC)
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        full_header = {"started": started.isoformat(), **header}
        metadata = {key: json.dumps(value) for key, value in full_header.items()}
        attachments_m = logged_attachments_m(header)
        self._layout = logged_layout(attachments_m)
        self._style = SceneStyle(attachments_m) if attachments_m else None
        sink_type = _McapPackageSink if library == "mcap" else _FoxgloveSdkSink
        self._sink: _Sink = sink_type(path, metadata, self._layout)
        self._sync = BackgroundSync(path)
        self._sync.request()
        self._start_ns = int(started.timestamp() * 1e9)
        self._first_t_s: float | None = None
        self._last_flush_s = 0.0
        self._closed = False

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None:
        """Write one tick's messages; finish the chunk when the last is a second old."""
        if self._first_t_s is None:
            self._first_t_s = self._last_flush_s = record.t_s
        log_time_ns = self._start_ns + round((record.t_s - self._first_t_s) * 1e9)
        for topic, payload in json_messages(record, self._layout):
            self._sink.write(
                topic, log_time_ns, pydantic_core.to_json(payload, inf_nan_mode="null")
            )
        for text in notices:
            notice = pydantic_core.to_json({"t_s": record.t_s, "text": text}, inf_nan_mode="null")
            self._sink.write(NOTICES_TOPIC, log_time_ns, notice)
        if self._style is not None:
            stamp = fg.Timestamp(log_time_ns // 1_000_000_000, log_time_ns % 1_000_000_000)
            for topic, message in well_known_messages(record, stamp, self._style):
                self._sink.write(topic, log_time_ns, message)
        if record.t_s - self._last_flush_s >= FLUSH_INTERVAL_S:
            self._sink.flush()
            self._sync.request()
            self._last_flush_s = record.t_s

    def close(self) -> None:
        """Close the file. Raises when its last write fails (the sync thread is released
        all the same); foxglove-sdk's writer refuses once after a failed write, and a
        second call closes it."""
        if not self._closed:
            try:
                self._sink.close()
                self._closed = True
            finally:
                self._sync.close()

    def __enter__(self) -> McapFlightLogWriter:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


class RecoveredMcap:
    """What a (possibly torn) MCAP flight log holds: its header, every tick record in order,
    the notices (t_s, text), and whether the file ended cleanly with its summary."""

    def __init__(self) -> None:
        self.header: dict[str, Any] | None = None
        self.records: list[TickRecord] = []
        self.notices: list[tuple[float, str]] = []
        self.complete = False


MAGIC = b"\x89MCAP0\r\n"
# Every record is an opcode, the content's length and the content (MCAP spec, "Records").
RECORD_PREFIX = struct.Struct("<BQ")
# Our writers write no other record (the spec's private opcodes 0x80-0xff neither): any
# other opcode is a byte that is not where a record starts.
OPCODES = frozenset(Opcode)
# What the mcap package raises below it for bytes that are not what it expects: its own
# errors, struct's, LZ4's (RuntimeError: a frame or its checksum), UTF-8's and
# CRCValidationError (ValueErrors), an impossible length (OverflowError).
UNREADABLE = (McapError, struct.error, ValueError, RuntimeError, OverflowError)


class _Bounded(io.BytesIO):
    """One record's content: a field that runs past its end is an error, not a short read
    (which ``ReadDataStream`` would take as it is)."""

    def read(self, size: int | None = -1, /) -> bytes:
        data = super().read(size)
        if size is not None and 0 <= size != len(data):
            raise ValueError(f"a field of {size} bytes runs past the record's end")
        return data


def _parsed(opcode: int, content: bytes) -> list[McapRecord]:
    """The records one top-level record holds: the chunk's (its CRC and LZ4 checksum
    checked), or itself for those the reader uses; nothing for the indexes and statistics
    (the summary CRC checks them)."""
    stream = ReadDataStream(_Bounded(content))
    if opcode == Opcode.CHUNK:
        return list(breakup_chunk(Chunk.read(stream), validate_crc=True))
    if opcode == Opcode.MESSAGE:
        return [Message.read(stream, len(content))]
    readers: dict[int, Any] = {
        Opcode.CHANNEL: McapChannel.read,
        Opcode.METADATA: Metadata.read,
        Opcode.DATA_END: DataEnd.read,
        Opcode.FOOTER: Footer.read,
    }
    return [readers[opcode](stream)] if opcode in readers else []


def _corrupt(path: Path, offset: int, what: str) -> ValueError:
    return ValueError(f"{path}: corrupt at byte {offset}: {what}")


def _mcap_records(path: Path, recovered: RecoveredMcap) -> Iterator[McapRecord]:
    """Every record in file order, chunks opened, each checked: the chunks' CRCs and LZ4
    checksums, the data section's and the summary's CRCs, every length. The end a killed
    writer leaves — a last record that runs past the end of a file without the closing
    magic — ends the iteration (``recovered.complete`` then stays False); any other bytes
    that do not read raise ``ValueError`` naming where the record holding them starts."""
    size = path.stat().st_size
    with path.open("rb") as handle:
        handle.seek(size - len(MAGIC))
        closed = size > 2 * len(MAGIC) and handle.read() == MAGIC
        handle.seek(len(MAGIC))
        offset = len(MAGIC)
        data_crc: int | None = zlib.crc32(MAGIC)  # None after the data section
        summary_crc = 0
        while True:
            prefix = handle.read(RECORD_PREFIX.size)
            if len(prefix) == RECORD_PREFIX.size:
                opcode, length = RECORD_PREFIX.unpack(prefix)
                if opcode not in OPCODES:
                    raise _corrupt(path, offset, f"no MCAP record starts with {opcode:#04x}")
                fits = length <= size - offset - RECORD_PREFIX.size
            else:
                opcode, length, fits = 0, 0, False
            if not fits:
                if closed:
                    raise _corrupt(path, offset, "a record runs past the end of the file")
                return  # torn by a killed writer: everything before it is whole
            content = handle.read(length)
            try:
                records = _parsed(opcode, content)
            except UNREADABLE as error:
                name = Opcode(opcode).name.lower()
                raise _corrupt(path, offset, f"{name} record: {error}") from error
            record = records[0] if records else None
            if isinstance(record, DataEnd):
                if data_crc is not None and record.data_section_crc not in (0, data_crc):
                    raise _corrupt(path, offset, "the data section's CRC does not match")
                data_crc = None
            elif isinstance(record, Footer):
                summary_crc = zlib.crc32(prefix + content[:16], summary_crc)
                if record.summary_start and record.summary_crc not in (0, summary_crc):
                    raise _corrupt(path, offset, "the summary's CRC does not match")
                if handle.read() != MAGIC:
                    raise _corrupt(path, offset + RECORD_PREFIX.size + length, "no end magic")
                recovered.complete = True
                return
            elif data_crc is not None:
                data_crc = zlib.crc32(content, zlib.crc32(prefix, data_crc))
            else:
                summary_crc = zlib.crc32(content, zlib.crc32(prefix, summary_crc))
            yield from records
            offset += RECORD_PREFIX.size + length


_JSON_TOPICS = frozenset((*PER_TICK_TOPICS, NOTICES_TOPIC))


def _decoded_messages(path: Path, recovered: RecoveredMcap) -> Iterator[tuple[str, Any]]:
    """(topic, decoded JSON) of our own channels in file order (``_mcap_records``); the
    header into ``recovered``."""
    topics: dict[int, str] = {}
    for record in _mcap_records(path, recovered):
        if isinstance(record, McapChannel):
            topics[record.id] = record.topic
        elif isinstance(record, Metadata) and record.name == HEADER_METADATA:
            try:
                recovered.header = {key: json.loads(v) for key, v in record.metadata.items()}
            except ValueError as error:
                raise ValueError(f"{path}: corrupt {HEADER_METADATA} ({error})") from error
        elif isinstance(record, Message):
            topic = topics.get(record.channel_id, "")
            if topic in _JSON_TOPICS:
                try:
                    yield topic, json.loads(record.data)
                except ValueError as error:
                    raise ValueError(f"{path}: corrupt {topic} message ({error})") from error


def _header_layout(path: Path, header: dict[str, Any] | None) -> FormationLayout:
    """The layout of the ticks ``header`` announces (``ValueError`` naming ``path`` for a
    message before it, which our writers never write, or for attachments that do not
    read)."""
    if header is None:
        raise ValueError(f"{path}: a message before its {HEADER_METADATA} metadata")
    try:
        return logged_layout(logged_attachments_m(header))
    except ValueError as error:
        raise ValueError(f"{path}: corrupt {HEADER_METADATA} ({error})") from error


def read_mcap_records(path: Path) -> RecoveredMcap:
    """Read back every complete tick of an MCAP flight log; of a file torn by a killed
    writer, those before the tear. Raises ``ValueError`` naming the file and what is wrong
    for a file that is not a flight log (empty, no MCAP magic, no ``uavbar.header``) or
    whose bytes were changed (a CRC, a checksum, a length or a message that does not
    read)."""
    with path.open("rb") as handle:
        magic = handle.read(len(MAGIC))
    if not magic:
        raise ValueError(f"{path}: empty file, not a flight log")
    if magic != MAGIC:
        raise ValueError(f"{path}: not an MCAP file")
    recovered = RecoveredMcap()
    pending: dict[str, list[Any]] = defaultdict(list)
    layout: FormationLayout | None = None
    for topic, message in _decoded_messages(path, recovered):
        if layout is None:
            layout = _header_layout(path, recovered.header)
        try:
            if topic == NOTICES_TOPIC:
                recovered.notices.append((float(message["t_s"]), str(message["text"])))
                continue
            pending[topic].append(message)
            if all(pending[t] for t in PER_TICK_TOPICS):
                tick = {t: pending[t].pop(0) for t in PER_TICK_TOPICS}
                recovered.records.append(record_from_messages(tick, layout))
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{path}: a {topic} message of another shape ({error!r})") from error
    if recovered.header is None:
        if not recovered.complete:
            raise ValueError(f"{path}: cut short before its {HEADER_METADATA} metadata")
        raise ValueError(f"{path}: no {HEADER_METADATA} metadata: not a flight log")
    return recovered
