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

import contextlib
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, fields
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal, Protocol

import numpy as np
import pydantic_core

from controllers.formation_params import BAR_TOLERANCE_M, FormationParams, Vector3
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.background_sync import BackgroundSync

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
    with contextlib.suppress(ValueError):  # not the paper's bar: it has no arms
        header["arms_m"] = list(params.bar_arms_m)
    return header


def _real(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def _point_m(value: Any) -> Vector3:
    if not (isinstance(value, list) and len(value) == 3 and all(_real(v) for v in value)):
        raise ValueError(f"the header's attachments_m holds {value!r}, not a point [x, y, z]")
    return float(value[0]), float(value[1]), float(value[2])


def logged_attachments_m(header: dict[str, Any]) -> tuple[Vector3, ...] | None:
    """Each cable's attachment in the payload's frame [m] as ``header`` gives them (cable
    1's first): its ``attachments_m``, or an older log's bar arms ``arms_m`` (d1, d2) as
    (−d1, 0, 0), (d2, 0, 0); None when it gives neither. Raises ``ValueError`` when they
    are not what ``formation_header`` writes, or not for 2 to 8 UAVs."""
    if "attachments_m" in header:
        points = header["attachments_m"]
        if not isinstance(points, list):
            raise ValueError(f"the header's attachments_m is {points!r}, not a list of points")
        attachments = tuple(_point_m(point) for point in points)
    elif "arms_m" in header:
        arms = header["arms_m"]
        if not (isinstance(arms, list) and len(arms) == 2 and all(_real(v) for v in arms)):
            raise ValueError(f"the header's arms_m is {arms!r}, not the bar's arms [d1, d2]")
        attachments = ((-float(arms[0]), 0.0, 0.0), (float(arms[1]), 0.0, 0.0))
    else:
        return None
    FormationLayout(len(attachments))  # 2 to 8, or ValueError
    return attachments


def logged_layout(attachments_m: Sequence[Vector3] | None) -> FormationLayout:
    """The state layout of a log whose header gives ``attachments_m``
    (``logged_attachments_m``): one UAV per attachment; without any, the paper's two."""
    return FormationLayout(len(attachments_m) if attachments_m else 2)


def is_bar(attachments_m: Sequence[Vector3]) -> bool:
    """Whether the attachments lie on one line through the payload's CoM, to
    ``BAR_TOLERANCE_M``: ``PayloadParams.is_bar``'s test, on a log's attachments."""
    points = np.array(attachments_m, dtype=float)
    farthest = points[np.argmax(np.linalg.norm(points, axis=1))]
    off_line_m = np.linalg.norm(np.cross(points, farthest), axis=1) / np.linalg.norm(farthest)
    return bool(off_line_m.max() <= BAR_TOLERANCE_M)


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
    """A log read back as arrays (ticks along axis 0), laid out as ``layout`` (the
    formation its header names: ``logged_attachments_m``, ``logged_layout``)."""

    path: Path
    header: dict[str, Any]
    layout: FormationLayout
    attachments_m: tuple[Vector3, ...] | None  # None: an older log without (the paper's bar)
    t_s: FloatArray
    state: FloatArray  # (T, layout.n_states)
    state_ref: FloatArray  # (T, layout.n_states)
    inputs: FloatArray  # (T, layout.n_inputs)
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

    @property
    def payload_is_bar(self) -> bool:
        """Whether the payload is a bar (``is_bar``); an older log's is the paper's."""
        return self.attachments_m is None or is_bar(self.attachments_m)


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


def _formation(
    path: Path, header: dict[str, Any]
) -> tuple[FormationLayout, tuple[Vector3, ...] | None]:
    """The layout and the attachments ``header`` names; ``ValueError`` naming ``path``."""
    try:
        attachments_m = logged_attachments_m(header)
    except ValueError as error:
        raise ValueError(f"{path}: not a flight-log header ({error})") from error
    return logged_layout(attachments_m), attachments_m


def _widths(layout: FormationLayout) -> dict[str, int]:
    """How many numbers each of a tick's vectors holds."""
    return {"state": layout.n_states, "state_ref": layout.n_states, "inputs": layout.n_inputs}


def _flight_log(
    path: Path,
    header: dict[str, Any],
    ticks: list[dict[str, Any]],
    notices: list[tuple[float, str]],
) -> FlightLog:
    layout, attachments_m = _formation(path, header)
    widths = _widths(layout)
    return FlightLog(
        path=path,
        header=header,
        layout=layout,
        attachments_m=attachments_m,
        t_s=_array([t["t_s"] for t in ticks]),
        state=_array([t["state"] for t in ticks], widths["state"]),
        state_ref=_array([t["state_ref"] for t in ticks], widths["state_ref"]),
        inputs=_array([t["inputs"] for t in ticks], widths["inputs"]),
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


_NUMBERS = ("solve_ms", "compute_ms", "lateness_ms", "mocap_age_ms")
_NAMES = ("mode", "controller", "plan_status")


def _is_number(value: Any) -> bool:
    """A JSON number, or null (a non-finite value, as the writer writes it)."""
    return value is None or _real(value)


def _tick_problem(entry: dict[str, Any], widths: dict[str, int]) -> str | None:
    """What keeps ``entry`` from being a tick the reader can take (its vectors ``widths``
    long), or None."""
    if not _real(entry.get("t_s")):
        return "no time t_s"
    for name in _NUMBERS:
        if not _is_number(entry.get(name, "")):
            return f"{name} is not a number"
    for name in _NAMES:
        if not isinstance(entry.get(name), str):
            return f"{name} is not a name"
    for name, width in widths.items():
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
    widths: dict[str, int] = {}
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
            widths = _widths(_formation(path, header)[0])
        elif entry.get("kind") == "tick":
            if header is None:
                raise ValueError(f"{path}:{number}: a tick before the flight-log header")
            problem = _tick_problem(entry, widths)
            if problem is not None:
                raise ValueError(f"{path}:{number}: not a tick line ({problem})")
            ticks.append(entry)
    if header is None:
        raise ValueError(f"{path}: no flight-log header: not a flight log")
    notices = [(t["t_s"], text) for t in ticks for text in t.get("notices", ())]
    return _flight_log(path, header, ticks, notices)
