"""Flight reports: the paper's Figs 6–8 and a Table III-style summary from flight logs.

``write_report([log], out)`` writes ``positions.png``, ``orientations.png`` (Fig. 6),
``inputs.png`` (Fig. 7), ``errors.png`` (Fig. 8) and ``summary.md`` / ``summary.json``.
The figures have a column (inputs), or a column or a row of panels (the others), for the
payload and for each of the log's N UAVs (UAV 1 … UAV N); the payload is "bar" when it is
one (the paper's, or any whose attachments lie on a line through its CoM), else "payload".
Time is in seconds from each log's first tick (the flight's start: a service's log counts
its ticks on the machine's clock, since it booted). With two logs (e.g. centralized and
decentralized) both are drawn on the same axes of every panel, the first solid and the
second dashed, each in its colour and labelled by its file name; the figure's title says
which controller flew each. References are dotted black; angles are unwrapped in Fig. 6 and
errors wrapped to ±180° in Fig. 8, one panel per component; inputs are a moving mean with
the raw range shaded (the MPC's tick-to-tick input chatter otherwise fills the panel).
Every panel has its legend, inside the panel.
"""

from __future__ import annotations

import json
import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Patch

from controllers.mpc import PlanStatus
from geometry.formation import FormationLayout
from geometry.state import P_B, PAYLOAD_YAW, TH_B
from supervisor.logs.flight_log import FlightLog

AXES = ("x", "y", "z")
ANGLES = ("roll", "pitch", "yaw")
# A bar's attitude is its pitch and yaw: it cannot roll about its own axis in the model
# (its attachments depend on θ_b and ψ_b only), so its roll is not drawn.
BAR_ANGLES = ("pitch", "yaw")


@dataclass(frozen=True)
class Formation:
    """What the figures draw: the bodies of the logs' formation (every log's the same)."""

    layout: FormationLayout
    payload_is_bar: bool

    @property
    def payload(self) -> str:
        """The payload's name in the figures."""
        return "bar" if self.payload_is_bar else "payload"

    @property
    def uavs(self) -> tuple[tuple[str, tuple[slice, slice, slice, slice]], ...]:
        """("UAV i", its (p, v, Θ, ω) slices) for UAV 1 … UAV N."""
        return tuple((f"UAV {i}", self.layout.uav_slices(i)) for i in self.layout.vehicles)

    @property
    def bodies(self) -> tuple[tuple[str, int], ...]:
        """Each body's name and where its block starts in the state, the payload's first."""
        return ((self.payload, P_B.start), *((name, parts[0].start) for name, parts in self.uavs))

    @property
    def orientation_panels(self) -> tuple[tuple[str, int, tuple[str, ...]], ...]:
        """Each body's name, its block's start and the angles drawn of it."""
        payload_angles = BAR_ANGLES if self.payload_is_bar else ANGLES
        return (
            (self.payload, P_B.start, payload_angles),
            *((name, parts[0].start, ANGLES) for name, parts in self.uavs),
        )

    @property
    def error_rows(self) -> tuple[tuple[str, int, tuple[str, ...], str], ...]:
        """Fig. 8's rows: (name, the state index of its first component, its components,
        unit); a panel per component, x/roll, y/pitch, z/yaw from the left."""
        return (
            (f"{self.payload} position error", P_B.start, AXES, "[m]"),
            (f"{self.payload} yaw error", PAYLOAD_YAW, ("yaw",), "[°]"),
            *(
                row
                for name, parts in self.uavs
                for row in (
                    (f"{name} position error", parts[0].start, AXES, "[m]"),
                    (f"{name} attitude error", parts[2].start, ANGLES, "[°]"),
                )
            ),
        )


def formation(logs: list[FlightLog]) -> Formation:
    """The formation every one of ``logs`` flew. Raises ``ValueError`` for logs of
    different formations (their panels would not be the same)."""
    kinds = {(log.layout, log.payload_is_bar) for log in logs}
    if len(kinds) != 1:
        raise ValueError(
            "a report draws logs of one formation: these are of "
            + " and ".join(
                f"{log.layout.n_vehicles} UAVs and a {'bar' if log.payload_is_bar else 'payload'}"
                for log in logs
            )
        )
    return Formation(*kinds.pop())


