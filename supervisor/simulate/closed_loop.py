"""The closed-loop simulator: the service's tick path flown against the physics plant,
faster than real time.

Per 20 ms tick: the plant (RK4, 1 kHz) advances, the mocap model captures frames at its
rate and delivers them after its latency, ``MocapFusion`` filters them, ``estimate_state``
assembles x, and the very ``FlightCore`` the service runs decides the commands, which the
plant receives as thrust and body torque (the paper's direct actuator path). A scenario
script plays the operator.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from mocap.qtm_protocol import MocapFrame as QtmFrame
from sim.measurement import MocapFrame as SimFrame
from sim.measurement import MocapModel
from sim.plant import Plant, resting_state
from sim.truth import TruthStats
from sim.world import qtm_poses
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
)
from supervisor.app.config import Config
from supervisor.app.sim_assembly import (
    mocap_params_from_config,
    plant_params_from_config,
    qtm_names_of_plant_bodies,
)
from supervisor.flight.core import FlightCore, TickResult
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import Event, Mode
from supervisor.flight.setpoints import SetpointError
from supervisor.logs.flight_log import FlightLogSink, formation_header, open_flight_log
from supervisor.runtime.tick_driver import TickDriver
from supervisor.simulate.path_metrics import PathTracking
from supervisor.simulate.scenarios import Scenario, Step, check_setpoints, scenario_config

TICK_S = 0.02
STEP_TIMEOUT_S = 60.0


def qtm_frame(frame: SimFrame, qtm_names: Mapping[str, str]) -> QtmFrame:
    """A simulated mocap frame as the QTM client would deliver it (µs capture stamp,
    receive time = delivery time), each plant body under its QTM name (``qtm_names``)."""
    bodies = qtm_poses(frame, qtm_names)
    return QtmFrame(
        frame.frame_number, round(frame.capture_time_s * 1e6), bodies, frame.delivery_time_s
    )


@dataclass
class SimulationResult:
    """The outcome of one simulated flight."""

    completed: bool
    sim_time_s: float
    wall_time_s: float
    final_mode: str
    truth: TruthStats
    paths: PathTracking = field(default_factory=PathTracking)
    messages: list[str] = field(default_factory=list)
    log_path: Path | None = None

    @property
    def realtime_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


# Modes a scenario never asks for but an abort step: a flight that enters one has failed.
UNPLANNED_ENDS = frozenset({Mode.ABORT, Mode.PX4_LANDING, Mode.KILLED})


class ScenarioScript:
    """Plays a scenario's steps as an operator would, one tick at a time."""

    def __init__(self, scenario: Scenario) -> None:
        self.steps = list(scenario.step)
        self.index = 0
        self.messages: list[str] = []
        self._started_s: float | None = None
        self._budget_s = 0.0
        self.failed = False

    @property
    def done(self) -> bool:
        return self.failed or self.index >= len(self.steps)

    def advance(self, core: FlightCore, now_s: float) -> None:
        """Start the current step, or finish it when its condition holds."""
        if self.done:
            return
        step = self.steps[self.index]
        if self._started_s is None:
            self._started_s = now_s
            first = self.index
            self._start(step, core, now_s)
            self._budget_s = sum(
                (s.timeout_s or STEP_TIMEOUT_S) + s.hold_s
                for s in self.steps[first : self.index + 1]
            )
            return
        if core.modes.mode in UNPLANNED_ENDS and step.action != "abort":
            self._fail(f"step {self.index + 1}: the flight ended in {core.modes.mode.value}")
            return
        if self._finished(step, core, now_s):
            self.index += 1
            self._started_s = None
            self.advance(core, now_s)
            return
        budget = self._budget_s
        if core.modes.mode in (Mode.DISARMED, Mode.KILLED) and step.action not in ("land", "abort"):
            self._fail(f"step {self.index + 1}: the system is {core.modes.mode.value}")
        elif now_s - self._started_s > budget:
            self._fail(f"step {self.index + 1} did not finish within {budget:.0f} s")

    def _fail(self, message: str) -> None:
        self.messages.append(message)
        self.failed = True

    def _start(self, step: Step, core: FlightCore, now_s: float) -> None:
        if step.action is None:
            # Queue the following setpoint and path steps too, so the queue flows from one to
            # the next.
            while True:
                try:
                    _queue(self.steps[self.index], core)
                except SetpointError as error:
                    self._fail(f"step {self.index + 1}: setpoints refused: {error}")
                    return
                if self.index + 1 >= len(self.steps) or self.steps[self.index + 1].action:
                    return
                self.index += 1
        elif step.action == "takeoff":
            for request in (Event.ARM, Event.TAKEOFF):
                result = core.request(request, now_s)
                if not result.accepted:
                    self._fail(f"{request.value} refused: {result.reason}")
                    return
        elif step.action in ("land", "abort"):
            result = core.request(Event(step.action), now_s)
            if not result.accepted:
                self._fail(f"{step.action} refused: {result.reason}")

    def _finished(self, step: Step, core: FlightCore, now_s: float) -> bool:
        assert self._started_s is not None
        mode = core.modes.mode
        if step.action is None:
            return core.queue.active is None and not core.queue.queued
        if step.action == "takeoff":
            return mode is Mode.HOVER
        if step.action == "hover":
            return now_s - self._started_s >= step.hold_s
        return mode is Mode.DISARMED


