"""Records the stream a client receives, as it receives it, into a QTM recording file
(``mocap.recording``'s format): the flight process's own mocap input, written beside its
flight log, so that the flight's estimate can be replayed on the flight's own clock
(``supervisor.logs.mocap_replay``).

Each datagram is written as it is received (about 5 µs: a line handed to gzip's buffer),
on the receiving loop itself: a thread of Python work in the flight process would hold the
GIL against the tick for up to the interpreter's switch interval. Every
``FLUSH_PERIOD_S`` of receive time the stream is sync-flushed to the OS (about 80 µs), so
a killed process leaves a file that reads up to the last flush (``read_recording`` keeps
what is complete).

Recording is best-effort: a write error (a full disk) ends the recording, never the
receiving. The first error is kept as ``failure`` for the owner to report, and nothing more
is written.
"""

from __future__ import annotations

import contextlib
import gzip
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from mocap.qtm_protocol import ComponentType
from mocap.recording import header_line, packet_line

FLUSH_PERIOD_S = 0.5


@dataclass(frozen=True)
class StreamSession:
    """What a recording's header says of the stream: where it came from and what was
    negotiated."""

    source: str
    protocol_version: str
    component: ComponentType
    body_names: tuple[str, ...]
    parameters_xml: str


class StreamRecorder:
    """Appends every datagram given to ``packet`` to ``path``, timed from ``clock_start_s``
    (on the receive times' clock), until closed or a write fails (``failure``)."""

    def __init__(self, path: Path, session: StreamSession, clock_start_s: float) -> None:
        self.path = path
        self.session = session
        self.clock_start_s = clock_start_s
        self.failure: OSError | None = None
        self._flushed_s = clock_start_s
        self._handle: gzip.GzipFile | None = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            # Binary: its close releases the file even when the last write fails.
            self._handle = gzip.open(path, "wb")  # noqa: SIM115 (closed by close)
            self._write(
                header_line(
                    session.source,
                    session.protocol_version,
                    session.component,
                    session.body_names,
                    session.parameters_xml,
                    datetime.now(UTC).isoformat(),
                    clock_start_s,
                )
            )
            self._handle.flush()
        except OSError as error:
            self._fail(error)

    def packet(self, data: bytes, receive_time_s: float) -> None:
        """One datagram as received at ``receive_time_s``."""
        if self._handle is None:
            return
        try:
            self._write(packet_line(receive_time_s - self.clock_start_s, data))
            if receive_time_s - self._flushed_s >= FLUSH_PERIOD_S:
                self.flush(receive_time_s)
        except OSError as error:
            self._fail(error)

    def flush(self, now_s: float) -> None:
        """Hand what was written to the OS, readable (a gzip sync flush); raises ``OSError``
        when the write fails."""
        if self._handle is not None:
            self._handle.flush()
        self._flushed_s = now_s

    def close(self) -> None:
        """Write what is left and close the file."""
        handle, self._handle = self._handle, None
        if handle is None:
            return
        try:
            handle.close()
        except OSError as error:
            self._fail(error)

    def _write(self, line: str) -> None:
        assert self._handle is not None
        self._handle.write(line.encode())

    def _fail(self, error: OSError) -> None:
        """Stop for good on the first write error; the file keeps what was flushed."""
        self.failure = self.failure or error
        handle, self._handle = self._handle, None
        if handle is not None:
            with contextlib.suppress(OSError):
                handle.close()
