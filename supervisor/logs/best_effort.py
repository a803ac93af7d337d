"""Flight logging is best-effort, as PX4's logger is: a write error (a full disk, a folder
gone) ends the log, never the tick, the mocap path or the process. ``BestEffortLog`` wraps
either format's writer, keeps the first error as ``failure`` for the flight process to
report, and writes nothing more."""

from __future__ import annotations

import contextlib
import errno
import shutil
from datetime import datetime
from pathlib import Path
from typing import Any

from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import FlightLogSink, LogFormat, open_flight_log

# What the writers raise for a failed write: the JSON Lines writer the OS's error, the MCAP
# writer (foxglove-sdk) a RuntimeError naming its I/O error.
WRITE_ERRORS = (OSError, RuntimeError)
NEARLY_FULL_BYTES = 64 * 1024  # less than a chunk of the MCAP writer's


class BestEffortLog:
    """A flight log at ``path`` whose first write error stops it (``failure``)."""

    def __init__(
        self,
        path: Path,
        header: dict[str, Any],
        log_format: LogFormat = "jsonl",
        started: datetime | None = None,
    ) -> None:
        self.path = path
        self.failure: Exception | None = None
        self._sink: FlightLogSink | None = None
        try:
            self._sink = open_flight_log(path, header, log_format, started)
        except WRITE_ERRORS as error:
            self.failure = error

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None:
        """Write one tick, unless the log has stopped."""
        if self._sink is None:
            return
        try:
            self._sink.append(record, notices)
        except WRITE_ERRORS as error:
            self.failure = error
            self.close()

    def close(self) -> None:
        """Close the file (what it holds stays readable up to the last write)."""
        sink, self._sink = self._sink, None
        if sink is None:
            return
        try:
            sink.close()
        except WRITE_ERRORS as error:
            self.failure = self.failure or error
            with contextlib.suppress(*WRITE_ERRORS):
                sink.close()  # the MCAP writer refuses once after a failed write, then closes


def write_error_words(error: Exception, folder: Path) -> str:
    """A write error in ``folder`` as an operator reads it: a full disk said so (foxglove-sdk
    says no more than "I/O error", so the disk itself is asked)."""
    full = isinstance(error, OSError) and error.errno == errno.ENOSPC
    with contextlib.suppress(OSError):
        full = full or shutil.disk_usage(folder).free < NEARLY_FULL_BYTES
    return "log disk full" if full else f"cannot write the log ({error})"
