"""MCAP flight logs: Foxglove's and our channels, read back whole, and what a killed writer
leaves (a real subprocess, SIGKILL) read up to its last complete chunk."""

from __future__ import annotations

import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from datetime import UTC, datetime
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
from mcap.reader import make_reader

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from supervisor.cli.main import main
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import open_flight_log, read_flight_log
from supervisor.logs.flight_messages import json_schemas, well_known
from supervisor.logs.mcap_log import McapFlightLogWriter, McapLibrary, read_mcap_records
from supervisor.logs.report import figures
from tests.conftest import NEVER_LATE

START = datetime(2026, 11, 23, 3, 15, 0, tzinfo=UTC)
ROOT = Path(__file__).resolve().parents[2]


def flight_records(params: FormationParams, ticks: int, seed: int = 0) -> list[TickRecord]:
    """Ticks of a payload swinging around its reference, a NaN-state tick among them."""
    reference = FormationReference((0.2, -0.1, 1.0), 0.3, (0.0,) * params.n_vehicles)
    ref = formation_equilibrium(params, reference).x
    rng = np.random.default_rng(seed)
    records = []
    for k in range(ticks):
        state = ref + rng.normal(0.0, 0.02, ref.size)
        if k == 3:
            state[:] = math.nan  # no estimate yet
        records.append(
            TickRecord(
                t_s=100.0 + 0.02 * k,
                mode="tracking" if k > 10 else "hover",
                controller="decentralized" if k < ticks // 2 else "centralized",
                state=state.tolist(),
                state_ref=ref.tolist(),
                inputs=(14.0 + rng.normal(0, 0.1, params.layout.n_inputs)).tolist(),
                plan_status="optimal" if k % 7 else "shifted",
                solve_ms=float(rng.uniform(0.1, 1.0)),
                compute_ms=0.7,
                lateness_ms=math.nan if k == 5 else 0.01,
                mocap_age_ms=3.0,
                extra={"latency_ms": 2.5, "skipped": k % 2, "mpc_prepared": True},
            )
        )
    return records


def _same(a: TickRecord, b: TickRecord) -> bool:
    arrays = ("state", "state_ref", "inputs")
    scalars = ("t_s", "solve_ms", "compute_ms", "lateness_ms", "mocap_age_ms")
    return (
        all(np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in arrays)
        and all(np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True) for f in scalars)
        and (a.mode, a.controller, a.plan_status, a.extra)
        == (b.mode, b.controller, b.plan_status, b.extra)
    )


@pytest.mark.parametrize("library", ["foxglove", "mcap"])
def test_every_record_comes_back_with_its_notices(
    tmp_path: Path, lab_params: FormationParams, library: McapLibrary
) -> None:
    records = flight_records(lab_params, 120)
    header = {"setup": "test", "arms_m": list(lab_params.bar_arms_m)}
    with McapFlightLogWriter(tmp_path / "f.mcap", header, START, library) as log:
        for k, record in enumerate(records):
            log.append(record, ("safety: a notice",) if k == 40 else ())
    recovered = read_mcap_records(tmp_path / "f.mcap")
    assert recovered.complete
    assert recovered.header == {"started": START.isoformat(), **header}
    assert len(recovered.records) == len(records)
    assert all(_same(a, b) for a, b in zip(recovered.records, records, strict=True))
    assert recovered.notices == [(records[40].t_s, "safety: a notice")]


