"""Flight scenarios: TOML files in ``configs/scenarios/`` that script a simulated flight.

A scenario starts either hovering at the hanging equilibrium (``start = "hover"``, as the
paper's Section VII) or resting on the ground (``start = "ground"``). Each ``[[step]]`` is
a bar setpoint (``bar_position`` [m], ``bar_yaw_deg``, ``uav_yaw_deg`` [ψ1, …, ψN]
(default: the bar yaw), ``theta_l_deg``, ``hold_s``, and ``timeout_s``, after which the queue moves
on even if the setpoint was not reached), a path (``path = [[x, y, z], …]`` [m] from where the
bar is, ``speed_mps``, ``accel_mps2``, optionally ``jerk_mps3``, ``bar_yaw_deg`` one per point
or one for all, ``theta_l_deg`` and ``hold_s`` at its end; ``supervisor.flight.paths``) or an
operator action (``action = "takeoff"`` —
arm and take off, done when hovering; ``"hover"`` — wait ``hold_s``; ``"land"`` — done
when landed and disarmed; ``"abort"`` — done when landed and disarmed). A ``[control]``
table sets keys of the setup's ``control`` section for this scenario alone (the reference's
rates, take-off height, ..., key by key over the setup's; ``scenario_config``). Each
``[[load]]`` acts on a body of the plant (``body`` "bar" or "payload", "uav1" … "uavN";
``force_n`` and ``torque_nm`` [x, y, z] in the arena frame; ``start_s`` after the scenario
starts, on the plant's clock; ``duration_s``, none: to the end; ``profile`` "steady" or
"gust", ``sim/loads.py``): a push or a gust. Before a scenario flies, ``check_setpoints``
refuses it when a load names a body the setup has not, or a setpoint step cannot be flown
in the setup (the arena, and the feasibility bounds of ``supervisor.flight.feasibility``),
naming the step and the bound.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
    model_validator,
)

from geometry.formation import MAX_VEHICLES, MIN_VEHICLES
from sim.loads import BODIES, ExternalLoad
from sim.plant import layout_of
from supervisor.app.config import (
    Config,
    ConfigError,
    ControlSection,
    FiniteFloat,
    NonNegativeFloat,
    PositiveFloat,
    Vec3,
)
from supervisor.app.config_files import SCENARIO_DIR, shipped_scenarios
from supervisor.app.sim_assembly import plant_params_from_config
from supervisor.flight.operator_requests import MAX_WAYPOINTS_PER_PATH
from supervisor.flight.setpoints import Arena, Setpoint, SetpointError, validate_setpoint
from supervisor.flight.waypoint import Waypoint
from supervisor.flight.waypoint_checks import validate_waypoints


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Step(_Strict):
    """One scripted step: a setpoint (``bar_position``), a path (``path``) or an operator
    action (``action``)."""

    action: Literal["takeoff", "hover", "land", "abort"] | None = None
    bar_position: Vec3 | None = None
    path: Annotated[list[Vec3], Field(min_length=1, max_length=MAX_WAYPOINTS_PER_PATH)] | None = (
        None
    )
    speed_mps: PositiveFloat | None = None
    accel_mps2: PositiveFloat | None = None
    jerk_mps3: PositiveFloat | None = None
    bar_yaw_deg: FiniteFloat | list[FiniteFloat] = 0.0
    uav_yaw_deg: (
        Annotated[list[FiniteFloat], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)] | None
    ) = None
    theta_l_deg: FiniteFloat = 0.0
    hold_s: NonNegativeFloat = 5.0
    timeout_s: PositiveFloat | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> Step:
        kinds = [k for k in ("action", "bar_position", "path") if getattr(self, k) is not None]
        if len(kinds) != 1:
            raise ValueError(
                "a step is exactly one of an 'action', a setpoint ('bar_position') or a "
                f"'path'; this one has {' and '.join(kinds) or 'none'}"
            )
        if self.path is None:
            if isinstance(self.bar_yaw_deg, list):
                raise ValueError("bar_yaw_deg is a list only for a path (one per point)")
            if self.speed_mps is not None or self.accel_mps2 is not None:
                raise ValueError("speed_mps and accel_mps2 belong to a 'path' step")
            return self
        if self.speed_mps is None or self.accel_mps2 is None:
            raise ValueError("a 'path' step needs speed_mps and accel_mps2")
        if isinstance(self.bar_yaw_deg, list) and len(self.bar_yaw_deg) != len(self.path):
            raise ValueError(
                f"bar_yaw_deg: one per point of the path ({len(self.path)}), "
                f"got {len(self.bar_yaw_deg)}"
            )
        if self.uav_yaw_deg is not None:
            raise ValueError("a path's UAVs keep their yaws about the bar's: no uav_yaw_deg")
        return self

    def waypoints(self) -> list[Waypoint]:
        """This path step's waypoints (only for a ``path`` step)."""
        assert self.path is not None
        yaws = (
            self.bar_yaw_deg
            if isinstance(self.bar_yaw_deg, list)
            else [self.bar_yaw_deg] * len(self.path)
        )
        theta = math.radians(self.theta_l_deg)
        return [
            Waypoint((p[0], p[1], p[2]), math.radians(yaw), theta)
            for p, yaw in zip(self.path, yaws, strict=True)
        ]

    def setpoint(self) -> Setpoint:
        """This step as a setpoint (only for a setpoint step)."""
        assert self.bar_position is not None and not isinstance(self.bar_yaw_deg, list)
        bar_yaw = math.radians(self.bar_yaw_deg)
        uav_yaw = (
            tuple(math.radians(yaw) for yaw in self.uav_yaw_deg)
            if self.uav_yaw_deg is not None
            else None  # each UAV the bar's yaw
        )
        return Setpoint(
            (self.bar_position[0], self.bar_position[1], self.bar_position[2]),
            bar_yaw,
            uav_yaw,
            math.radians(self.theta_l_deg),
            self.hold_s,
            self.timeout_s,
        )


