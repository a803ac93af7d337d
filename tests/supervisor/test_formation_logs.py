"""Flight logs of N UAVs: the header's attachments say how many, the readers take states of
that width only, and every channel, column, figure and the Foxglove scene names UAV 1 … N."""

from __future__ import annotations

import asyncio
import csv
import json
import math
from itertools import pairwise
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pytest
import websockets
from mcap.reader import make_reader

from controllers.formation_params import FormationParams
from geometry.frames import rotation_from_euler_zyx
from geometry.state import TH_B
from mocap.recording import read_recording
from supervisor.app.assembly import body_names_from_config, fusion_from_config
from supervisor.app.config import CONFIG_DIR, load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.cli.main import main
from supervisor.logs.csv_export import write_csv
from supervisor.logs.flight_log import (
    FlightLog,
    formation_header,
    open_flight_log,
    read_flight_log,
)
from supervisor.logs.flight_messages import SceneStyle, json_schemas, well_known
from supervisor.logs.foxglove_live import FoxgloveLiveView
from supervisor.logs.mocap_replay import replay_estimates
from supervisor.logs.report import figures, summarize, write_report
from supervisor.logs.view_seal import view_keys
from tests.supervisor.test_mcap_log import START, flight_records

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def tri_params() -> FormationParams:
    """configs/sim_tri.toml: three UAVs carrying a triangular plate by its corners."""
    return load_config(CONFIG_DIR / "sim_tri.toml").system.to_params()


def logged(path: Path, params: FormationParams, ticks: int = 60) -> FlightLog:
    """``flight_records`` of ``params``' formation written with the header the flight
    process and the simulator write (``formation_header``), read back."""
    log = open_flight_log(path, {"setup": "test", **formation_header(params)}, started=START)
    for record in flight_records(params, ticks):
        log.append(record)
    log.close()
    return read_flight_log(path)


@pytest.mark.parametrize("suffix", [".jsonl", ".mcap"])
def test_a_log_of_three_uavs_reads_back_48_states_and_12_inputs(
    tmp_path: Path, tri_params: FormationParams, suffix: str
) -> None:
    log = logged(tmp_path / f"f{suffix}", tri_params)
    records = flight_records(tri_params, 60)
    assert log.layout.n_vehicles == 3
    assert log.state.shape == log.state_ref.shape == (60, 48)
    assert log.inputs.shape == (60, 12)
    assert np.array_equal(log.state, np.array([r.state for r in records]), equal_nan=True)
    assert np.array_equal(log.inputs, np.array([r.inputs for r in records]))
    assert log.attachments_m == tri_params.payload.attachments_m
    assert not log.payload_is_bar
    assert "arms_m" not in log.header  # a plate has no bar arms


