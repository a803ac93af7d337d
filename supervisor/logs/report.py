"""Flight reports: the paper's Figs 6–8 and a Table III-style summary from flight logs.

``write_report([log], out)`` writes ``positions.png``, ``orientations.png`` (Fig. 6),
``inputs.png`` (Fig. 7), ``errors.png`` (Fig. 8) and ``summary.md`` / ``summary.json``.
With two logs (e.g. centralized and decentralized) the second is drawn dashed over the
first, as in Fig. 8. References are dashed in Figs 6 (thin, grey-toned) as in the paper.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only, no display
import matplotlib.pyplot as plt
import numpy as np

from controllers.mpc import PlanStatus
from supervisor.logs.flight_log import FlightLog

BODIES = (("bar", 0), ("UAV 1", 12), ("UAV 2", 24))
AXES = ("x", "y", "z")
ANGLES = ("roll", "pitch", "yaw")


FALLBACK_STATUSES = frozenset(s.value for s in PlanStatus if s.is_fallback)


def _wrap(angles: np.ndarray) -> np.ndarray:
    return np.remainder(angles + np.pi, 2 * np.pi) - np.pi


def summarize(log: FlightLog) -> dict[str, Any]:
    """Table III statistics and timing figures of one flight.

    ``bar_x_error_*`` are the arithmetic mean and sample standard deviation of the bar
    centre's x error (the paper's proxy); RMS figures cover position (3-D) and yaw.
    """
    error = log.state[:, 0:3] - log.state_ref[:, 0:3]
    yaw_error = _wrap(log.state[:, 8] - log.state_ref[:, 8])
    x_error = error[:, 0]
    finite = np.isfinite(x_error)
    solve = log.solve_ms[np.isfinite(log.solve_ms)]
    compute = log.compute_ms[np.isfinite(log.compute_ms)]

    def pct(values: np.ndarray, q: float) -> float:
        return float(np.percentile(values, q)) if values.size else math.nan

    return {
        "controller": log.controller,
        "ticks": len(log.t_s),
        "duration_s": float(log.t_s[-1] - log.t_s[0]) if len(log.t_s) else 0.0,
        "bar_x_error_mean_m": float(np.mean(x_error[finite])) if finite.any() else math.nan,
        "bar_x_error_std_m": float(np.std(x_error[finite], ddof=1))
        if finite.sum() > 1
        else math.nan,
        "bar_position_rms_m": float(np.sqrt(np.nanmean(np.sum(error**2, axis=1))))
        if len(error)
        else math.nan,
        "bar_yaw_rms_deg": float(np.degrees(np.sqrt(np.nanmean(yaw_error**2))))
        if len(yaw_error)
        else math.nan,
        "solve_ms": {
            "p50": pct(solve, 50),
            "p99": pct(solve, 99),
            "max": float(solve.max()) if solve.size else math.nan,
        },
        "compute_ms": {"p50": pct(compute, 50), "p99": pct(compute, 99)},
        "fallback_ticks": sum(1 for s in log.plan_status if s in FALLBACK_STATUSES),
    }


def _style(index: int) -> str:
    return "-" if index == 0 else "--"


def _positions(logs: list[FlightLog], out: Path) -> Path:
    fig, axes = plt.subplots(3, 3, figsize=(13, 8), sharex=True)
    for col, (body, offset) in enumerate(BODIES):
        for row, axis in enumerate(AXES):
            ax = axes[row, col]
            for k, log in enumerate(logs):
                ax.plot(
                    log.t_s, log.state[:, offset + row], _style(k), lw=1.2, label=log.controller
                )
                ax.plot(log.t_s, log.state_ref[:, offset + row], ":", color="k", lw=0.9)
            ax.set_ylabel(f"{body} {axis} [m]")
            ax.grid(alpha=0.3)
        axes[-1, col].set_xlabel("t [s]")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle("Positions (dotted: reference)")
    fig.tight_layout()
    path = out / "positions.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _orientations(logs: list[FlightLog], out: Path) -> Path:
    fig, axes = plt.subplots(3, 3, figsize=(13, 8), sharex=True)
    for col, (body, offset) in enumerate(BODIES):
        for row, angle in enumerate(ANGLES):
            ax = axes[row, col]
            for k, log in enumerate(logs):
                ax.plot(
                    log.t_s,
                    np.degrees(log.state[:, offset + 6 + row]),
                    _style(k),
                    lw=1.2,
                    label=log.controller,
                )
                ax.plot(
                    log.t_s, np.degrees(log.state_ref[:, offset + 6 + row]), ":", color="k", lw=0.9
                )
            ax.set_ylabel(f"{body} {angle} [°]")
            ax.grid(alpha=0.3)
        axes[-1, col].set_xlabel("t [s]")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle("Orientations (dotted: reference)")
    fig.tight_layout()
    path = out / "orientations.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _inputs(logs: list[FlightLog], out: Path) -> Path:
    fig, axes = plt.subplots(2, 2, figsize=(12, 6), sharex=True)
    for uav in range(2):
        for k, log in enumerate(logs):
            axes[0, uav].plot(
                log.t_s, log.inputs[:, 4 * uav], _style(k), lw=1.1, label=log.controller
            )
            for j, name in enumerate(("τx", "τy", "τz")):
                axes[1, uav].plot(
                    log.t_s,
                    log.inputs[:, 4 * uav + 1 + j],
                    _style(k),
                    lw=1.0,
                    label=f"{name} {log.controller}",
                )
        axes[0, uav].set_ylabel(f"F{uav + 1} [N]")
        axes[1, uav].set_ylabel(f"τ{uav + 1} [N m]")
        axes[1, uav].set_xlabel("t [s]")
        for ax in axes[:, uav]:
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[1, 0].legend(fontsize=7, ncol=2)
    fig.suptitle("Inputs: thrust and body torque per UAV")
    fig.tight_layout()
    path = out / "inputs.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _errors(logs: list[FlightLog], out: Path) -> Path:
    fig, axes = plt.subplots(2, 3, figsize=(14, 6), sharex=True)
    for k, log in enumerate(logs):
        style, label = _style(k), log.controller
        uav_pos = np.linalg.norm(log.state[:, 12:15] - log.state_ref[:, 12:15], axis=1)
        uav_att = np.degrees(
            np.linalg.norm(_wrap(log.state[:, 18:21] - log.state_ref[:, 18:21]), axis=1)
        )
        axes[0, 0].plot(log.t_s, uav_pos, style, label=label)
        axes[1, 0].plot(log.t_s, uav_att, style, label=label)
        thrust = log.inputs[:, [0, 4]]
        torque = np.linalg.norm(log.inputs[:, [1, 2, 3, 5, 6, 7]].reshape(-1, 2, 3), axis=2)
        axes[0, 1].plot(log.t_s, thrust, style, label=label)
        axes[1, 1].plot(log.t_s, torque, style, label=label)
        bar_err = np.abs(log.state[:, 0:3] - log.state_ref[:, 0:3])
        axes[0, 2].plot(log.t_s, bar_err, style, label=label)
        axes[1, 2].plot(
            log.t_s, np.degrees(_wrap(log.state[:, 8] - log.state_ref[:, 8])), style, label=label
        )
    titles = (
        ("UAV 1 position error [m]", "thrust F1, F2 [N]", "bar |error| x, y, z [m]"),
        ("UAV 1 attitude error [°]", "torque norm ‖τ1‖, ‖τ2‖ [N m]", "bar yaw error [°]"),
    )
    for row in range(2):
        for col in range(3):
            axes[row, col].set_title(titles[row][col], fontsize=10)
            axes[row, col].grid(alpha=0.3)
    for col in range(3):
        axes[1, col].set_xlabel("t [s]")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle("Errors and input magnitudes" + (" (dashed: second log)" if len(logs) > 1 else ""))
    fig.tight_layout()
    path = out / "errors.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


SUMMARY_COLUMNS = (
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


def _markdown(summaries: list[dict[str, Any]]) -> str:
    lines = ["# Flight summary", "", "| " + " | ".join(SUMMARY_COLUMNS) + " |"]
    lines.append("|" + "---|" * len(SUMMARY_COLUMNS))
    for s in summaries:
        cells = (
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


def write_report(logs: list[FlightLog], out: Path) -> list[Path]:
    """Write the figures and the summary for one or two logs; returns the files written."""
    out.mkdir(parents=True, exist_ok=True)
    files = [
        _positions(logs, out),
        _orientations(logs, out),
        _inputs(logs, out),
        _errors(logs, out),
    ]
    summaries = [summarize(log) for log in logs]
    (out / "summary.json").write_text(json.dumps(summaries, indent=2) + "\n")
    (out / "summary.md").write_text(_markdown(summaries))
    return [*files, out / "summary.json", out / "summary.md"]