class Load(_Strict):
    """An external force and torque on one body of the plant (``sim.loads.ExternalLoad``)."""

    body: str
    force_n: Vec3
    torque_nm: Vec3 = [0.0, 0.0, 0.0]
    start_s: NonNegativeFloat = 0.0
    duration_s: PositiveFloat | None = None
    profile: Literal["steady", "gust"] = "steady"

    @field_validator("body")
    @classmethod
    def _known_body(cls, body: str) -> str:
        if body not in BODIES:
            raise ValueError(f"one of {', '.join(BODIES)}, not {body!r}")
        return body

    @model_validator(mode="after")
    def _gust_ends(self) -> Load:
        if self.profile == "gust" and self.duration_s is None:
            raise ValueError("a gust needs a duration_s")
        return self

    def external_load(self) -> ExternalLoad:
        """This load for the plant."""
        f, t = self.force_n, self.torque_nm
        return ExternalLoad(
            self.body,
            (f[0], f[1], f[2]),
            (t[0], t[1], t[2]),
            self.start_s,
            self.duration_s,
            self.profile,
        )


class Scenario(_Strict):
    """A scripted flight."""

    name: str
    start: Literal["hover", "ground"]
    start_bar_position: Vec3 = [0.0, 0.0, 1.0]
    start_bar_yaw_deg: FiniteFloat = 0.0
    control: ControlSection | None = None
    """Keys of the setup's ``control`` section set for this scenario (the others stay)."""
    load: list[Load] = []
    """External loads on the plant's bodies (pushes, gusts)."""
    step: Annotated[list[Step], Field(min_length=1)]

    @model_validator(mode="after")
    def _actions_fit_the_start(self) -> Scenario:
        if self.start == "hover" and any(s.action == "takeoff" for s in self.step):
            raise ValueError("a scenario starting in hover cannot take off")
        return self


def scenario_path(name: str) -> Path:
    """A scenario by name (``configs/scenarios/NAME.toml``) or by path."""
    path = Path(name)
    if path.suffix == ".toml" or path.parent != Path("."):
        return path
    return SCENARIO_DIR / f"{name}.toml"


def load_scenario(name: str) -> Scenario:
    """Read and validate a scenario; raises ``ConfigError`` naming the bad key."""
    path = scenario_path(name)
    try:
        with path.open("rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        known = ", ".join(shipped_scenarios())
        raise ConfigError(f"no scenario {name!r} (shipped: {known})") from None
    except OSError as error:
        raise ConfigError(f"cannot read scenario {path}: {error.strerror}") from error
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: not valid TOML: {error}") from error
    try:
        return Scenario.model_validate(data)
    except ValidationError as error:
        problems = [
            f"{'.'.join(str(p) for p in item['loc']) or '(top level)'}: {item['msg']}"
            for item in error.errors()
        ]
        raise ConfigError(f"invalid scenario {path.name}:\n  " + "\n  ".join(problems)) from None


def _merged(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in over.items():
        below = merged.get(key)
        both_tables = isinstance(value, dict) and isinstance(below, dict)
        merged[key] = _merged(below, value) if both_tables else value  # type: ignore[arg-type]
    return merged


def scenario_config(config: Config, scenario: Scenario) -> Config:
    """``config`` with the scenario's ``[control]`` keys set over its own, validated as a
    whole again (raises ``ConfigError`` naming the key)."""
    if scenario.control is None:
        return config
    control = _merged(config.control.model_dump(), scenario.control.model_dump(exclude_unset=True))
    try:
        return Config.model_validate({**config.model_dump(), "control": control})
    except ValidationError as error:
        problems = [f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}" for e in error.errors()]
        raise ConfigError(
            f"scenario {scenario.name} in setup {config.name}:\n  " + "\n  ".join(problems)
        ) from None


def check_setpoints(scenario: Scenario, config: Config) -> None:
    """Raise ``ConfigError`` naming the first load on a body ``config``'s plant does not
    have, or the first setpoint step it cannot fly (outside its arena, or an equilibrium
    beyond its bounds), before anything flies."""
    bodies = layout_of(plant_params_from_config(config)).body_names
    for number, load in enumerate(scenario.load, start=1):
        if load.body not in bodies:
            raise ConfigError(
                f"scenario {scenario.name}, load {number}: setup {config.name} has no body "
                f"{load.body!r} (its bodies: {', '.join(bodies)})"
            )
    params = config.system.to_params()
    arena = Arena.between(config.arena.min_m, config.arena.max_m)
    bounds = config.setpoint_bounds()
    for number, step in enumerate(scenario.step, start=1):
        if step.action is not None:
            continue
        try:
            if step.path is None:
                validate_setpoint(step.setpoint(), params, arena, bounds)
            else:
                validate_waypoints(step.waypoints(), params, arena, bounds)
        except SetpointError as error:
            raise ConfigError(
                f"scenario {scenario.name}, step {number}: cannot be flown in setup "
                f"{config.name}: {error}"
            ) from None


def scenario_duration_s(scenario: Scenario, transit_s: float = 6.0) -> float:
    """A rough length of the flight [s] (holds plus a transit per step), for progress bars."""
    return sum(step.hold_s + transit_s for step in scenario.step)
