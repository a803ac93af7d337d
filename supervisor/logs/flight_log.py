"""The flight log: one file per flight, JSON Lines or MCAP (``mcap_log``), crash-safe.

``open_flight_log`` picks the format by the path's extension (``.jsonl``, ``.mcap``), or
for a folder by ``log_format``; ``read_flight_log`` reads either. In JSON Lines the first
line is a header (``{"kind": "header", ...}``: setup name, parameters, start time); every
tick appends ``{"kind": "tick", ...}`` with the fields of ``TickRecord``. Each line is
flushed to the OS as it is written and the file is fsync'ed at least once a second (in a
thread: ``background_sync``), so a killed process loses at most the last second and a
reader skips a torn last line. Files are named by the flight's start time:
``flight-20261123-031500.jsonl``.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal, Protocol

import numpy as np
import pydantic_core

from controllers.formation_params import FormationParams
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.background_sync import BackgroundSync

# The logs' states and inputs are the paper's two UAVs and bar: their readers, the figures
# and the Foxglove scene name these bodies (issue 31 generalizes the controllers, not yet
# the logs).
LOG_LAYOUT = FormationLayout(2)
FSYNC_INTERVAL_S = 1.0
LogFormat = Literal["jsonl", "mcap"]
SUFFIXES: dict[str, LogFormat] = {".jsonl": "jsonl", ".mcap": "mcap"}


_TICK_FIELDS = tuple(f.name for f in fields(TickRecord))


def formation_header(params: FormationParams) -> dict[str, Any]:
    """What a log's header says of the formation: each cable's attachment in the payload's
    frame [m] (``attachments_m``) and, for the paper's bar, its arms d1, d2 (``arms_m``)."""
    header: dict[str, Any] = {
        "attachments_m": [list(point) for point in params.payload.attachments_m]
    }
    if params.payload.is_bar and params.n_vehicles == 2:
        header["arms_m"] = list(params.bar_arms_m)
    return header


def new_log_path(folder: Path, started: datetime, extension: str = ".jsonl") -> Path:
    """A file in ``folder`` named by ``started`` that does not exist yet."""
    folder.mkdir(parents=True, exist_ok=True)
    stem = f"flight-{started:%Y%m%d-%H%M%S}"
    path = folder / f"{stem}{extension}"
    suffix = 1
    while path.exists():  # two flights started within the same second
        path = folder / f"{stem}-{suffix}{extension}"
        suffix += 1
    return path


def mocap_recording_path(log_path: Path) -> Path:
    """Where the flight process records its mocap input during the flight ``log_path``
    logs: beside it, ``flight-….qtm.gz`` (supervisor/logs/mocap_replay.py replays it)."""
    return log_path.with_name(f"{log_path.stem}.qtm.gz")


class FlightLogSink(Protocol):
    """What the tick driver writes to: either format's writer."""

    path: Path

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None: ...
    def close(self) -> None: ...


def open_flight_log(
    destination: Path,
    header: dict[str, Any],
    log_format: LogFormat = "jsonl",
    started: datetime | None = None,
) -> FlightLogSink:
    """A writer for ``destination``: a ``.jsonl`` or ``.mcap`` file (its extension picks the
    format; created or replaced), or a folder, where a new file named by the start time is
    created in ``log_format``. Raises ``ValueError`` for a file of another extension."""
    started = started or datetime.now(UTC)
    if destination.suffix:
        if destination.suffix not in SUFFIXES:
            raise ValueError(
                f"{destination}: a flight log is .jsonl or .mcap, not {destination.suffix}"
            )
        log_format, path = SUFFIXES[destination.suffix], destination
    else:
        path = new_log_path(destination, started, f".{log_format}")
    if log_format == "mcap":
        from supervisor.logs.mcap_log import McapFlightLogWriter

        return McapFlightLogWriter(path, header, started)
    return FlightLogWriter(path, header, started)