@pytest.mark.parametrize("library", ["foxglove", "mcap"])
def test_the_mcap_reader_lists_the_channels_and_their_schemas(
    tmp_path: Path, lab_params: FormationParams, library: McapLibrary
) -> None:
    records = flight_records(lab_params, 60)
    with McapFlightLogWriter(
        tmp_path / "f.mcap", {"arms_m": list(lab_params.bar_arms_m)}, START, library
    ) as log:
        for k, record in enumerate(records):  # a channel is written with its first message
            log.append(record, ("mode: a notice",) if k == 10 else ())
    with (tmp_path / "f.mcap").open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == set(json_schemas(lab_params.layout)) | set(
            well_known(lab_params.layout)
        )
        for topic, (name, schema) in json_schemas(lab_params.layout).items():
            channel = channels[topic]
            assert channel.message_encoding == "json"
            assert summary.schemas[channel.schema_id].name == name
            assert summary.schemas[channel.schema_id].encoding == "jsonschema"
            assert json.loads(summary.schemas[channel.schema_id].data) == schema
        for topic, kind in well_known(lab_params.layout).items():
            written = summary.schemas[channels[topic].schema_id]
            assert (written.name, written.encoding) == (kind.get_schema().name, "protobuf")
        counts = summary.statistics.channel_message_counts
        assert counts[channels["/uavbar/state"].id] == 60
        assert counts[channels["/tf"].id] == 59  # not the tick without an estimate
        first = next(m for _, c, m in reader.iter_messages(topics=["/uavbar/state"]))
        assert first.log_time == int(START.timestamp() * 1e9)
        assert json.loads(first.data)["bar"]["position_m"]["x"] == records[0].state[0]


def test_a_chunk_is_finished_each_second(tmp_path: Path, lab_params: FormationParams) -> None:
    with McapFlightLogWriter(tmp_path / "f.mcap", {}, START) as log:
        for record in flight_records(lab_params, 270):  # 5.4 s
            log.append(record)
        # Before close: what the OS has holds all but the last second, in complete chunks.
        assert 270 - 50 <= len(read_mcap_records(tmp_path / "f.mcap").records) < 270
    with (tmp_path / "f.mcap").open("rb") as handle:
        summary = make_reader(handle).get_summary()
    assert summary is not None and len(summary.chunk_indexes) == 6
    spans_s = [(c.message_end_time - c.message_start_time) / 1e9 for c in summary.chunk_indexes]
    assert max(spans_s) <= 1.0 + 1e-6