FALLBACK_STATUSES = frozenset(s.value for s in PlanStatus if s.is_fallback)


@contextmanager
def _warnings_ignored() -> Iterator[None]:
    """numpy's "mean of empty slice" where a window holds no finite value (an NaN is the
    answer wanted there)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        yield


def _wrap(angles: np.ndarray) -> np.ndarray:
    return np.remainder(angles + np.pi, 2 * np.pi) - np.pi


def _tilt_rad(euler_zyx: np.ndarray) -> np.ndarray:
    """The angle between a body's z axis and the vertical, per row of (φ, θ, ψ) [rad]."""
    cos_tilt = np.cos(euler_zyx[:, 0]) * np.cos(euler_zyx[:, 1])  # R[2, 2] of Z-Y-X
    tilt: np.ndarray = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
    return tilt


def summarize(log: FlightLog) -> dict[str, Any]:
    """Table III statistics and timing figures of one flight of ``vehicles`` UAVs.

    ``bar_x_error_*`` are the arithmetic mean and sample standard deviation of the bar
    centre's x error (the paper's proxy; of any other payload, its CoM's); RMS figures
    cover position (3-D) and yaw, under the bar's names and, for any setup, the payload's
    (``payload_position_rmse_m``, ``payload_yaw_rmse_deg``); ``max_payload_tilt_deg`` is the
    payload's largest tilt from level as estimated.
    """
    error = log.state[:, P_B] - log.state_ref[:, P_B]
    yaw_error = _wrap(log.state[:, PAYLOAD_YAW] - log.state_ref[:, PAYLOAD_YAW])
    x_error = error[:, 0]
    finite = np.isfinite(x_error)
    solve = log.solve_ms[np.isfinite(log.solve_ms)]
    compute = log.compute_ms[np.isfinite(log.compute_ms)]

    def pct(values: np.ndarray, q: float) -> float:
        return float(np.percentile(values, q)) if values.size else math.nan

    with _warnings_ignored():
        position_rms_m = float(np.sqrt(np.nanmean(np.sum(error**2, axis=1))))
        yaw_rms_deg = float(np.degrees(np.sqrt(np.nanmean(yaw_error**2))))
        tilt_deg = np.degrees(_tilt_rad(log.state[:, TH_B]))
        max_payload_tilt_deg = float(np.nanmax(tilt_deg)) if len(tilt_deg) else math.nan
    return {
        "controller": log.controller,
        "vehicles": log.layout.n_vehicles,
        "ticks": len(log.t_s),
        "duration_s": float(log.t_s[-1] - log.t_s[0]) if len(log.t_s) else 0.0,
        "bar_x_error_mean_m": float(np.mean(x_error[finite])) if finite.any() else math.nan,
        "bar_x_error_std_m": float(np.std(x_error[finite], ddof=1))
        if finite.sum() > 1
        else math.nan,
        "bar_position_rms_m": position_rms_m,
        "bar_yaw_rms_deg": yaw_rms_deg,
        "payload_position_rmse_m": position_rms_m,
        "payload_yaw_rmse_deg": yaw_rms_deg,
        "max_payload_tilt_deg": max_payload_tilt_deg,
        "solve_ms": {
            "p50": pct(solve, 50),
            "p99": pct(solve, 99),
            "max": float(solve.max()) if solve.size else math.nan,
        },
        "compute_ms": {"p50": pct(compute, 50), "p99": pct(compute, 99)},
        "fallback_ticks": sum(1 for s in log.plan_status if s in FALLBACK_STATUSES),
    }


COLOURS = ("tab:blue", "tab:orange")
FILTER_S = 0.5  # the inputs' moving window: the MPC's tick-to-tick chatter is ~20 ms
# A panel's legend holds a label per log: longer file names are shortened in their middle
# (the start and the end tell flight logs apart: flight-20261203-101500.mcap is 27).
LABEL_CHARS = 36
TIME_LABEL = "t since the flight's start [s]"
COLUMN_WIDTH_IN = 4.3  # a column of panels, beyond the paper's two UAVs
ERROR_ROW_HEIGHT_IN = 2.5  # a row of Fig. 8's panels (the paper's two UAVs: 15 in)