class FlightLogWriter:
    """Appends tick records to a log file; use as a context manager.

    ``destination`` is a folder (a new file named by the start time is created in it; the
    service's one-log-per-flight) or a ``.jsonl`` file path (created or replaced).
    """

    def __init__(
        self, destination: Path, header: dict[str, Any], started: datetime | None = None
    ) -> None:
        started = started or datetime.now(UTC)
        if destination.suffix == ".jsonl":
            destination.parent.mkdir(parents=True, exist_ok=True)
            path, mode = destination, "w"
        else:
            path, mode = new_log_path(destination, started), "x"
        self.path = path
        self._file: IO[str] = path.open(mode, encoding="utf-8")
        self._last_sync_s = -math.inf
        self._write({"kind": "header", "started": started.isoformat(), **header})
        self._sync = BackgroundSync(path)
        self._sync.request()

    def _write(self, payload: dict[str, Any]) -> None:
        # JSON has no NaN: the serializer writes non-finite numbers as null.
        line = pydantic_core.to_json(payload, inf_nan_mode="null").decode()
        self._file.write(line + "\n")
        self._file.flush()

    def append(self, record: TickRecord, notices: tuple[str, ...] = ()) -> None:
        """Write one tick (with the notices it raised); fsync when the last sync is more than
        a second (of ``t_s``) old."""
        values = {name: getattr(record, name) for name in _TICK_FIELDS}  # shallow: no deepcopy
        if notices:
            values["notices"] = list(notices)
        self._write({"kind": "tick", **values})
        if record.t_s - self._last_sync_s >= FSYNC_INTERVAL_S:
            self._sync.request()
            self._last_sync_s = record.t_s

    def close(self) -> None:
        """Close the file (raises ``OSError`` when its last write fails; the file and its
        sync thread are released all the same)."""
        if not self._file.closed:
            try:
                self._file.close()
            finally:
                self._sync.close()

    def __enter__(self) -> FlightLogWriter:
        return self

    def __exit__(self, *_: object) -> None:
        self.close()


@dataclass(frozen=True)
class FlightLog:
    """A log read back as arrays (ticks along axis 0)."""

    path: Path
    header: dict[str, Any]
    t_s: FloatArray
    state: FloatArray  # (T, LOG_LAYOUT.n_states)
    state_ref: FloatArray  # (T, LOG_LAYOUT.n_states)
    inputs: FloatArray  # (T, LOG_LAYOUT.n_inputs)
    solve_ms: FloatArray
    compute_ms: FloatArray
    lateness_ms: FloatArray
    mocap_age_ms: FloatArray
    modes: list[str]
    controllers: list[str]
    plan_status: list[str]
    extra: list[dict[str, Any]]
    notices: list[tuple[float, str]]  # (t_s, "kind: text"), each when it was raised

    @property
    def controller(self) -> str:
        """The controller that flew, or the controllers in turn with when each took over,
        counted from the log's first tick ("decentralized, centralized after 45.1 s"), when
        it was switched in flight."""
        if not self.controllers:
            return "none"
        turns = [0] + [
            k
            for k in range(1, len(self.controllers))
            if self.controllers[k] != self.controllers[k - 1]
        ]
        return ", ".join(
            self.controllers[k] + (f" after {self.t_s[k] - self.t_s[0]:.1f} s" if k else "")
            for k in turns
        )


def _array(rows: list[Any], width: int | None = None) -> FloatArray:
    """Rows as floats; JSON nulls (non-finite values) come back as NaN."""
    array = np.array(rows, dtype=float)
    if width is not None and array.size == 0:
        array = array.reshape(0, width)
    return array


def read_flight_log(path: Path) -> FlightLog:
    """Read a log of either format, chosen by its extension; what a killed writer tore at
    the end (a last line, a last chunk) is skipped. Raises ``ValueError`` naming the file
    (and the line of JSON Lines) for a file that is not a flight log — empty, another
    format — or is broken anywhere else: a line that is no tick, an MCAP's changed bytes."""
    if path.suffix == ".mcap":
        return _read_mcap(path)
    return _read_jsonl(path)