def test_a_torn_file_gives_every_complete_chunk(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    records = flight_records(lab_params, 200)
    path = tmp_path / "f.mcap"
    with McapFlightLogWriter(path, {}, START) as log:
        for record in records:
            log.append(record)
    whole = path.read_bytes()
    torn = tmp_path / "torn.mcap"
    counts = []
    for cut in range(200, len(whole), len(whole) // 37):
        torn.write_bytes(whole[:cut])
        recovered = read_mcap_records(torn)
        assert not recovered.complete
        assert all(_same(a, b) for a, b in zip(recovered.records, records, strict=False))
        assert len(recovered.records) % 50 in (0, 1) or len(recovered.records) == 200
        counts.append(len(recovered.records))
    assert counts == sorted(counts) and counts[-1] >= 150


def test_not_a_flight_log_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "x.mcap"
    path.write_bytes(b"not an mcap file at all")
    with pytest.raises(ValueError, match="not an MCAP file"):
        read_flight_log(path)
    with pytest.raises(ValueError, match=r"\.jsonl or \.mcap"):
        open_flight_log(tmp_path / "x.csv", {})


WRITER = """
import sys, time
from pathlib import Path
from controllers.formation_params import FormationParams
from supervisor.app.config import load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.logs.flight_log import open_flight_log
from tests.supervisor.test_mcap_log import flight_records

params = load_config(DEFAULT_SETUP).system.to_params()
records = flight_records(params, 1000)  # 20 s, more than the test waits
log = open_flight_log(Path(sys.argv[1]), {"arms_m": list(params.bar_arms_m)})
for record in records:
    log.append(record)
    print(record.t_s, flush=True)  # written: what the killer knows
    time.sleep(0.02)
"""


@pytest.mark.parametrize("suffix", [".mcap", ".jsonl"])
def test_a_writer_killed_with_sigkill_loses_at_most_the_last_second(
    tmp_path: Path, lab_params: FormationParams, suffix: str
) -> None:
    path = tmp_path / f"killed{suffix}"
    with subprocess.Popen(
        [sys.executable, "-c", WRITER, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        cwd=ROOT,
    ) as writer:
        assert writer.stdout is not None
        first_s = last_s = float(writer.stdout.readline())
        deadline = time.monotonic() + 15.0
        while last_s - first_s < 3.3 and time.monotonic() < deadline:  # mid-chunk
            last_s = float(writer.stdout.readline())
        writer.send_signal(signal.SIGKILL)
    assert last_s - first_s >= 3.3
    log = read_flight_log(path)
    assert log.t_s[-1] >= last_s - 1.0 - 1e-9
    expected = flight_records(lab_params, len(log.t_s))
    assert np.array_equal(log.state, np.array([r.state for r in expected]), equal_nan=True)
    assert main(["report", str(path), "--out", str(tmp_path / "report")]) == 0


def test_report_gives_the_same_table_for_both_formats(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    records = flight_records(lab_params, 300)
    for suffix in (".jsonl", ".mcap"):
        log = open_flight_log(tmp_path / f"f{suffix}", {"setup": "same"}, started=START)
        for record in records:
            log.append(record)
        log.close()
        assert main(["report", str(log.path), "--out", str(tmp_path / suffix[1:])]) == 0
    # The same but for the file each report names (its summary rows, its figures' legends).
    jsonl, mcap = (
        json.loads((tmp_path / f / "summary.json").read_text()) for f in ("jsonl", "mcap")
    )
    assert [s.pop("log") for s in jsonl] == [str(tmp_path / "f.jsonl")]
    assert [s.pop("log") for s in mcap] == [str(tmp_path / "f.mcap")]
    assert jsonl == mcap
    table = (tmp_path / "jsonl" / "summary.md").read_text().replace("| f.jsonl |", "| f.mcap |")
    assert table == (tmp_path / "mcap" / "summary.md").read_text()
    drawn = [figures([read_flight_log(tmp_path / f"f{suffix}")]) for suffix in (".jsonl", ".mcap")]
    for stem, fig in drawn[0].items():
        for a, b in zip(fig.axes, drawn[1][stem].axes, strict=True):
            for line_a, line_b in zip(a.get_lines(), b.get_lines(), strict=True):
                assert np.array_equal(line_a.get_xydata(), line_b.get_xydata(), equal_nan=True)
    plt.close("all")


def test_csv_export_has_a_named_column_per_figure(
    tmp_path: Path, lab_params: FormationParams, capsys: pytest.CaptureFixture[str]
) -> None:
    records = flight_records(lab_params, 20)
    with McapFlightLogWriter(tmp_path / "f.mcap", {}, START) as log:
        for record in records:
            log.append(record)
    assert main(["csv", str(tmp_path / "f.mcap")]) == 0
    assert "f.csv: 20 ticks" in capsys.readouterr().out
    with (tmp_path / "f.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 20
    row = rows[7]
    assert float(row["t_s"]) == records[7].t_s
    assert float(row["state.bar.position_m.x"]) == records[7].state[0]
    assert float(row["state.uav2.euler_rad.yaw"]) == records[7].state[32]
    assert float(row["reference.uav1.position_m.z"]) == records[7].state_ref[14]
    assert float(row["inputs.uav2.torque_nm.z"]) == records[7].inputs[7]
    assert (row["mode"], row["controller"]) == ("hover", "decentralized")
    assert rows[3]["state.bar.position_m.x"] == ""  # not finite: an empty cell
    assert main(["csv", str(tmp_path / "absent.mcap")]) == 2


@pytest.mark.slow
def test_simulate_writes_an_mcap_log_with_the_same_flight_as_json_lines(tmp_path: Path) -> None:
    never_late = ["--set", NEVER_LATE]
    for suffix in (".mcap", ".jsonl"):
        command = ["simulate", "--scenario", "takeoff-land", "--seed", "3", "--json", *never_late]
        assert main([*command, "--log", str(tmp_path / f"f{suffix}")]) == 0
    mcap_log, jsonl_log = (read_flight_log(tmp_path / f"f{s}") for s in (".mcap", ".jsonl"))
    assert len(mcap_log.t_s) > 500
    for name in ("t_s", "state", "state_ref", "inputs", "mocap_age_ms"):
        assert np.array_equal(getattr(mcap_log, name), getattr(jsonl_log, name), equal_nan=True)
    assert (mcap_log.modes, mcap_log.notices) == (jsonl_log.modes, jsonl_log.notices)
    assert mcap_log.header["arms_m"] == jsonl_log.header["arms_m"]
    assert main(["simulate", "--scenario", "takeoff-land", "--log", str(tmp_path / "f.txt")]) == 2
