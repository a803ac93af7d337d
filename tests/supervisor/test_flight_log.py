"""Flight logs survive a crash and turn into the paper's figures and Table III summary."""

from __future__ import annotations

import json
import math
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from geometry.formation import FormationLayout
from supervisor.cli.main import main
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import FlightLogWriter, read_flight_log
from supervisor.logs.report import summarize

START = datetime(2026, 11, 23, 3, 15, 0, tzinfo=UTC)
BAR = FormationLayout(2)  # a header without attachments: the paper's two UAVs and bar


def write_synthetic_flight(
    folder: Path, params: FormationParams, controller: str, wobble_m: float
) -> Path:
    """A bar oscillating in x around its reference: known mean and std of the x error."""
    ref = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    with FlightLogWriter(folder, {"setup": "test", "controller": controller}, START) as log:
        for k in range(500):
            t = 0.02 * k
            state = ref.copy()
            state[0] += 0.01 + wobble_m * math.sin(2 * math.pi * t)
            log.append(
                TickRecord(
                    t,
                    "tracking",
                    controller,
                    state.tolist(),
                    ref.tolist(),
                    [13.0, 0, 0, 0, 13.0, 0, 0, 0],
                    "optimal",
                    0.5,
                    0.7,
                    0.01,
                    3.0,
                )
            )
        return log.path


def test_round_trip_and_statistics(tmp_path: Path, lab_params: FormationParams) -> None:
    path = write_synthetic_flight(tmp_path, lab_params, "centralized", 0.05)
    assert path.name == "flight-20261123-031500.jsonl"
    log = read_flight_log(path)
    assert log.state.shape == (500, BAR.n_states)
    assert log.inputs.shape == (500, BAR.n_inputs)
    summary = summarize(log)
    x_error = 0.01 + 0.05 * np.sin(2 * np.pi * 0.02 * np.arange(500))
    assert summary["bar_x_error_mean_m"] == pytest.approx(x_error.mean(), abs=1e-12)
    assert summary["bar_x_error_std_m"] == pytest.approx(x_error.std(ddof=1), abs=1e-12)
    assert summary["bar_yaw_rms_deg"] == pytest.approx(0.0, abs=1e-9)
    assert summary["fallback_ticks"] == 0


def test_a_torn_last_line_is_skipped(tmp_path: Path, lab_params: FormationParams) -> None:
    path = write_synthetic_flight(tmp_path, lab_params, "centralized", 0.05)
    text = path.read_text()
    path.write_text(text[: len(text) - 40])  # the process died mid-line
    assert len(read_flight_log(path).t_s) == 499


def test_second_flight_in_the_same_second_gets_its_own_file(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    first = write_synthetic_flight(tmp_path, lab_params, "centralized", 0.0)
    second = write_synthetic_flight(tmp_path, lab_params, "decentralized", 0.0)
    assert first != second and first.exists() and second.exists()


def test_non_finite_values_are_logged_as_missing(tmp_path: Path) -> None:
    with FlightLogWriter(tmp_path, {}) as log:
        nan36 = [math.nan] * BAR.n_states
        log.append(
            TickRecord(
                0.0,
                "hover",
                "centralized",
                nan36,
                nan36,
                [math.inf] * BAR.n_inputs,
                "shifted_bad_state",
                0,
                0,
                0,
                math.nan,
            )
        )
    line = log.path.read_text().splitlines()[1]
    assert "NaN" not in line and "Infinity" not in line
    assert np.isnan(read_flight_log(log.path).state).all()


def test_report_command_overlays_two_logs(
    tmp_path: Path, lab_params: FormationParams, capsys: pytest.CaptureFixture[str]
) -> None:
    a = write_synthetic_flight(tmp_path / "a", lab_params, "centralized", 0.02)
    b = write_synthetic_flight(tmp_path / "b", lab_params, "decentralized", 0.10)
    out = tmp_path / "report"
    assert main(["report", str(a), str(b), "--out", str(out)]) == 0
    for name in (
        "positions.png",
        "orientations.png",
        "inputs.png",
        "errors.png",
        "summary.md",
        "summary.json",
    ):
        assert (out / name).stat().st_size > 0
    summaries = json.loads((out / "summary.json").read_text())
    assert [s["controller"] for s in summaries] == ["centralized", "decentralized"]
    assert summaries[0]["bar_x_error_std_m"] < summaries[1]["bar_x_error_std_m"]
    assert "Table III" in (out / "summary.md").read_text()
    assert (out / "errors.png").read_bytes()[:4] == b"\x89PNG"


def test_report_of_a_missing_log_fails_cleanly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["report", str(tmp_path / "absent.jsonl"), "--out", str(tmp_path)]) == 2
    assert "absent.jsonl" in capsys.readouterr().err


def test_a_log_can_be_written_to_a_named_file(tmp_path: Path) -> None:
    path = tmp_path / "runs" / "mine.jsonl"
    for _ in range(2):  # a named file is replaced, not appended to
        with FlightLogWriter(path, {"setup": "named"}) as log:
            log.append(
                TickRecord(
                    0.0,
                    "hover",
                    "centralized",
                    [0.0] * BAR.n_states,
                    [0.0] * BAR.n_states,
                    [0.0] * BAR.n_inputs,
                    "optimal",
                    1.0,
                    1.0,
                    0.0,
                    5.0,
                )
            )
        assert log.path == path
    assert len(read_flight_log(path).t_s) == 1
