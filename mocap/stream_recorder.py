"""Records the stream a client receives, as it receives it, into a QTM recording file
(``mocap.recording``'s format): the flight process's own mocap input, written beside its
flight log, so that the flight's estimate can be replayed on the flight's own clock
(``supervisor.logs.mocap_replay``).

The receiving side only appends each datagram and its receive time to a list; a thread
of the recorder's own encodes and compresses them twice a second, so no tick waits for
gzip. Each batch ends with a gzip sync flush: a killed process leaves a file that reads
up to the last batch (``read_recording`` keeps what is complete).
"""

from __future__ import annotations

import base64
import gzip
import json
import threading
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from mocap.qtm_protocol import COMPONENT_NAMES, ComponentType
from mocap.recording import FORMAT, VERSION

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
    (on the receive times' clock)."""

    def __init__(self, path: Path, session: StreamSession, clock_start_s: float) -> None:
        self.path = path
        self.session = session
        self.clock_start_s = clock_start_s
        self.packets = 0
        self._pending: list[tuple[float, bytes]] = []
        self._stop = threading.Event()
        path.parent.mkdir(parents=True, exist_ok=True)
        self._handle = gzip.open(path, "wt", encoding="utf-8")  # noqa: SIM115 (closed by close)
        header = {
            "format": FORMAT,
            "version": VERSION,
            "source": session.source,
            "protocol_version": session.protocol_version,
            "component": COMPONENT_NAMES[session.component],
            "body_names": list(session.body_names),
            "parameters_xml": session.parameters_xml,
            "started": datetime.now(UTC).isoformat(),
            "clock_start_s": clock_start_s,
        }
        self._handle.write(json.dumps(header) + "\n")
        self._handle.flush()
        self._thread = threading.Thread(target=self._run, name="mocap-recorder", daemon=True)
        self._thread.start()

    def packet(self, data: bytes, receive_time_s: float) -> None:
        """One datagram as received (called on the receiving loop: a list append only)."""
        self._pending.append((receive_time_s, data))

    def _run(self) -> None:
        while not self._stop.wait(FLUSH_PERIOD_S):
            self._write_pending()

    def _write_pending(self) -> None:
        # Swapping the list is atomic under the GIL: the receiving loop appends to the new one.
        batch, self._pending = self._pending, []
        if not batch:
            return
        lines = [
            json.dumps({"t_s": t - self.clock_start_s, "packet": base64.b64encode(data).decode()})
            + "\n"
            for t, data in batch
        ]
        self._handle.write("".join(lines))
        self._handle.flush()
        self.packets += len(batch)

    def close(self) -> None:
        """Write what is left and close the file."""
        self._stop.set()
        self._thread.join()
        self._write_pending()
        self._handle.close()