def _queue(step: Step, core: FlightCore) -> None:
    """Queue a setpoint or path step (raises ``SetpointError`` when refused)."""
    if step.path is None:
        core.queue_setpoints([step.setpoint()])
        return
    assert step.speed_mps is not None and step.accel_mps2 is not None
    core.queue_path(step.waypoints(), step.speed_mps, step.accel_mps2, step.jerk_mps3, step.hold_s)


class ClosedLoop:
    """Plant, mocap model, fusion and tick core wired together on simulated time."""

    def __init__(
        self,
        config: Config,
        controller: str = "centralized",
        seed: int | None = None,
    ) -> None:
        self.config = config
        self.plant = Plant(plant_params_from_config(config))
        self.mocap = MocapModel(mocap_params_from_config(config, seed))
        self._qtm_names = qtm_names_of_plant_bodies(config)
        self.driver = TickDriver(
            flight_core_from_config(config, controller, clock=time.thread_time),
            fusion_from_config(config),
            body_names_from_config(config),
        )
        self.now_s = 0.0

    @property
    def core(self) -> FlightCore:
        """The tick core the driver runs."""
        return self.driver.core

    def place(self, scenario: Scenario) -> None:
        """Put the plant where the scenario starts (hanging equilibrium, or on the ground)."""
        position = scenario.start_bar_position
        yaw = math.radians(scenario.start_bar_yaw_deg)
        if scenario.start == "ground":
            self.plant.place_resting((position[0], position[1]), yaw)
        else:
            params = self.config.system.to_params()
            reference = FormationReference(
                (position[0], position[1], position[2]), yaw, (yaw,) * params.n_vehicles, 0.0
            )
            eq = formation_equilibrium(params, reference)
            vehicles = range(1, params.n_vehicles + 1)
            self.plant.place_hanging(
                [eq.uav_position(i) for i in vehicles], [yaw] * params.n_vehicles
            )

    def resting_heights(self) -> tuple[float, ...]:
        """Heights of the payload's and then each UAV's centre [m] when all rest on the
        ground."""
        x = resting_state(self.plant.params)
        layout = self.plant.layout
        names = (layout.payload_name, *layout.uav_names)
        return tuple(float(x[layout.body_slice(name)][2]) for name in names)

    def estimate(self) -> Estimate:
        """Advance the mocap pipeline to ``now_s`` and estimate the state there."""
        self._fuse_frames()
        return self.driver.estimate_at(self.now_s)

    def decide(self) -> TickResult:
        """The tick at ``now_s`` on the frames delivered by then. The plant's vehicles have
        no arming of their own: landed (``disarming``), they are disarmed by the next tick,
        as a flight process hears its vehicles before it decides."""
        self._fuse_frames()
        if self.core.modes.mode is Mode.DISARMING:
            self.core.vehicles_disarmed(self.now_s)
        return self.driver.decide(self.now_s)

    def _fuse_frames(self) -> None:
        for frame in self.mocap.poll(self.now_s):
            self.driver.fusion.update(qtm_frame(frame, self._qtm_names))

    def advance_plant(self, until_s: float) -> None:
        """Step the plant to ``until_s``, capturing mocap frames when they are due."""
        while self.plant.time_s < until_s - 1e-9:
            next_capture = self.mocap.next_capture_time_s
            stop = min(until_s, max(next_capture, self.plant.time_s + self.plant.step_s))
            self.plant.advance(stop - self.plant.time_s)
            if self.mocap.due(self.plant.time_s):
                self.mocap.capture(self.plant.truth())
        self.now_s = until_s

    def apply(self, result: TickResult) -> None:
        """Hand the tick's commands to the plant (motors off: zero thrust and torque)."""
        for uav, command in enumerate(result.commands, start=1):
            if command.motors_on:
                self.plant.command(uav, command.thrust_n, command.torque_nm)
            else:
                self.plant.command(uav, 0.0, np.zeros(3))


