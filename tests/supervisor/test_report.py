"""The report's figures, read as a person reads them: a legend and data on every panel,
angles without ±180° stripes, UAV 2's errors, both logs on every error panel."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from supervisor.flight.tick_record import TickRecord
from supervisor.logs.flight_log import FlightLog, open_flight_log, read_flight_log
from supervisor.logs.report import figures


def turning_flight(folder: Path, params: FormationParams, controller: str) -> FlightLog:
    """UAV 1's yaw turning through ±180° (wrapped, as the estimate gives it), noisy inputs."""
    rng = np.random.default_rng(1)
    path = folder / f"{controller}.mcap"
    log = open_flight_log(path, {"setup": "test"})
    for k in range(400):
        t = 0.02 * k
        ref = formation_equilibrium(params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
        ref[20] = math.remainder(math.radians(150.0 + 10.0 * t), 2 * math.pi)
        state = ref + rng.normal(0.0, 0.005, ref.size)
        state[20] = math.remainder(state[20], 2 * math.pi)
        inputs = 13.0 + rng.normal(0.0, 0.3, params.layout.n_inputs)
        log.append(
            TickRecord(
                t,
                "tracking",
                controller,
                state.tolist(),
                ref.tolist(),
                inputs.tolist(),
                "optimal",
                0.3,
                0.5,
                0.0,
                3.0,
            )
        )
    log.close()
    return read_flight_log(path)


def test_every_panel_has_data_and_a_legend(tmp_path: Path, lab_params: FormationParams) -> None:
    logs = [turning_flight(tmp_path, lab_params, c) for c in ("centralized", "decentralized")]
    for stem, fig in figures(logs).items():
        panels = [ax for ax in fig.axes if ax.axison]
        assert panels, stem
        for ax in panels:
            title = ax.get_title()
            assert ax.get_legend() is not None, f"{stem}: {title} has no legend"
            drawn = [np.asarray(line.get_ydata(), float) for line in ax.get_lines()]
            assert any(np.isfinite(y).any() for y in drawn), f"{stem}: {title} is empty"
        plt.close(fig)


def test_angles_are_unwrapped_and_the_bar_has_no_roll_panel(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    fig = figures([turning_flight(tmp_path, lab_params, "centralized")])["orientations"]
    titles = {ax.get_title(): ax for ax in fig.axes if ax.axison}
    assert "bar roll" not in titles and "bar yaw" in titles
    yaw, reference = (np.asarray(line.get_ydata()) for line in titles["UAV 1 yaw"].get_lines())
    assert np.max(np.abs(np.diff(yaw))) < 5.0  # degrees per tick: no 360° jump
    assert yaw[-1] - yaw[0] > 70.0  # 150° → 230°, through 180°
    assert np.max(np.abs(yaw - reference)) < 5.0
    plt.close(fig)


def test_errors_of_both_uavs_and_both_logs_share_their_panels(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    logs = [turning_flight(tmp_path, lab_params, c) for c in ("centralized", "decentralized")]
    fig = figures(logs)["errors"]
    panels = {ax.get_title(): ax for ax in fig.axes if ax.axison}
    for panel in ("bar position error x", "bar yaw error", "UAV 1 attitude error yaw"):
        assert [line.get_label() for line in panels[panel].get_lines()] == [
            "centralized.mcap",
            "decentralized.mcap",
        ]
    assert "UAV 2 position error z" in panels
    yaw_error = np.asarray(panels["UAV 1 attitude error yaw"].get_lines()[0].get_ydata())
    assert np.max(np.abs(yaw_error)) < 5.0  # wrapped: no ±360° where the yaw crosses 180°
    plt.close(fig)


def test_inputs_are_a_moving_mean_inside_the_raw_range(
    tmp_path: Path, lab_params: FormationParams
) -> None:
    log = turning_flight(tmp_path, lab_params, "centralized")
    fig = figures([log])["inputs"]
    thrust = next(ax for ax in fig.axes if ax.get_title() == "UAV 1 thrust F1")
    mean = np.asarray(thrust.get_lines()[0].get_ydata())
    assert np.std(mean) < 0.3 * np.std(log.inputs[:, 0])  # the chatter averaged out
    band = thrust.collections[0].get_paths()[0].vertices[:, 1]
    assert band.min() <= np.nanmin(log.inputs[:, 0]) + 1e-12
    assert band.max() >= np.nanmax(log.inputs[:, 0]) - 1e-12
    plt.close(fig)
