"""Control outside the nominal case (issue 19): each case flies both controllers on the
closed-loop simulator (``supervisor.simulate``, ``configs/sim.toml``; the decentralized
MPC with the reference lead [0.6, 0.2]) with and without a remedy, in one run, and prints
the figures side by side.

* ``latency``: the paper's sequence with 45 ms of mocap latency, without and with the
  delay compensation (``mpc.delay_s``, controllers/delay.py).
* ``offset``: a 0.54 m move and a 20 s hold, with the configured bar and one 50 % heavier,
  without and with the integral action (``mpc.integral_gain_per_s``).
* ``paper-integral``: the paper's sequence, nominal, without and with the integral action.
* ``theta``: from hover, θ_l ramps to 70°, is held 10 s, and back (held 5 s).
* ``combined``: the paper's sequence, the paper's controllers at the nominal 5 ms of
  latency against all three remedies at 45 ms (delay 0.045 s, rate filter 0.5, integral
  0.4).
* ``shipped``: issue 33's checks of the shipped settings against those before them.
* ``move``: a 4 m straight move at 1 m/s and 1 m/s², and at 2 m/s and 2 m/s² (issue 33).
* ``paths``: the paths of ``configs/scenarios/paths.toml`` — a 4 m straight path at 1 m/s
  and 1 m/s², a closed path at 2 m/s and 2 m/s², and at 2 m/s and 4 m/s² — without and
  with the preview (``control.preview``): moving RMSE and overshoot against the timed
  path (the truth, as ``simulate --json``), and the MPC's solve time per tick.
* ``noise``: the move and hold of ``offset`` (nominal bar) with the UAVs' body rates
  unfiltered and filtered (``mpc.rate_filter_weight``, controllers/rate_filter.py).

Figures per flight: done (the steps completed with no forced decision), max UAV tilt [°]
(truth), share of MPC ticks with an input at its bound, cable slack events (truth), bar
position error spread [mm] (estimate against the shaped reference: the norm of the
per-axis standard deviations), median |Δτ| between ticks [N m], the steady error [mm]
(norm of the mean bar error over the last 5 s) and the largest gap between the
reference's θ_l and the cables' mean angle [°].

Run: ``python -m benchmarks.robustness CASE [--json] [--seconds S]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import statistics
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controllers.formation_params import FormationParams
from geometry.state import payload_points, payload_position
from supervisor.app.config import load_config
from supervisor.app.config_files import CONFIG_DIR
from supervisor.flight.core import TickResult
from supervisor.simulate.closed_loop import run_scenario
from supervisor.simulate.scenarios import Scenario, load_scenario

CONFIG = CONFIG_DIR / "sim.toml"
CONTROLLERS = ("centralized", "decentralized")
# The decentralized controller as issue 19 decided it flies (its reference lead).
LEAD = "mpc.decentralized.reference_lead_s=[0.6, 0.2]"
SATURATION_MARGIN = 1e-6
TICK_S = 0.02
INTEGRAL_GAIN = 0.4
# The cases about the integral action measure it alone, without the force observer.
OBSERVER_OFF = "mpc.force_observer_s=0"


@dataclass
class Figures:
    """What one simulated flight did (see the module's docstring)."""

    completed: bool
    final_mode: str
    notices: list[str]
    max_tilt_deg: float
    saturated_share: float
    slack_events: int
    bar_error_std_mm: float
    torque_step_median_nm: float
    extra: dict[str, float] = field(default_factory=dict)


class Recorder:
    """Collects each tick's inputs and tracking error while a scenario flies."""

    def __init__(
        self,
        thrust_bounds_n: tuple[float, float],
        torque_max_nm: float,
        params: FormationParams,
    ) -> None:
        self._params = params
        self.cable_lags_deg: list[float] = []
        self._thrust = thrust_bounds_n
        self._torque = torque_max_nm
        self.mpc_ticks = 0
        self.saturated = 0
        self.errors: list[np.ndarray] = []
        self.inputs: list[np.ndarray] = []
        self.solve_times_s: list[float] = []

    def __call__(self, result: TickResult) -> None:
        if result.plan is None:
            return
        self.mpc_ticks += 1
        self.solve_times_s.append(result.plan.solve_time_s)
        u = np.asarray(result.record.inputs).reshape(self._params.n_vehicles, -1)
        at_bound = (
            np.any(u[:, 0] <= self._thrust[0] + SATURATION_MARGIN)
            or np.any(u[:, 0] >= self._thrust[1] - SATURATION_MARGIN)
            or np.any(np.abs(u[:, 1:]) >= self._torque - SATURATION_MARGIN)
        )
        self.saturated += int(at_bound)
        state = np.asarray(result.record.state)
        reference = np.asarray(result.record.state_ref)
        self.errors.append(payload_position(state) - payload_position(reference))
        self.cable_lags_deg.append(self.cable_angle_deg(state) - self.cable_angle_deg(reference))
        self.inputs.append(u)

    def cable_angle_deg(self, x: np.ndarray) -> float:
        """The cables' mean angle from the vertical [°] in the state ``x``."""
        layout = self._params.layout
        ends = payload_points(x, self._params.payload.attachments_m)
        angles = []
        for i in layout.vehicles:
            cable = layout.uav_position(x, i) - ends[i - 1]
            angles.append(math.degrees(math.atan2(math.hypot(cable[0], cable[1]), cable[2])))
        return sum(angles) / layout.n_vehicles


def fly(
    scenario: Scenario,
    controller: str,
    overrides: Sequence[str],
    seed: int = 0,
    observe: Callable[[TickResult], None] | None = None,
) -> tuple[Figures, Recorder]:
    """Fly ``scenario`` on ``configs/sim.toml`` with ``overrides``; its figures (and each
    tick to ``observe`` too)."""
    config = load_config(CONFIG, list(overrides))
    limits = config.mpc
    recorder = Recorder(
        (limits.thrust_min_n, limits.thrust_max_n),
        limits.torque_max_nm,
        config.system.to_params(),
    )

    def observed(result: TickResult) -> None:
        recorder(result)
        if observe is not None:
            observe(result)

    result = run_scenario(config, scenario, controller, seed=seed, observe=observed)
    errors = np.array(recorder.errors) if recorder.errors else np.zeros((1, 3))
    inputs = np.array(recorder.inputs) if recorder.inputs else np.zeros((2, 2, 4))
    torque_steps = np.abs(np.diff(inputs[:, :, 1:], axis=0)).ravel()
    figures = Figures(
        completed=result.completed and not result.messages,
        final_mode=result.final_mode,
        notices=result.messages,
        max_tilt_deg=result.truth.max_tilt_deg,
        saturated_share=recorder.saturated / max(recorder.mpc_ticks, 1),
        slack_events=result.truth.slack_events,
        bar_error_std_mm=1e3 * float(np.linalg.norm(errors.std(axis=0))),
        torque_step_median_nm=float(statistics.median(torque_steps.tolist() or [0.0])),
    )
    paths = result.paths
    if paths.moving_rmse_m is not None:
        figures.extra["moving RMSE mm"] = 1e3 * paths.moving_rmse_m
        figures.extra["overshoot mm"] = 1e3 * (paths.overshoot_m or 0.0)
    return figures, recorder


def _scenario(data: dict[str, Any]) -> Scenario:
    return Scenario.model_validate(data)


def shortened(scenario: Scenario, seconds: float | None) -> Scenario:
    """``scenario`` with every hold cut to ``seconds`` (None: as it is): a quicker look."""
    if seconds is None:
        return scenario
    steps = [
        step.model_copy(update={"hold_s": min(step.hold_s, seconds)}) for step in scenario.step
    ]
    return scenario.model_copy(update={"step": steps})


def latency_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The paper's sequence at 45 ms of mocap latency, without and with compensation, and
    at 50 ms compensated."""
    scenario = shortened(load_scenario("paper"), seconds)
    latency = "sim.mocap.latency_s=0.045"
    variants = {
        "45 ms, no compensation": [latency],
        "45 ms, compensated": [latency, "mpc.delay_s=0.045"],
        "50 ms, compensated": ["sim.mocap.latency_s=0.05", "mpc.delay_s=0.05"],
    }
    return _flights(scenario, variants)


STEADY_S = 5.0
SETTLE_S = 10.0  # a flight's first seconds left out of its settled mean
HELD = {
    "name": "held setpoint",
    "start": "hover",
    "step": [{"bar_position": [0.5, 0.0, 1.2], "hold_s": 20.0, "timeout_s": 30.0}],
}


def offset_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """A move of 0.54 m then a 20 s hold, with the configured bar and one 50 % heavier
    than configured, without and with the integral action; ``steady mm``: the norm of
    the mean bar position error over the hold's last 5 s."""
    scenario = shortened(_scenario(HELD), seconds)
    heavy, integral = "sim.bar_mass_scale=1.5", f"mpc.integral_gain_per_s={INTEGRAL_GAIN}"
    variants = {
        "nominal bar": ["mpc.integral_gain_per_s=0"],
        "nominal bar, integral": [integral],
        "bar +50 %": [heavy, "mpc.integral_gain_per_s=0"],
        "bar +50 %, integral": [heavy, integral],
    }
    variants = {label: [*settings, OBSERVER_OFF] for label, settings in variants.items()}
    return _flights(scenario, variants)


def paper_integral_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The paper's sequence, nominal, without and with the integral action: is tracking
    worse with it?"""
    scenario = shortened(load_scenario("paper"), seconds)
    variants = {
        "nominal": ["mpc.integral_gain_per_s=0", OBSERVER_OFF],
        "integral": [f"mpc.integral_gain_per_s={INTEGRAL_GAIN}", OBSERVER_OFF],
    }
    return _flights(scenario, variants)


def theta_scenario() -> Scenario:
    """From hover, θ_l ramps to 70° (held 10 s) and back (held 5 s)."""
    return _scenario(
        {
            "name": "theta_l 70",
            "start": "hover",
            "step": [
                {
                    "bar_position": [0.0, 0.0, 1.0],
                    "theta_l_deg": 70.0,
                    "hold_s": 10.0,
                    "timeout_s": 30.0,
                },
                {"bar_position": [0.0, 0.0, 1.0], "hold_s": 5.0, "timeout_s": 30.0},
            ],
        }
    )


def theta_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """``theta_scenario``; ``lag °``: the largest gap between the reference's θ_l and the
    estimate's mean cable angle."""
    return _flights(shortened(theta_scenario(), seconds), {"as is": []})


REMEDIES = [
    "mpc.delay_s=0.045",
    "mpc.rate_filter_weight=0.5",
    f"mpc.integral_gain_per_s={INTEGRAL_GAIN}",
]


def combined_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The paper's sequence: the paper's controllers at the nominal 5 ms of latency
    against all three remedies together at 45 ms."""
    scenario = shortened(load_scenario("paper"), seconds)
    variants = {
        "5 ms, paper's controllers": [],
        "45 ms, all remedies": ["sim.mocap.latency_s=0.045", *REMEDIES],
    }
    return _flights(scenario, variants)


def noise_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The held setpoint's flight with the body rates as fused and filtered."""
    scenario = shortened(_scenario(HELD), seconds)
    variants = {
        "rates as fused": [],
        "rate filter 0.5": ["mpc.rate_filter_weight=0.5"],
        "rate filter 0.8": ["mpc.rate_filter_weight=0.8"],
    }
    return _flights(scenario, variants)


def _flights(scenario: Scenario, variants: dict[str, list[str]]) -> dict[str, dict[str, Figures]]:
    table: dict[str, dict[str, Figures]] = {}
    for controller in CONTROLLERS:
        for label, overrides in variants.items():
            extra = [LEAD] if controller == "decentralized" else []
            figures, recorder = fly(scenario, controller, [*overrides, *extra])
            steady = np.array(recorder.errors[-round(STEADY_S / TICK_S) :])
            figures.extra["steady mm"] = 1e3 * float(np.linalg.norm(steady.mean(axis=0)))
            figures.extra["lag °"] = max(map(abs, recorder.cable_lags_deg), default=0.0)
            table.setdefault(controller, {})[label] = figures
            print(f"  flown: {controller}, {label}", file=sys.stderr, flush=True)
    return table


def default_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The decentralized MPC as shipped (the setup's own settings, the reference lead
    included) against the centralized one, in one run: the paper's sequence and a 120 s
    hover. ``x std mm``: the std of the bar's x-error; ``x std ×``: the decentralized
    MPC's over the centralized MPC's in the same flight. "done" means no forced decision,
    a swing hand-over included."""
    hover = _scenario(
        {"name": "hover 120 s", "start": "hover", "step": [{"action": "hover", "hold_s": 120.0}]}
    )
    scenarios = {"paper's sequence": load_scenario("paper"), "120 s hover": hover}
    table: dict[str, dict[str, Figures]] = {}
    for label, scenario in scenarios.items():
        x_std_mm = {}
        for controller in CONTROLLERS:
            figures, recorder = fly(shortened(scenario, seconds), controller, [])
            x_std_mm[controller] = 1e3 * float(np.array(recorder.errors)[:, 0].std())
            figures.extra["x std mm"] = x_std_mm[controller]
            table.setdefault(controller, {})[label] = figures
            print(f"  flown: {controller}, {label}", file=sys.stderr, flush=True)
        ratio = x_std_mm["decentralized"] / x_std_mm["centralized"]
        table["decentralized"][label].extra["x std ×"] = ratio
    return table


def push_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """From hover, a steady 1 N push along x on the bar from 2 s on, the setpoint held 30 s
    (``steady mm``: the bar's mean position error over the last 5 s), with neither remedy,
    the integral action alone, and the force observer (as shipped)."""
    scenario = _scenario(
        {
            "name": "push 1 N",
            "start": "hover",
            "load": [{"body": "bar", "force_n": [1.0, 0.0, 0.0], "start_s": 2.0}],
            "step": [{"action": "hover", "hold_s": 30.0}],
        }
    )
    variants = {
        "neither": ["mpc.integral_gain_per_s=0", OBSERVER_OFF],
        "integral": [f"mpc.integral_gain_per_s={INTEGRAL_GAIN}", OBSERVER_OFF],
        "force observer": [],
    }
    return _flights(shortened(scenario, seconds), variants)


# 4 m along the arena's diagonal: the bar's ends (±0.72 m along x) stay clear of its walls.
MOVE_START_M = (-math.sqrt(2.0), -math.sqrt(2.0), 1.0)
MOVE_END_M = (math.sqrt(2.0), math.sqrt(2.0), 1.0)


class MoveRecorder:
    """The bar's 3D error against the shaped reference while that moves (speed above
    1 mm/s) on the way to ``MOVE_END_M``, and how far the bar passes the goal along the
    move's direction."""

    def __init__(self) -> None:
        self.moving_errors_m: list[float] = []
        self.overshoot_m = 0.0
        self._direction = np.subtract(MOVE_END_M, MOVE_START_M) / np.linalg.norm(
            np.subtract(MOVE_END_M, MOVE_START_M)
        )

    def __call__(self, result: TickResult) -> None:
        reference = result.reference
        if reference is None:
            return
        bar = payload_position(np.asarray(result.record.state))
        if float(np.dot(reference.velocity_mps, self._direction)) > 1e-3:
            error = bar - np.asarray(reference.payload_position_m)
            self.moving_errors_m.append(float(np.linalg.norm(error)))
        past = float(np.dot(bar - np.asarray(MOVE_END_M), self._direction))
        self.overshoot_m = max(self.overshoot_m, past)


def move_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """A 4 m straight move of the bar (along the diagonal, 1 m high) at 1 m/s and 1 m/s²
    and at 2 m/s and 2 m/s², held 5 s at its end, without and with the acceleration
    feed-forward (issue 33): ``moving RMSE mm`` is the bar centre's 3D RMSE against the
    shaped reference while it moves, ``overshoot mm`` how far the bar passed the goal."""
    scenario = _scenario(
        {
            "name": "4 m move",
            "start": "hover",
            "step": [
                {"bar_position": list(MOVE_START_M), "hold_s": 3.0, "timeout_s": 30.0},
                {"bar_position": list(MOVE_END_M), "hold_s": 5.0, "timeout_s": 30.0},
            ],
        }
    )
    variants = {}
    for v, feed in itertools.product((1.0, 2.0), (False, True)):
        label = f"{v:.0f} m/s, {v:.0f} m/s², {'' if feed else 'no '}acc. FF"
        variants[label] = [
            f"control.flight_rates.position_mps={v}",
            f"control.flight_rates.acceleration_mps2={v}",
            f"control.acceleration_feed_forward={str(feed).lower()}",
        ]
    table: dict[str, dict[str, Figures]] = {}
    for controller in CONTROLLERS:
        for label, overrides in variants.items():
            move = MoveRecorder()
            figures, _ = fly(shortened(scenario, seconds), controller, overrides, observe=move)
            errors = np.array(move.moving_errors_m or [math.nan])
            figures.extra["moving RMSE mm"] = 1e3 * float(np.sqrt(np.mean(errors**2)))
            figures.extra["overshoot mm"] = 1e3 * move.overshoot_m
            table.setdefault(controller, {})[label] = figures
            print(f"  flown: {controller}, {label}", file=sys.stderr, flush=True)
    return table


def paths_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """The shipped ``paths`` scenario's straight and closed paths (the closed one also at
    4 m/s²), each from hover, without and with the preview."""
    shipped = load_scenario("paths")
    straight = shipped.model_copy(update={"step": shipped.step[:1]})
    hover_at = shipped.step[1].bar_position
    assert hover_at is not None
    loop = shipped.step[2]
    flights = {
        "4 m line, 1 m/s, 1 m/s²": straight,
        "loop, 2 m/s, 2 m/s²": shipped.model_copy(
            update={"start_bar_position": hover_at, "step": [loop]}
        ),
        "loop, 2 m/s, 4 m/s²": shipped.model_copy(
            update={
                "start_bar_position": hover_at,
                "step": [loop.model_copy(update={"accel_mps2": 4.0})],
            }
        ),
    }
    table: dict[str, dict[str, Figures]] = {}
    for controller in CONTROLLERS:
        for (name, scenario), preview in itertools.product(flights.items(), (False, True)):
            label = f"{name}, {'' if preview else 'no '}preview"
            recorder_figures, recorder = fly(
                shortened(scenario, seconds),
                controller,
                [f"control.preview={str(preview).lower()}"],
            )
            solve_ms = 1e3 * np.array(recorder.solve_times_s or [math.nan])
            recorder_figures.extra["solve p50 ms"] = float(np.median(solve_ms))
            recorder_figures.extra["solve p99 ms"] = float(np.percentile(solve_ms, 99))
            table.setdefault(controller, {})[label] = recorder_figures
            print(f"  flown: {controller}, {label}", file=sys.stderr, flush=True)
    return table


BEFORE_OFFSET_FREE = ["mpc.integral_gain_per_s=0", "mpc.delay_s=0", "mpc.force_observer_s=0"]


def shipped_case(seconds: float | None) -> dict[str, dict[str, Figures]]:
    """Issue 33's checks of the shipped settings, against the settings before them (no
    integral, no delay compensation, no force observer) in the same run: the paper's
    sequence nominal and with 45 ms of mocap latency, a bar 50 % heavier hovering 120 s,
    steady pushes of 1 N and 3 N on the bar held 30 s, a 2 m/s wind with gusts (std 0.5 m/s
    across, 0.2 m/s up; drag 0.3 N s/m on every body) for 60 s, UAV 1 20 % heavier than
    configured for 30 s, and the paper's sequence with the bar's CoM 5 cm off. ``RMS mm``:
    the bar's 3D error RMS; ``mean mm``: the norm of its mean; ``settled mm``: the norm of
    its mean from 10 s on; ``x std mm`` as in ``default``."""
    hover = {
        "name": "hover 120 s",
        "start": "hover",
        "step": [{"action": "hover", "hold_s": 120.0}],
    }

    def push(force_n: float) -> Scenario:
        return _scenario(
            {
                "name": f"push {force_n:g} N",
                "start": "hover",
                "load": [{"body": "bar", "force_n": [force_n, 0.0, 0.0], "start_s": 2.0}],
                "step": [{"action": "hover", "hold_s": 30.0}],
            }
        )

    def hovering(seconds: float) -> Scenario:
        return _scenario({**hover, "step": [{"action": "hover", "hold_s": seconds}]})

    wind = [
        "sim.drag_linear_n_s_per_m=0.3",
        "sim.wind_mean_mps=[2, 0, 0]",
        "sim.wind_gust_std_mps=[0.5, 0.5, 0.2]",
    ]
    paper = load_scenario("paper")
    flights = {
        "paper's sequence": (paper, []),
        "paper's, 45 ms latency": (paper, ["sim.mocap.latency_s=0.045"]),
        "bar +50 %, 120 s hover": (_scenario(hover), ["sim.bar_mass_scale=1.5"]),
        "1 N push, 30 s": (push(1.0), []),
        "3 N push, 30 s": (push(3.0), []),
        "2 m/s wind, gusts, 60 s": (hovering(60.0), wind),
        "UAV 1 +20 %, 30 s hover": (hovering(30.0), ["sim.uav_mass_scale=[1.2, 1.0]"]),
        "paper's sequence, CoM 5 cm off": (paper, ["sim.bar_com_shift_m=0.05"]),
    }
    table: dict[str, dict[str, Figures]] = {}
    for controller in CONTROLLERS:
        for label, (scenario, overrides) in flights.items():
            for variant, settings in (("before", BEFORE_OFFSET_FREE), ("shipped", [])):
                figures, recorder = fly(
                    shortened(scenario, seconds), controller, [*overrides, *settings]
                )
                errors = np.array(recorder.errors)
                figures.extra["x std mm"] = 1e3 * float(errors[:, 0].std())
                figures.extra["RMS mm"] = 1e3 * float(np.sqrt((errors**2).sum(axis=1).mean()))
                figures.extra["mean mm"] = 1e3 * float(np.linalg.norm(errors.mean(axis=0)))
                steady = errors[-round(STEADY_S / TICK_S) :]
                figures.extra["steady mm"] = 1e3 * float(np.linalg.norm(steady.mean(axis=0)))
                settled = errors[round(SETTLE_S / TICK_S) :]
                figures.extra["settled mm"] = 1e3 * float(np.linalg.norm(settled.mean(axis=0)))
                table.setdefault(controller, {})[f"{label}, {variant}"] = figures
                print(f"  flown: {controller}, {label}, {variant}", file=sys.stderr, flush=True)
    return table


CASES = {
    "default": default_case,
    "shipped": shipped_case,
    "move": move_case,
    "paths": paths_case,
    "push": push_case,
    "combined": combined_case,
    "noise": noise_case,
    "latency": latency_case,
    "theta": theta_case,
    "offset": offset_case,
    "paper-integral": paper_integral_case,
}


def _print(table: dict[str, dict[str, Figures]]) -> None:
    header = (
        f"{'controller':<14} {'variant':<36} {'done':<5} {'tilt°':>6} {'sat %':>6} "
        f"{'slack':>5} {'err mm':>7} {'|Δτ| N m':>9}  extra / notices"
    )
    print(header)
    for controller, rows in table.items():
        for label, f in rows.items():
            extra = ", ".join(f"{k} {v:.2f}" for k, v in f.extra.items())
            notes = "; ".join(f.notices)[:120]
            print(
                f"{controller:<14} {label:<36} {'yes' if f.completed else 'NO':<5} "
                f"{f.max_tilt_deg:6.1f} {100 * f.saturated_share:6.2f} {f.slack_events:5d} "
                f"{f.bar_error_std_mm:7.1f} {f.torque_step_median_nm:9.4f}  "
                f"{extra} {f.final_mode} {notes}"
            )


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("case", choices=sorted(CASES))
    parser.add_argument("--json", action="store_true")
    parser.add_argument(
        "--seconds", type=float, default=None, help="cut every hold to this [s] (a quick look)"
    )
    args = parser.parse_args(argv)
    table = CASES[args.case](args.seconds)
    if args.json:
        print(json.dumps({c: {k: vars(v) for k, v in r.items()} for c, r in table.items()}))
    else:
        _print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