def _flight_log(
    path: Path,
    header: dict[str, Any],
    ticks: list[dict[str, Any]],
    notices: list[tuple[float, str]],
) -> FlightLog:
    return FlightLog(
        path=path,
        header=header,
        t_s=_array([t["t_s"] for t in ticks]),
        state=_array([t["state"] for t in ticks], _WIDTHS["state"]),
        state_ref=_array([t["state_ref"] for t in ticks], _WIDTHS["state_ref"]),
        inputs=_array([t["inputs"] for t in ticks], _WIDTHS["inputs"]),
        solve_ms=_array([t["solve_ms"] for t in ticks]),
        compute_ms=_array([t["compute_ms"] for t in ticks]),
        lateness_ms=_array([t["lateness_ms"] for t in ticks]),
        mocap_age_ms=_array([t["mocap_age_ms"] for t in ticks]),
        modes=[t["mode"] for t in ticks],
        controllers=[t["controller"] for t in ticks],
        plan_status=[t["plan_status"] for t in ticks],
        extra=[t.get("extra", {}) for t in ticks],
        notices=notices,
    )


def _read_mcap(path: Path) -> FlightLog:
    from supervisor.logs.mcap_log import read_mcap_records

    recovered = read_mcap_records(path)
    assert recovered.header is not None
    ticks = [{name: getattr(r, name) for name in _TICK_FIELDS} for r in recovered.records]
    return _flight_log(path, recovered.header, ticks, recovered.notices)


_WIDTHS = {
    "state": LOG_LAYOUT.n_states,
    "state_ref": LOG_LAYOUT.n_states,
    "inputs": LOG_LAYOUT.n_inputs,
}
_NUMBERS = ("solve_ms", "compute_ms", "lateness_ms", "mocap_age_ms")
_NAMES = ("mode", "controller", "plan_status")


def _is_number(value: Any) -> bool:
    """A JSON number, or null (a non-finite value, as the writer writes it)."""
    return value is None or (isinstance(value, int | float) and not isinstance(value, bool))


def _tick_problem(entry: dict[str, Any]) -> str | None:
    """What keeps ``entry`` from being a tick the reader can take, or None."""
    if not isinstance(entry.get("t_s"), int | float) or isinstance(entry["t_s"], bool):
        return "no time t_s"
    for name in _NUMBERS:
        if not _is_number(entry.get(name, "")):
            return f"{name} is not a number"
    for name in _NAMES:
        if not isinstance(entry.get(name), str):
            return f"{name} is not a name"
    for name, width in _WIDTHS.items():
        values = entry.get(name)
        if not (isinstance(values, list) and len(values) == width):
            return f"{name} is not {width} numbers"
        if not all(_is_number(value) for value in values):
            return f"{name} holds something other than numbers"
    if not isinstance(entry.get("extra", {}), dict):
        return "extra is not an object"
    notices = entry.get("notices", [])
    if not (isinstance(notices, list) and all(isinstance(text, str) for text in notices)):
        return "notices are not texts"
    return None


def _read_jsonl(path: Path) -> FlightLog:
    data = path.read_bytes()
    if not data:
        raise ValueError(f"{path}: empty file, not a flight log")
    lines = data.split(b"\n")
    header: dict[str, Any] | None = None
    ticks: list[dict[str, Any]] = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            entry = json.loads(line.decode("utf-8"))
        except ValueError as error:  # JSON's and UTF-8's
            if number == len(lines):
                break  # a last line without its newline: the torn tail of a killed writer
            raise ValueError(f"{path}:{number}: not a flight-log line ({error})") from error
        if not isinstance(entry, dict):
            raise ValueError(f"{path}:{number}: not a flight-log line (not a JSON object)")
        if entry.get("kind") == "header" and header is None:
            header = entry
        elif entry.get("kind") == "tick":
            problem = _tick_problem(entry)
            if problem is not None:
                raise ValueError(f"{path}:{number}: not a tick line ({problem})")
            ticks.append(entry)
    if header is None:
        raise ValueError(f"{path}: no flight-log header: not a flight log")
    notices = [(t["t_s"], text) for t in ticks for text in t.get("notices", ())]
    return _flight_log(path, header, ticks, notices)
