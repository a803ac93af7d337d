"""Flight logs that are broken — bytes changed, a garbage line, empty, not a log at all —
are refused by ``report`` and ``mocap check`` in one line naming the file and what is
wrong, exit status 2; a log a killed writer tore at its end is still read. The logs are
real: a simulated flight's MCAP, and the same flight written as JSON Lines by the
project's writer."""

from __future__ import annotations

import contextlib
import io
import json
import subprocess
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mocap.client import FrameReceiver
from mocap.recording import read_recording, write_recording
from supervisor.app.assembly import body_names_from_config, fusion_from_config
from supervisor.app.config import load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.cli.main import main
from supervisor.flight.estimation import estimate_state
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import FlightLogWriter, mocap_recording_path, read_flight_log
from supervisor.logs.mcap_log import McapFlightLogWriter, McapLibrary, read_mcap_records

ROOT = Path(__file__).resolve().parents[2]


def cli(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """The command line's entry point with an operator's arguments, in this process (a
    fresh interpreter per call spent most of this module's time importing)."""
    argv = [str(arg) for arg in args]
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return subprocess.CompletedProcess(argv, status, out.getvalue(), err.getvalue())


def assert_refused_in_one_line(
    said: subprocess.CompletedProcess[str], path: Path, what: str
) -> None:
    assert said.returncode == 2, said
    assert said.stdout == "", said
    lines = said.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in said.stderr, said.stderr
    assert str(path) in lines[0] and what in lines[0], lines[0]


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A simulated take-off and landing, logged as MCAP by the simulator (~20 s of flight,
    about 20 chunks)."""
    path = tmp_path_factory.mktemp("flight") / "flight.mcap"
    said = cli("simulate", "--scenario", "takeoff-land", "--seed", "1", "--json", "--log", path)
    assert said.returncode == 0, said
    return path


@pytest.fixture(scope="module")
def flight_jsonl(flight: Path) -> Path:
    """The same flight as JSON Lines, written by the project's writer."""
    recovered = read_mcap_records(flight)
    assert recovered.header is not None
    path = flight.with_suffix(".jsonl")
    with FlightLogWriter(path, recovered.header) as log:
        for record in recovered.records:
            log.append(record)
    return path


def flipped(source: Path, out: Path, offset: int, count: int = 16) -> Path:
    """``source`` with ``count`` bytes inverted from ``offset``."""
    data = bytearray(source.read_bytes())
    for k in range(offset, offset + count):
        data[k] ^= 0xFF
    out.write_bytes(bytes(data))
    return out


def commands(log: Path, out: Path) -> list[list[str | Path]]:
    """Both commands that read a flight log, on ``log``."""
    return [["report", log, "--out", out], ["mocap", "check", log]]


@pytest.mark.parametrize("command", ["report", "mocap check"])
def test_an_mcap_with_bytes_changed_in_its_middle_is_refused_in_one_line(
    flight: Path, tmp_path: Path, command: str
) -> None:
    broken = flipped(flight, tmp_path / "broken.mcap", flight.stat().st_size // 2)
    [args] = [c for c in commands(broken, tmp_path / "report") if c[0] == command.split()[0]]
    assert_refused_in_one_line(cli(*args), broken, "corrupt at byte")
    assert not (tmp_path / "report").exists()


@pytest.mark.parametrize("library", ["foxglove", "mcap"])
def test_no_changed_byte_goes_unnoticed(flight: Path, tmp_path: Path, library: McapLibrary) -> None:
    """One byte changed anywhere in the file (data, indexes, summary, footer): refused,
    naming the file, or — where a writer keeps no CRC over bytes the reader does not use —
    read as the very same flight."""
    recovered = read_mcap_records(flight)
    source = tmp_path / f"{library}.mcap"
    with McapFlightLogWriter(source, recovered.header or {}, library=library) as log:
        for record in recovered.records[:150]:
            log.append(record)
    whole = read_mcap_records(source)
    size = source.stat().st_size
    unnoticed = 0
    for offset in range(8, size, size // 150):
        broken = flipped(source, tmp_path / "broken.mcap", offset, count=1)
        try:
            again = read_mcap_records(broken)
        except ValueError as error:
            assert str(broken) in str(error)
            continue
        assert again.header == whole.header and repr(again.records) == repr(whole.records)
        unnoticed += 1
    if library == "foxglove":  # CRCs over the data section and the summary
        assert unnoticed == 0


def test_a_torn_log_is_read_but_a_change_before_the_tear_is_not(
    flight: Path, tmp_path: Path
) -> None:
    """A killed writer leaves the last record cut: everything before it is read. A byte
    changed before the tear is not taken for one."""
    whole = flight.read_bytes()
    torn = tmp_path / "torn.mcap"
    torn.write_bytes(whole[: len(whole) // 2])
    records = read_mcap_records(torn).records
    assert 0 < len(records) < len(read_mcap_records(flight).records)
    broken = flipped(torn, tmp_path / "torn-broken.mcap", len(whole) // 5)
    with pytest.raises(ValueError, match="corrupt at byte"):
        read_mcap_records(broken)
    assert cli("report", torn, "--out", tmp_path / "report").returncode == 0


def jsonl_with(source: Path, out: Path, line: bytes) -> Path:
    """``source`` with ``line`` inserted in its middle."""
    lines = source.read_bytes().split(b"\n")
    middle = len(lines) // 2
    out.write_bytes(b"\n".join([*lines[:middle], line, *lines[middle:]]))
    return out


def a_tick_of(source: Path, without: str = "", **change: object) -> bytes:
    """The log's first tick, ``without`` a field, with the fields in ``change`` set."""
    tick = json.loads(source.read_bytes().split(b"\n")[1])
    tick.update(change)
    tick.pop(without, None)
    return json.dumps(tick).encode()


BROKEN_LINES: dict[str, tuple[Callable[[Path], bytes], str]] = {
    "garbage": (lambda _: b"\x00\x01 garbage {{{", "not a flight-log line (Expecting value"),
    "a list": (lambda _: b"[1, 2, 3]", "not a flight-log line (not a JSON object)"),
    "not UTF-8": (lambda source: a_tick_of(source).replace(b"mode", b"mo\xffde"), "'utf-8'"),
    "35 states": (lambda source: a_tick_of(source, state=[0.0] * 35), "state is not 36 numbers"),
    "no mode": (lambda source: a_tick_of(source, without="mode"), "mode is not a name"),
}


@pytest.mark.parametrize("broken_line", BROKEN_LINES)
def test_a_json_lines_log_with_a_broken_line_is_refused_naming_the_line(
    flight_jsonl: Path, tmp_path: Path, broken_line: str
) -> None:
    line, what = BROKEN_LINES[broken_line]
    broken = jsonl_with(flight_jsonl, tmp_path / "broken.jsonl", line(flight_jsonl))
    number = len(flight_jsonl.read_bytes().split(b"\n")) // 2 + 1
    with pytest.raises(ValueError, match="not a") as refused:
        read_flight_log(broken)
    assert str(refused.value).startswith(f"{broken}:{number}: ") and what in str(refused.value)


def test_broken_json_lines_are_refused_by_both_commands_in_one_line(
    flight_jsonl: Path, tmp_path: Path
) -> None:
    broken = jsonl_with(flight_jsonl, tmp_path / "broken.jsonl", b"garbage")
    for command in commands(broken, tmp_path / "report"):
        assert_refused_in_one_line(cli(*command), broken, "not a flight-log line")


PICTURE = b"\x89PNG\r\n\x1a\n" + bytes(range(256))
NOTES = b'{"note": "no flight here"}\n'


@pytest.mark.parametrize(
    ("name", "content", "what"),
    [
        pytest.param("empty.mcap", b"", "empty file", id="empty mcap"),
        pytest.param("empty.jsonl", b"", "empty file", id="empty jsonl"),
        pytest.param("picture.mcap", PICTURE, "not an MCAP file", id="a PNG as mcap"),
        pytest.param("picture.jsonl", PICTURE, "not a flight-log line", id="a PNG as jsonl"),
        pytest.param("notes.jsonl", NOTES, "no flight-log header", id="other JSON Lines"),
    ],
)
def test_what_is_no_flight_log_is_refused_in_one_line(
    tmp_path: Path, name: str, content: bytes, what: str
) -> None:
    path = tmp_path / name
    path.write_bytes(content)
    for command in commands(path, tmp_path / "report"):
        assert_refused_in_one_line(cli(*command), path, what)


def test_a_log_without_a_tick_gives_no_report(flight_jsonl: Path, tmp_path: Path) -> None:
    header_only = tmp_path / "header-only.jsonl"
    header_only.write_bytes(flight_jsonl.read_bytes().split(b"\n")[0] + b"\n")
    said = cli("report", header_only, "--out", tmp_path / "report")
    assert_refused_in_one_line(said, header_only, "no tick")


# ---- a flight's own mocap recording (mocap check) -------------------------------------------
DATA = ROOT / "tests" / "data"
TICK_S = 0.02


def flown_with_its_recording(folder: Path) -> Path:
    """A flight log and its mocap recording beside it, as the flight process leaves them:
    the shipped recording of the simulator's stream received datagram by datagram, the
    estimate at every 20 ms tick logged, and the receiver's and the fusion's state when
    the recording began in the log's header."""
    config = load_config(DEFAULT_SETUP)
    stream = read_recording(DATA / "hover-dropout.qtm.gz")
    receiver = FrameReceiver(stream.body_names, stream.component)
    fusion, names = fusion_from_config(config), body_names_from_config(config)
    first, *later = stream.packets
    receiver.receive_datagram(first.data, stream.clock_start_s + first.arrival_s)
    for frame in receiver.drain():
        fusion.update(frame)
    path = folder / "flight-20261204-120000.jsonl"
    write_recording(replace(stream, packets=tuple(later)), mocap_recording_path(path))
    header = {
        "setup": config.name,
        "mocap_recording": {
            "file": mocap_recording_path(path).name,
            "receiver": receiver.sequence(),
            "fusion": fusion.snapshot(),
        },
    }
    received_s = [stream.clock_start_s + p.arrival_s for p in later]
    with FlightLogWriter(path, header) as log:
        t_s, pending = received_s[0], 0
        while t_s < received_s[-1] + 0.2:
            while pending < len(later) and received_s[pending] <= t_s:
                receiver.receive_datagram(later[pending].data, received_s[pending])
                pending += 1
            for frame in receiver.drain():
                fusion.update(frame)
            estimate = estimate_state(fusion.states(t_s), names)
            state = estimate.x.tolist()
            log.append(
                TickRecord(t_s, "hover", "centralized", state, state, [0.0] * 8, "optimal",
                           0.0, 0.0, 0.0, estimate.age_s * 1e3, {"repeats_refused": False})
            )  # fmt: skip
            t_s += TICK_S
    return path


@pytest.fixture(scope="module")
def flown(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return flown_with_its_recording(tmp_path_factory.mktemp("flown"))


def test_a_flight_and_its_recording_check_the_same(flown: Path) -> None:
    said = cli("mocap", "check", flown)
    assert said.returncode == 0 and "the same as logged" in said.stdout, said
    assert said.stderr == ""


def test_a_truncated_recording_is_checked_up_to_its_end_and_said_to_be(
    flown: Path, tmp_path: Path
) -> None:
    """A recording cut short (its flight process killed): the ticks before its last packet
    are compared — after it, the flight fused packets the file lost — and the operator is
    told the file is truncated, with what it holds."""
    log = tmp_path / flown.name
    log.write_bytes(flown.read_bytes())
    whole = mocap_recording_path(flown).read_bytes()
    mocap_recording_path(log).write_bytes(whole[: len(whole) * 3 // 5])
    cut = read_recording(mocap_recording_path(log))
    end_s = cut.clock_start_s + cut.packets[-1].arrival_s
    t_s = read_flight_log(log).t_s
    covered = int(np.sum(t_s < end_s))
    assert 0 < covered < len(t_s) - 100

    said = cli("mocap", "check", log)

    assert said.returncode == 0, said
    [warning] = said.stderr.splitlines()
    assert str(mocap_recording_path(log)) in warning and "truncated" in warning
    assert f"it holds {cut.frame_count} frames over {cut.duration_s:.2f} s" in warning
    assert f"{covered} of {len(t_s)} ticks" in said.stdout
    assert "the same as logged" in said.stdout


def test_a_recording_corrupted_in_its_middle_is_refused_in_one_line(
    flown: Path, tmp_path: Path
) -> None:
    log = tmp_path / flown.name
    log.write_bytes(flown.read_bytes())
    recording = mocap_recording_path(flown)
    broken = flipped(recording, mocap_recording_path(log), recording.stat().st_size // 2)
    assert_refused_in_one_line(cli("mocap", "check", log), broken, "corrupt")