def _style(index: int) -> str:
    return "-" if index == 0 else "--"


def _t_s(log: FlightLog) -> np.ndarray:
    """The ticks' times from the log's first tick [s]."""
    return log.t_s - log.t_s[0] if len(log.t_s) else log.t_s


def _shortened(name: str) -> str:
    if len(name) <= LABEL_CHARS:
        return name
    keep = LABEL_CHARS - 1
    return f"{name[: keep - keep // 2]}…{name[len(name) - keep // 2 :]}"


def log_names(logs: list[FlightLog]) -> list[str]:
    """What names each log in the report: its file name; with its folder's when the names
    are the same, and its place when the paths are too."""
    names = [log.path.name for log in logs]
    if len(set(names)) < len(names):
        names = [f"{log.path.parent.name}/{log.path.name}" for log in logs]
    if len(set(names)) < len(names):
        names = [f"{name} ({k + 1})" for k, name in enumerate(names)]
    return names


def _labels(logs: list[FlightLog]) -> list[str]:
    """Each log's name as its figures' legends and titles give it."""
    return [_shortened(name) for name in log_names(logs)]


def _title(fig: Any, title: str, logs: list[FlightLog]) -> None:
    """The figure's title, then a line per log: its label and the controller(s) it flew."""
    labels = _labels(logs)
    styles = ("", "") if len(logs) == 1 else (" (solid)", " (dashed)")
    lines = [f"{labels[k]}{styles[k]}: {log.controller}" for k, log in enumerate(logs)]
    fig.suptitle(title + "\n" + "\n".join(lines), fontsize=11)


def _unwrap(angles_rad: np.ndarray) -> np.ndarray:
    """np.unwrap over the finite samples only (a NaN would spread through the rest)."""
    out = np.full_like(angles_rad, np.nan)
    finite = np.isfinite(angles_rad)
    out[finite] = np.unwrap(angles_rad[finite])
    return out