def test_a_header_of_the_paper_bar_keeps_its_arms_and_an_older_one_reads_as_two_uavs(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    assert formation_header(lab_params)["arms_m"] == [0.705, 0.765]
    older = open_flight_log(tmp_path / "older.jsonl", {"arms_m": [0.705, 0.765]})
    for record in flight_records(lab_params, 5):
        older.append(record)
    older.close()
    log = read_flight_log(older.path)
    assert log.layout.n_vehicles == 2 and log.state.shape == (5, 36)
    assert log.attachments_m == lab_params.payload.attachments_m
    assert log.payload_is_bar


def test_a_tick_of_two_uavs_in_a_log_of_three_is_refused(
    tmp_path: Path, tri_params: FormationParams, lab_params: FormationParams
) -> None:
    path = tmp_path / "mixed.jsonl"
    log = open_flight_log(path, formation_header(tri_params))
    log.append(flight_records(lab_params, 1)[0])
    log.close()
    with pytest.raises(ValueError, match=rf"{path}:2: not a tick line \(state is not 48 numbers"):
        read_flight_log(path)


@pytest.mark.parametrize(
    ("attachments", "what"),
    [
        ([[0.5, 0.0, 0.0]], "not 1"),  # one UAV: no formation
        ([[0.5, 0.0], [-0.5, 0.0]], "not a point"),
        ("a plate", "not a list of points"),
    ],
)
def test_a_header_whose_attachments_do_not_read_is_refused(
    tmp_path: Path, attachments: object, what: str
) -> None:
    path = tmp_path / "f.jsonl"
    path.write_text(json.dumps({"kind": "header", "attachments_m": attachments}) + "\n")
    with pytest.raises(ValueError, match="not a flight-log header") as refused:
        read_flight_log(path)
    assert str(refused.value).startswith(str(path)) and what in str(refused.value)


def test_the_mcap_channels_name_every_uav(tmp_path: Path, tri_params: FormationParams) -> None:
    layout = tri_params.layout
    assert {"/uav1/pose", "/uav2/pose", "/uav3/pose", "/bar/pose"} <= set(well_known(layout))
    assert "/uav4/pose" not in well_known(layout)
    inputs = json_schemas(layout)["/uavbar/inputs"][1]["properties"]
    assert set(inputs) == {"uav1", "uav2", "uav3"}
    state = json_schemas(layout)["/uavbar/state"][1]["properties"]
    assert set(state) == {"t_s", "bar", "uav1", "uav2", "uav3"}
    log = logged(tmp_path / "f.mcap", tri_params)
    with log.path.open("rb") as handle:
        reader = make_reader(handle)
        summary = reader.get_summary()
        assert summary is not None
        topics = {c.topic for c in summary.channels.values()}
        assert topics == set(json_schemas(layout)) - {"/uavbar/notices"} | set(well_known(layout))
        first = next(json.loads(m.data) for _, _, m in reader.iter_messages(["/uavbar/inputs"]))
    assert first["uav3"]["thrust_n"] == flight_records(tri_params, 1)[0].inputs[8]


def test_the_csv_has_the_columns_of_every_uav(tmp_path: Path, tri_params: FormationParams) -> None:
    log = logged(tmp_path / "f.mcap", tri_params, 20)
    assert write_csv(log, tmp_path / "f.csv") == 20
    with (tmp_path / "f.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    record = flight_records(tri_params, 20)[7]
    row = rows[7]
    assert float(row["inputs.uav3.thrust_n"]) == record.inputs[8]
    assert float(row["inputs.uav3.torque_nm.z"]) == record.inputs[11]
    assert float(row["state.uav3.position_m.z"]) == record.state[38]
    assert float(row["reference.uav3.euler_rad.yaw"]) == record.state_ref[44]
    assert not any(name.startswith(("state.uav4", "inputs.uav4")) for name in rows[0])


def test_the_scene_hangs_a_cable_from_each_uav_to_its_corner(tri_params: FormationParams) -> None:
    """At the equilibrium, each cable drawn runs from its UAV to its own corner and is as long
    as the setup's cable."""
    record = flight_records(tri_params, 1)[0]
    style = SceneStyle(tri_params.payload.attachments_m)
    cables = style.cables_m(record.state_ref)
    assert len(cables) == 3
    for i, (top, bottom) in enumerate(cables, start=1):
        np.testing.assert_array_equal(
            top, tri_params.layout.uav_position(np.array(record.state_ref), i)
        )
        length_m = float(np.linalg.norm(top - bottom))
        assert length_m == pytest.approx(tri_params.cable_lengths_m[i - 1], abs=1e-6)
    corners = style.outline_m(record.state_ref)
    assert len(corners) == 3
    for a, b in pairwise([*corners, corners[0]]):
        assert float(np.linalg.norm(a - b)) == pytest.approx(1.3, abs=0.01)  # a side


def test_a_plate_is_drawn_round_its_edge_whatever_its_cables_order() -> None:
    """A square's corners numbered across its diagonals are still drawn as the square."""
    crossed = ((0.6, 0.6, 0.0), (-0.6, -0.6, 0.0), (0.6, -0.6, 0.0), (-0.6, 0.6, 0.0))
    state = np.zeros(12 + 12 * 4)
    state[2] = 1.0
    corners = SceneStyle(crossed).outline_m(state.tolist())
    sides_m = [float(np.linalg.norm(a - b)) for a, b in pairwise([*corners, corners[0]])]
    assert sides_m == pytest.approx([1.2] * 4)


def test_the_report_draws_every_uav_and_the_plates_roll(
    tmp_path: Path, tri_params: FormationParams, lab_params: FormationParams
) -> None:
    log = logged(tmp_path / "tri.mcap", tri_params, 100)
    drawn = figures([log])
    titles = {stem: {ax.get_title() for ax in fig.axes if ax.axison} for stem, fig in drawn.items()}
    assert {"UAV 3 thrust F3", "UAV 3 torque τz"} <= titles["inputs"]
    assert {"payload x", "UAV 3 z"} <= titles["positions"]
    assert {"payload roll", "UAV 3 yaw"} <= titles["orientations"]
    assert {"UAV 3 position error z", "payload yaw error"} <= titles["errors"]
    thrust = next(ax for ax in drawn["inputs"].axes if ax.get_title() == "UAV 3 thrust F3")
    mean = np.asarray(thrust.get_lines()[0].get_ydata())
    assert np.nanmean(mean) == pytest.approx(np.mean(log.inputs[:, 8]), abs=0.05)
    plt.close("all")
    bar = logged(tmp_path / "bar.mcap", lab_params, 100)
    with pytest.raises(ValueError, match="one formation"):
        write_report([log, bar], tmp_path / "report")
    assert not (tmp_path / "report").exists()


def test_summarize_counts_the_uavs(tmp_path: Path, tri_params: FormationParams) -> None:
    summary = summarize(logged(tmp_path / "f.jsonl", tri_params, 100))
    assert summary["vehicles"] == 3 and summary["ticks"] == 100
    assert 0.0 < summary["bar_position_rms_m"] < 0.1  # the 2 cm wobble of flight_records


def test_summarize_gives_the_payloads_figures_for_any_setup(
    tmp_path: Path, tri_params: FormationParams
) -> None:
    log = logged(tmp_path / "f.jsonl", tri_params, 100)
    log.state[40, TH_B] = (0.3, -0.4, 1.0)  # a roll and a pitch: tilted 28.4 deg
    summary = summarize(log)
    assert summary["payload_position_rmse_m"] == summary["bar_position_rms_m"]
    assert summary["payload_yaw_rmse_deg"] == summary["bar_yaw_rms_deg"]
    normals = [rotation_from_euler_zyx(*x[TH_B])[:, 2] for x in log.state]
    tilts = [math.degrees(math.acos(float(n[2]))) for n in normals if np.all(np.isfinite(n))]
    assert summary["max_payload_tilt_deg"] == pytest.approx(max(tilts), abs=1e-9)
    assert summary["max_payload_tilt_deg"] == pytest.approx(28.4, abs=0.1)


def test_the_mocap_check_refuses_a_setup_of_another_number_of_uavs(
    tmp_path: Path, tri_params: FormationParams
) -> None:
    log = logged(tmp_path / "f.jsonl", tri_params, 5)
    config = load_config(DEFAULT_SETUP)  # two UAVs
    recording = read_recording(ROOT / "tests" / "data" / "hover-dropout.qtm.gz")
    with pytest.raises(ValueError, match="a flight of 3 UAVs, not the 2 of this setup"):
        replay_estimates(log, recording, fusion_from_config(config), body_names_from_config(config))


async def test_the_live_view_advertises_the_channels_of_its_formation(
    tri_params: FormationParams,
) -> None:
    layout = tri_params.layout
    expected = set(json_schemas(layout)) | set(well_known(layout))
    view = FoxgloveLiveView("127.0.0.1", 0, tri_params.payload.attachments_m, view_keys("t"))
    topics: set[str] = set()
    try:
        async with (
            websockets.connect(
                f"ws://127.0.0.1:{view.port}",
                subprotocols=[websockets.Subprotocol("foxglove.sdk.v1")],
            ) as socket,
            asyncio.timeout(10.0),
        ):
            while len(topics) < len(expected):
                message = await socket.recv()
                if isinstance(message, str) and json.loads(message)["op"] == "advertise":
                    topics |= {c["topic"] for c in json.loads(message)["channels"]}
    finally:
        view.close()
    assert topics == expected and "/uav3/pose" in topics


@pytest.mark.slow
@pytest.mark.parametrize(
    "setup, controller", [("sim_tri", "centralized"), ("sim_quad", "decentralized")]
)
def test_a_square_flown_by_n_uavs_gives_its_log_report_and_table(
    tmp_path: Path, setup: str, controller: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """The ``square`` scenario (take-off, four setpoints with a 90° yaw and a 30° cone,
    landing) on a plate and a frame: completed, no cable slack, the payload's figures in
    the JSON; its log reads back, reports and exports for N UAVs."""
    path = tmp_path / "flight.mcap"
    command = ["simulate", "--scenario", "square", "--config", setup, "--json"]
    assert main([*command, "--controller", controller, "--log", str(path)]) == 0
    summary = json.loads(capsys.readouterr().out)
    n = load_config(CONFIG_DIR / f"{setup}.toml").system.to_params().n_vehicles
    assert summary["completed"] and summary["messages"] == [], summary["messages"]
    assert summary["vehicles"] == n and summary["slack_events"] == 0
    assert summary["payload_position_rmse_m"] < 0.1  # measured 0.046-0.059
    assert summary["max_payload_tilt_deg"] < 5.0  # measured 0.8-1.3
    log = read_flight_log(path)
    assert log.state.shape[1] == 12 + 12 * n and log.inputs.shape[1] == 4 * n
    assert main(["report", str(path), "--out", str(tmp_path / "report")]) == 0
    assert main(["csv", str(path)]) == 0
    with path.with_suffix(".csv").open(newline="") as handle:
        assert f"inputs.uav{n}.thrust_n" in next(csv.reader(handle))