def run_scenario(
    config: Config,
    scenario: Scenario,
    controller: str = "centralized",
    seed: int | None = None,
    log_path: Path | None = None,
    progress: Callable[[float], None] | None = None,
    observe: Callable[[TickResult], None] | None = None,
) -> SimulationResult:
    """Fly ``scenario`` on the plant; ``progress`` receives the simulated time each second,
    ``observe`` every tick's result. The scenario's ``[control]`` keys apply over the
    setup's. Raises ``ConfigError`` before anything flies when they do not validate or a
    setpoint step cannot be flown."""
    config = scenario_config(config, scenario)
    check_setpoints(scenario, config)
    loop = ClosedLoop(config, controller, seed)
    loop.place(scenario)
    for load in scenario.load:
        loop.plant.add_load(load.external_load())
    script = ScenarioScript(scenario)
    layout = loop.plant.layout
    truth = TruthStats(loop.resting_heights()[0], (layout.payload_name, *layout.uav_names))
    paths = PathTracking()
    header = {
        "setup": config.name,
        "scenario": scenario.name,
        "controller": controller,
        **formation_header(loop.core.params),
    }
    log: FlightLogSink | None = open_flight_log(log_path, header) if log_path else None
    loop.driver.log = log
    started = time.perf_counter()
    # Let the filters converge on a still system before anyone acts.
    loop.advance_plant(0.2)
    if scenario.start == "hover":
        loop.core.start_in_hover(loop.estimate(), loop.now_s, loop.resting_heights())
    last_progress = 0.0
    try:
        while True:
            result = loop.decide()
            loop.apply(result)
            if observe is not None:
                observe(result)
            script.messages.extend(str(notice) for notice in result.notices)
            script.advance(loop.core, loop.now_s)
            loop.driver.finish(result)  # as the service does after a tick
            truth.update(loop.plant, loop.core.modes.mode.airborne)
            paths.update(
                loop.core.path_progress(loop.now_s),
                loop.plant.body(layout.payload_name).position_m,
            )
            if script.done:
                break
            loop.advance_plant(loop.now_s + TICK_S)
            if progress is not None and loop.now_s - last_progress >= 1.0:
                last_progress = loop.now_s
                progress(loop.now_s)
    finally:
        if log is not None:
            log.close()
    return SimulationResult(
        completed=not script.failed,
        sim_time_s=loop.now_s,
        wall_time_s=time.perf_counter() - started,
        final_mode=loop.core.modes.mode.value,
        truth=truth,
        paths=paths,
        messages=script.messages,
        log_path=log.path if log is not None else None,
    )


def result_summary(result: SimulationResult, controller: str) -> dict[str, Any]:
    """The truth-side figures of ``simulate --json`` (the log adds the tracking figures)."""
    t = result.truth
    return {
        "controller": controller,
        "completed": result.completed,
        "final_mode": result.final_mode,
        "sim_time_s": result.sim_time_s,
        "wall_time_s": result.wall_time_s,
        "realtime_factor": result.realtime_factor,
        "slack_events": t.slack_events,
        "max_tilt_deg": t.max_tilt_deg,
        "min_tension_n": t.min_tension_n,
        "min_tension_airborne_n": t.min_tension_airborne_n,
        "moving_rmse_m": result.paths.moving_rmse_m,
        "overshoot_m": result.paths.overshoot_m,
        "messages": result.messages,
    }
