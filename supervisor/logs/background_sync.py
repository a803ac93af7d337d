"""fsync off the tick's path: a thread that syncs a file whenever asked.

An fsync waits for the disk, tens of ms when it is busy, and a flight log must reach it
without delaying a tick; the writer hands its data to the OS on the tick (which is what
survives a killed process) and asks this thread to sync (what survives a power cut).
"""

from __future__ import annotations

import contextlib
import os
import threading
from pathlib import Path


class BackgroundSync:
    """fsyncs a file in a thread of its own whenever asked, and once more on close."""

    def __init__(self, path: Path) -> None:
        self._fd = os.open(path, os.O_RDONLY)  # fsync reaches the file through any descriptor
        self._wanted = threading.Event()
        self._stopping = False
        self._thread = threading.Thread(target=self._run, name="flight-log-fsync", daemon=True)
        self._thread.start()

    def request(self) -> None:
        self._wanted.set()

    def _run(self) -> None:
        while True:
            self._wanted.wait()
            self._wanted.clear()
            if self._stopping:
                return
            with contextlib.suppress(OSError):  # the writer's own writes report the disk
                os.fsync(self._fd)

    def close(self) -> None:
        """Stop the thread, sync once more and release the file (raises ``OSError`` when
        that last sync fails; the file is released all the same). Once only."""
        if self._stopping:
            return
        self._stopping = True
        self._wanted.set()
        self._thread.join()
        try:
            os.fsync(self._fd)
        finally:
            os.close(self._fd)
