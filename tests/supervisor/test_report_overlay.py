"""Two flights in one report: on the same axes, each labelled by its file name, time from
each flight's start (a service's log counts on the machine's clock since it booted), the
legends inside the figure even after a controller switch, and a summary row per file."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest

from controllers.formation_params import FormationParams
from supervisor.logs.flight_log import FlightLog, open_flight_log, read_flight_log
from supervisor.logs.report import figures, log_names, write_report
from tests.supervisor.test_mcap_log import flight_records

BOOT_CLOCK_S = 6294.6  # where a service's log starts: the flight process's monotonic clock
TICKS = 250


def logged(path: Path, params: FormationParams, start_s: float) -> FlightLog:
    """A flight of ``TICKS`` ticks starting at ``start_s``, switched from decentralized to
    centralized half-way (``flight_records``), written by the project's writer."""
    records = flight_records(params, TICKS)
    log = open_flight_log(path, {"setup": "test"})
    for record in records:
        log.append(replace(record, t_s=start_s + record.t_s - records[0].t_s))
    log.close()
    return read_flight_log(path)


@pytest.fixture
def two_flights(tmp_path: Path, lab_params: FormationParams) -> list[FlightLog]:
    """A service's log (boot clock) and a simulated one (from 0.2 s)."""
    return [
        logged(tmp_path / "served.jsonl", lab_params, BOOT_CLOCK_S),
        logged(tmp_path / "simulated.mcap", lab_params, 0.2),
    ]


def test_both_flights_share_every_panel_on_time_from_their_start(
    two_flights: list[FlightLog],
) -> None:
    duration_s = 0.02 * (TICKS - 1)
    for stem, fig in figures(two_flights).items():
        panels = [ax for ax in fig.axes if ax.axison]
        assert panels, stem
        for ax in panels:
            drawn = {line.get_label(): line for line in ax.get_lines()}
            for name in ("served.jsonl", "simulated.mcap"):
                t_s = np.asarray(drawn[name].get_xdata(), float)
                assert t_s[0] == 0.0, (stem, ax.get_title(), name)
                assert t_s[-1] == pytest.approx(duration_s), (stem, ax.get_title(), name)
            legend = [text.get_text() for text in ax.get_legend().get_texts()]
            assert {"served.jsonl", "simulated.mcap"} <= set(legend), (stem, ax.get_title())
        plt.close(fig)


def test_legends_stay_inside_the_figure_after_a_controller_switch(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    logs = [
        logged(tmp_path / "flight-20261203-101500-decentralized-then-centralized.jsonl",
               lab_params, BOOT_CLOCK_S),
        logged(tmp_path / "flight-20261203-104400.mcap", lab_params, 0.2),
    ]  # fmt: skip
    for stem, fig in figures(logs).items():
        fig.canvas.draw()
        inside = fig.bbox
        title = fig.get_suptitle()
        assert "decentralized, centralized after 2.5 s" in title, stem
        for ax in fig.axes:
            legend = ax.get_legend()
            if legend is None:
                continue
            box = legend.get_window_extent()
            assert inside.x0 <= box.x0 and box.x1 <= inside.x1, (stem, ax.get_title())
            assert inside.y0 <= box.y0 and box.y1 <= inside.y1, (stem, ax.get_title())
        plt.close(fig)


def test_each_summary_row_names_its_file(two_flights: list[FlightLog], tmp_path: Path) -> None:
    out = tmp_path / "report"
    write_report(two_flights, out)
    rows = [line for line in (out / "summary.md").read_text().splitlines() if line[:2] == "| "]
    assert rows[0].startswith("| log | controller |")
    assert rows[1].startswith("| served.jsonl | decentralized, centralized after 2.5 s |")
    assert rows[2].startswith("| simulated.mcap | decentralized, centralized after 2.5 s |")
    summaries = json.loads((out / "summary.json").read_text())
    assert [s["log"] for s in summaries] == [str(log.path) for log in two_flights]


def test_logs_of_the_same_name_are_told_apart(tmp_path: Path, lab_params: FormationParams) -> None:
    for folder in ("monday", "tuesday"):
        (tmp_path / folder).mkdir()
    logs = [logged(tmp_path / f / "flight.mcap", lab_params, 0.0) for f in ("monday", "tuesday")]
    assert log_names(logs) == ["monday/flight.mcap", "tuesday/flight.mcap"]
    assert log_names([logs[0], logs[0]]) == ["monday/flight.mcap (1)", "monday/flight.mcap (2)"]
