"""The log folder's free-space floor: a flight is not armed when its log could not be
written. Blocking (a statvfs of the folder): the flight process runs ``problem`` in a
thread, so that a stuck network folder never holds its loop."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

BYTES_PER_MB = 1e6


@dataclass(frozen=True)
class FreeSpaceFloor:
    """``folder`` must exist (it is made) and hold ``min_free_mb`` free."""

    folder: Path
    min_free_mb: float

    def problem(self) -> str | None:
        """Why a flight log cannot be written there now, with what to do; None: it can."""
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            free_mb = shutil.disk_usage(self.folder).free / BYTES_PER_MB
        except OSError as error:
            return (
                f"the log folder {self.folder} cannot be used ({error.strerror}): set "
                "log.folder to a writable folder"
            )
        if free_mb < self.min_free_mb:
            return (
                f"the log folder {self.folder} has {free_mb:.1f} MB free (at least "
                f"{self.min_free_mb:g} MB, log.min_free_mb): free space there, or set "
                "log.folder elsewhere"
            )
        return None