def _unwrapped_pair(state_rad: np.ndarray, ref_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """State and reference angles without ±180° jumps; the reference is put within half a
    turn of the state where both exist, so a line never sits a turn away from its
    reference."""
    state = _unwrap(state_rad)
    ref = np.where(np.isfinite(state), state + _wrap(ref_rad - state), _unwrap(ref_rad))
    return state, ref


def _legend(ax: Any, **kwargs: Any) -> None:
    ax.legend(fontsize=7, loc="best", framealpha=0.8, **kwargs)


def _against_reference(
    ax: Any, logs: list[FlightLog], k: int, values: np.ndarray, reference: np.ndarray
) -> None:
    """Log ``k``'s ``values`` in its style, and its ``reference`` dotted (labelled once)."""
    t_s = _t_s(logs[k])
    ax.plot(t_s, values, _style(k), color=COLOURS[k], lw=1.1, label=_labels(logs)[k])
    ax.plot(t_s, reference, ":", color="k", lw=0.9, label="reference" if k == 0 else None)


def _width_in(columns: int) -> float:
    """A figure's width for ``columns`` columns of panels [in]: the paper's 13 in for two
    UAVs' three, wider for more."""
    return max(13.0, COLUMN_WIDTH_IN * columns)


def _positions(logs: list[FlightLog], drawn: Formation) -> Any:
    """Fig. 6, positions: the payload, UAV 1 … UAV N (columns) × x, y, z (rows), reference
    dotted."""
    columns = len(drawn.bodies)
    fig, axes = plt.subplots(
        3, columns, figsize=(_width_in(columns), 8.5), sharex=True, layout="constrained"
    )
    for col, (body, offset) in enumerate(drawn.bodies):
        for row, axis in enumerate(AXES):
            ax = axes[row, col]
            for k, log in enumerate(logs):
                _against_reference(
                    ax, logs, k, log.state[:, offset + row], log.state_ref[:, offset + row]
                )
            ax.set_title(f"{body} {axis}", fontsize=9)
            ax.set_ylabel("[m]")
            ax.grid(alpha=0.3)
            _legend(ax)
        axes[-1, col].set_xlabel(TIME_LABEL)
    _title(fig, "Positions (dotted: reference)", logs)
    return fig


def _no_panel(ax: Any, text: str) -> None:
    ax.axis("off")
    ax.text(
        0.5, 0.5, text, ha="center", va="center", fontsize=9, color="0.4", transform=ax.transAxes
    )


def _orientations(logs: list[FlightLog], drawn: Formation) -> Any:
    """Fig. 6, orientations, unwrapped (no ±180° stripes); a bar has no roll panel."""
    columns = len(drawn.orientation_panels)
    fig, axes = plt.subplots(
        3, columns, figsize=(_width_in(columns), 8.5), sharex=True, layout="constrained"
    )
    for col, (body, offset, angles) in enumerate(drawn.orientation_panels):
        rows = [ANGLES.index(angle) for angle in angles]
        for row in range(3):
            ax = axes[row, col]
            if row not in rows:  # a bar's roll
                _no_panel(ax, f"{body}: no roll\n(it cannot turn about its own axis)")
                continue
            for k, log in enumerate(logs):
                state, ref = _unwrapped_pair(
                    log.state[:, offset + 6 + row], log.state_ref[:, offset + 6 + row]
                )
                _against_reference(ax, logs, k, np.degrees(state), np.degrees(ref))
            ax.set_title(f"{body} {ANGLES[row]}", fontsize=9)
            ax.set_ylabel("[°]")
            ax.grid(alpha=0.3)
            _legend(ax)
            ax.xaxis.set_tick_params(labelbottom=True)
        axes[max(rows), col].set_xlabel(TIME_LABEL)
    _title(fig, "Orientations, unwrapped (dotted: reference)", logs)
    return fig


def _window(log: FlightLog) -> int:
    dt = float(np.nanmedian(np.diff(log.t_s))) if len(log.t_s) > 1 else 0.02
    return max(1, round(FILTER_S / dt))


def _filtered(values: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centred moving mean, min and max over ``window`` samples (NaN-aware; the ends with
    a shorter window)."""
    pad = window // 2
    padded = np.pad(values, (pad, window - 1 - pad), constant_values=np.nan)
    views = np.lib.stride_tricks.sliding_window_view(padded, window)
    with np.errstate(all="ignore"), _warnings_ignored():
        return np.nanmean(views, axis=1), np.nanmin(views, axis=1), np.nanmax(views, axis=1)


INPUT_ROWS = (
    ("thrust F", 0, "[N]"),
    ("torque τx", 1, "[N m]"),
    ("torque τy", 2, "[N m]"),
    ("torque τz", 3, "[N m]"),
)


def _inputs(logs: list[FlightLog], drawn: Formation) -> Any:
    """Fig. 7: each UAV's thrust and torques, one panel each (a column per UAV), as a 0.5 s
    moving mean with the raw values' range over the same window shaded."""
    columns = drawn.layout.n_vehicles
    fig, axes = plt.subplots(
        4, columns, figsize=(_width_in(columns), 9.5), sharex=True, layout="constrained"
    )
    labels = _labels(logs)
    for uav in range(columns):
        first = drawn.layout.thrust_index(uav + 1)
        for row, (name, index, unit) in enumerate(INPUT_ROWS):
            ax = axes[row, uav]
            for k, log in enumerate(logs):
                mean, low, high = _filtered(log.inputs[:, first + index], _window(log))
                t_s = _t_s(log)
                ax.fill_between(t_s, low, high, color=COLOURS[k], alpha=0.22, lw=0)
                ax.plot(t_s, mean, _style(k), color=COLOURS[k], lw=1.1, label=labels[k])
            handles, _ = ax.get_legend_handles_labels()
            shade = Patch(color="0.5", alpha=0.3, lw=0, label="raw range")
            ax.legend(handles=[*handles, shade], fontsize=7, loc="best", framealpha=0.8, ncol=2)
            ax.set_title(f"UAV {uav + 1} {name}{uav + 1 if index == 0 else ''}", fontsize=9)
            ax.set_ylabel(unit)
            ax.grid(alpha=0.3)
        axes[-1, uav].set_xlabel(TIME_LABEL)
    _title(fig, f"Inputs: {FILTER_S:g} s moving mean, raw range shaded", logs)
    return fig


def _errors(logs: list[FlightLog], drawn: Formation) -> Any:
    """Fig. 8: tracking errors of the payload and every UAV, a panel per component with
    every log on it (the same scale along a row), angles wrapped to ±180°."""
    rows = drawn.error_rows
    fig, axes = plt.subplots(
        len(rows),
        3,
        figsize=(13, ERROR_ROW_HEIGHT_IN * len(rows)),
        sharex=True,
        sharey="row",
        layout="constrained",
    )
    labels = _labels(logs)
    for row, (name, offset, components, unit) in enumerate(rows):
        for col in range(len(components), 3):
            axes[row, col].axis("off")
        for j, component in enumerate(components):
            ax = axes[row, j]
            for k, log in enumerate(logs):
                error = log.state[:, offset + j] - log.state_ref[:, offset + j]
                if unit == "[°]":
                    error = np.degrees(_wrap(error))
                ax.plot(_t_s(log), error, _style(k), color=COLOURS[k], lw=0.9, label=labels[k])
            ax.set_title(f"{name} {component}" if len(components) > 1 else name, fontsize=9)
            ax.set_ylabel(unit)
            ax.grid(alpha=0.3)
            ax.xaxis.set_tick_params(labelbottom=True)
            _legend(ax)
    for col in range(3):
        axes[-1, col].set_xlabel(TIME_LABEL)
    _title(fig, "Tracking errors (state − reference)", logs)
    return fig


SUMMARY_COLUMNS = (
    "log",
    "controller",
    "duration [s]",
    "bar x error mean [m]",
    "std [m]",
    "bar position RMS [m]",
    "bar yaw RMS [°]",
    "solve p50 / p99 [ms]",
    "fallback ticks",
)
PAPER_TABLE_III = (
    "Paper, Table III (lab): centralized −0.05514 / 0.05846 m, "
    "decentralized 0.23468 / 0.12554 m (x error mean / std)."
)


def _markdown(summaries: list[dict[str, Any]], labels: list[str]) -> str:
    lines = ["# Flight summary", "", "| " + " | ".join(SUMMARY_COLUMNS) + " |"]
    lines.append("|" + "---|" * len(SUMMARY_COLUMNS))
    for s, label in zip(summaries, labels, strict=True):
        cells = (
            label.replace("|", "\\|"),
            s["controller"],
            f"{s['duration_s']:.1f}",
            f"{s['bar_x_error_mean_m']:.5f}",
            f"{s['bar_x_error_std_m']:.5f}",
            f"{s['bar_position_rms_m']:.4f}",
            f"{s['bar_yaw_rms_deg']:.2f}",
            f"{s['solve_ms']['p50']:.2f} / {s['solve_ms']['p99']:.2f}",
            str(s["fallback_ticks"]),
        )
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", PAPER_TABLE_III]
    return "\n".join(lines) + "\n"


def figures(logs: list[FlightLog]) -> dict[str, Any]:
    """The four figures of one or two logs, by file stem (matplotlib Figures, open).
    Raises ``ValueError`` for logs of different formations (``formation``)."""
    drawn = formation(logs)
    return {
        "positions": _positions(logs, drawn),
        "orientations": _orientations(logs, drawn),
        "inputs": _inputs(logs, drawn),
        "errors": _errors(logs, drawn),
    }


def write_report(logs: list[FlightLog], out: Path) -> list[Path]:
    """Write the figures and the summary (a row per log, named by its file) for one or two
    logs of one formation, each with at least one tick; returns the files written. Raises
    ``ValueError`` (before writing anything) for logs of different formations."""
    formation(logs)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for stem, fig in figures(logs).items():
        fig.savefig(out / f"{stem}.png", dpi=110)
        plt.close(fig)
        files.append(out / f"{stem}.png")
    summaries = [{"log": str(log.path), **summarize(log)} for log in logs]
    (out / "summary.json").write_text(json.dumps(summaries, indent=2) + "\n")
    (out / "summary.md").write_text(_markdown(summaries, log_names(logs)))
    return [*files, out / "summary.json", out / "summary.md"]
