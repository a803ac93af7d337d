"""Typed configuration: TOML files validated by pydantic, frozen after load.

A setup is one TOML file (the shipped ones in ``configs/``). A file may name
another with ``extends = "other.toml"`` (relative to itself); its own tables are merged
over the other's, key by key. Command-line overrides ``--set section.key=value`` are
applied last, with values parsed as TOML literals (``--set system.cable_length=[1.0, 1.1]``).
Reading and merging is ``supervisor.app.config_files`` (standard library only); this module
validates.

Every error names the offending key; nothing is applied from an invalid setup.
"""

from __future__ import annotations

import ipaddress
import math
from collections.abc import Sequence
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

from controllers.formation_params import FormationParams, PayloadParams, formation_from_bar
from controllers.params import (
    InputLimits,
    MpcSettings,
    MpcWeights,
    ReferenceLead,
    StateBound,
    UavParams,
)
from controllers.qp.registry import BACKEND_NAMES
from controllers.uav_pd import UavPdGains
from geometry.formation import MAX_VEHICLES, MIN_VEHICLES
from supervisor.agents.fleet_security import FleetSecurity, unprotected
from supervisor.app.config_files import CONFIG_DIR, TOKEN_ENV, ConfigError, read_setup
from supervisor.flight.feasibility import FeasibilitySettings, SetpointBounds
from supervisor.flight.reference_shaping import RateLimits

PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
PositiveVec3 = Annotated[list[PositiveFloat], Field(min_length=3, max_length=3)]

# Re-exported: what the setup files are and where, for the modules that validate them.
__all__ = ["CONFIG_DIR", "TOKEN_ENV", "Config", "ConfigError", "load_config"]

LOOPBACK = "127.0.0.1"
ZENOH_ENDPOINT = r"^(tcp|tls|udp|quic)/[^\s/]+:\d{1,5}$"


def host_port(address: str) -> tuple[str, int]:
    """ "host:port" (already validated) as (host, port)."""
    host, _, port = address.rpartition(":")
    return host, int(port)


def listens_beyond_loopback(host: str) -> bool:
    """``host`` (a bind address) is reachable from other machines."""
    if host.lower() == "localhost":
        return False
    try:
        return not ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return True  # a host name: whatever it resolves to, assume the network


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


def _per_vehicle(value: Any, n_vehicles: int, key: str, *, one_each: bool) -> tuple[Any, ...]:
    """``value`` for every vehicle, or (``one_each``) its items, one per vehicle."""
    if not one_each:
        return (value,) * n_vehicles
    if len(value) != n_vehicles:
        raise ValueError(f"{key} takes one value or {n_vehicles} (one per UAV), got {len(value)}")
    return tuple(value)


PerVehicle = Annotated[list[PositiveFloat], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)]
BAR_KEYS = ("bar_mass", "bar_d1", "bar_d2", "bar_inertia")


class PayloadSection(_Section):
    """A rigid payload other than the paper's bar, carried by one UAV per attachment: its
    mass [kg], its inertia about its CoM in its own frame [kg m²] (three principal moments
    or the whole matrix), and where each cable is fixed, in that frame from its CoM [m]."""

    mass: PositiveFloat
    inertia: PositiveVec3 | Annotated[list[Vec3], Field(min_length=3, max_length=3)]
    attachments: Annotated[list[Vec3], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)]

    def to_params(self) -> PayloadParams:
        """The controllers' payload (raises ``ValueError`` for a geometry no model takes)."""
        if isinstance(self.inertia[0], list):
            rows = tuple(_vector3(row) for row in self.inertia)
        else:
            a, b, c = self.inertia
            rows = ((a, 0.0, 0.0), (0.0, b, 0.0), (0.0, 0.0, c))
        return PayloadParams(
            mass_kg=self.mass,
            inertia_kgm2=(rows[0], rows[1], rows[2]),
            attachments_m=tuple(_vector3(point) for point in self.attachments),
        )


def _vector3(values: list[float]) -> tuple[float, float, float]:
    return (values[0], values[1], values[2])


class SystemSection(_Section):
    """Physical parameters of the UAVs, the payload and the cables (SI units). The payload
    is the paper's bar (``bar_mass``, ``bar_d1``, ``bar_d2``, ``bar_inertia``: two UAVs) or
    any rigid body (``[system.payload]``: one UAV per attachment), never both; per-UAV
    values are one value for all or a list of one per UAV."""

    uav_mass: PositiveFloat | PerVehicle
    uav_inertia: (
        PositiveVec3
        | Annotated[list[PositiveVec3], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)]
    )
    bar_mass: PositiveFloat | None = None
    bar_d1: NonNegativeFloat | None = None
    bar_d2: NonNegativeFloat | None = None
    bar_inertia: PositiveFloat | None = None
    payload: PayloadSection | None = None
    cable_length: PositiveFloat | PerVehicle
    gravity: PositiveFloat = 9.81

    @model_validator(mode="after")
    def _one_payload(self) -> SystemSection:
        given = [key for key in BAR_KEYS if getattr(self, key) is not None]
        if self.payload is not None and given:
            raise ValueError(
                f"the payload is the bar ({', '.join(given)}) or [system.payload], not both"
            )
        if self.payload is None and len(given) != len(BAR_KEYS):
            missing = [key for key in BAR_KEYS if key not in given]
            raise ValueError(
                f"a bar needs {', '.join(missing)} (or describe another payload in "
                "[system.payload])"
            )
        if self.payload is None and (self.bar_d1 or 0.0) + (self.bar_d2 or 0.0) <= 0.0:
            raise ValueError("bar_d1 + bar_d2 (the bar's length) must be > 0")
        self.to_params()  # every per-UAV list its length, a payload some model takes
        return self

    @property
    def n_vehicles(self) -> int:
        """N: two for the bar, one per attachment of any other payload."""
        return 2 if self.payload is None else len(self.payload.attachments)

    def to_params(self) -> FormationParams:
        """The controllers' plain parameter object."""
        n = self.n_vehicles
        masses = _per_vehicle(
            self.uav_mass, n, "uav_mass", one_each=isinstance(self.uav_mass, list)
        )
        inertias = _per_vehicle(
            self.uav_inertia, n, "uav_inertia", one_each=isinstance(self.uav_inertia[0], list)
        )
        lengths = _per_vehicle(
            self.cable_length, n, "cable_length", one_each=isinstance(self.cable_length, list)
        )
        uavs = tuple(
            UavParams(mass, _vector3(inertia))
            for mass, inertia in zip(masses, inertias, strict=True)
        )
        if self.payload is not None:
            return FormationParams(uavs, self.payload.to_params(), lengths, self.gravity)
        assert self.bar_mass and self.bar_inertia is not None  # _one_payload
        return formation_from_bar(
            uavs=(uavs[0], uavs[1]),
            bar_mass_kg=self.bar_mass,
            d1_m=self.bar_d1 or 0.0,
            d2_m=self.bar_d2 or 0.0,
            bar_inertia_kgm2=self.bar_inertia,
            cable_lengths_m=(lengths[0], lengths[1]),
            gravity_mps2=self.gravity,
        )


class ArenaSection(_Section):
    """The flight volume (arena frame, z up), used as the geofence."""

    min_m: Vec3
    max_m: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> ArenaSection:
        if any(lo >= hi for lo, hi in zip(self.min_m, self.max_m, strict=True)):
            raise ValueError("arena.min_m must be below arena.max_m on every axis")
        return self


class StateBoundEntry(_Section):
    """One bound of the state set X or X_N, on the absolute state (paper order)."""

    index: Annotated[int, Field(ge=0)]
    lower: FiniteFloat
    upper: FiniteFloat

    @model_validator(mode="after")
    def _ordered(self) -> StateBoundEntry:
        if self.lower > self.upper:
            raise ValueError("lower must not exceed upper")
        return self


class CentralizedWeights(_Section):
    """Table I: Q = diag(q_bar, q_uav, …, q_uav) (one q_uav per UAV), R = diag(r) with
    ``r`` one UAV's four weights (every UAV's) or all 4N, Q_N = terminal_scale * Q. The
    state bounds index the formation's 12 + 12N state (checked against N by ``Config``)."""

    q_bar: Annotated[list[NonNegativeFloat], Field(min_length=12, max_length=12)]
    q_uav: Annotated[list[NonNegativeFloat], Field(min_length=12, max_length=12)]
    r: Annotated[list[PositiveFloat], Field(min_length=4, max_length=4 * MAX_VEHICLES)]
    terminal_scale: PositiveFloat
    state_bounds: list[StateBoundEntry] = []
    terminal_bounds: list[StateBoundEntry] = []

    def check_for(self, n_vehicles: int) -> None:
        """Raise ``ValueError`` unless ``r`` and the bounds fit N UAVs."""
        if len(self.r) not in (4, 4 * n_vehicles):
            raise ValueError(
                f"mpc.centralized.r takes 4 weights (every UAV's) or {4 * n_vehicles} "
                f"(4 for each of the {n_vehicles} UAVs), got {len(self.r)}"
            )
        _check_indices(self.state_bounds + self.terminal_bounds, 12 + 12 * n_vehicles)

    def to_weights(self, n_vehicles: int) -> MpcWeights:
        q = (*self.q_bar, *self.q_uav * n_vehicles)
        r = tuple(self.r) * (n_vehicles if len(self.r) == 4 else 1)
        return MpcWeights(q_diag=q, r_diag=r, terminal_scale=self.terminal_scale)


class DecentralizedWeights(_Section):
    """Table II: Q = diag(q_uav, q_payload), R = diag(r), Q_N = terminal_scale * Q."""

    q_uav: Annotated[list[NonNegativeFloat], Field(min_length=12, max_length=12)]
    q_payload: Annotated[list[NonNegativeFloat], Field(min_length=6, max_length=6)]
    r: Annotated[list[PositiveFloat], Field(min_length=4, max_length=4)]
    terminal_scale: PositiveFloat
    state_bounds: list[StateBoundEntry] = []
    terminal_bounds: list[StateBoundEntry] = []
    reference_lead_s: Annotated[
        list[Annotated[float, Field(ge=0.0, le=2.0)]], Field(min_length=2, max_length=2)
    ] = [0.0, 0.0]
    """Beyond the paper: [position, yaw] lead of the agents' setpoint along the bar's
    measured velocity and yaw rate (``ReferenceLead``); [0, 0] is Section V."""

    @model_validator(mode="after")
    def _indices(self) -> DecentralizedWeights:
        _check_indices(self.state_bounds + self.terminal_bounds, 18)
        return self

    def to_weights(self) -> MpcWeights:
        q = (*self.q_uav, *self.q_payload)
        return MpcWeights(q_diag=q, r_diag=tuple(self.r), terminal_scale=self.terminal_scale)


def _check_indices(bounds: list[StateBoundEntry], nx: int) -> None:
    for bound in bounds:
        if bound.index >= nx:
            raise ValueError(f"state bound index {bound.index} is outside the {nx}-state vector")


def _bounds(entries: list[StateBoundEntry]) -> tuple[StateBound, ...]:
    return tuple(StateBound(e.index, e.lower, e.upper) for e in entries)


class MpcSection(_Section):
    """The MPC problem (MPC) of Section IV: horizon, step, input set U, weights."""

    horizon: Annotated[int, Field(ge=1, le=200)] = 30
    dt_s: PositiveFloat = 0.02
    thrust_min_n: PositiveFloat
    thrust_max_n: PositiveFloat
    torque_max_nm: PositiveFloat = 1.0
    qp_backend: str = "hpipm"
    late_after_s: PositiveFloat = 0.015
    prepared_yaw_tolerance_rad: Annotated[float, Field(ge=0.0, le=0.1)] = 0.0
    # The mocap-to-command delay the state is predicted across (controllers/delay.py).
    delay_s: Annotated[float, Field(ge=0.0, le=0.2, allow_inf_nan=False)] = 0.0
    # The model's weight in the UAVs' body-rate estimates (controllers/rate_filter.py).
    rate_filter_weight: Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)] = 0.0
    # The UAVs' slow body rates from the attitude's change per tick (controllers/rate_filter.py).
    rate_crossover_s: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0
    # The integral action on the held reference's error (controllers/integral_action.py).
    integral_gain_per_s: Annotated[float, Field(ge=0.0, le=5.0, allow_inf_nan=False)] = 0.0
    # The disturbance-force observer's time constant, 0 = off (controllers/force_observer.py).
    force_observer_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = 0.0
    # The most force it may put on any one body [N].
    force_observer_max_n: Annotated[float, Field(gt=0.0, le=50.0, allow_inf_nan=False)] = 5.0
    centralized: CentralizedWeights
    decentralized: DecentralizedWeights

    @model_validator(mode="after")
    def _thrust_range(self) -> MpcSection:
        if self.thrust_min_n >= self.thrust_max_n:
            raise ValueError("mpc.thrust_min_n must be below mpc.thrust_max_n")
        if self.qp_backend not in BACKEND_NAMES:
            raise ValueError(f"qp_backend must be one of {', '.join(BACKEND_NAMES)}")
        return self

    def settings(self, controller: str, n_vehicles: int) -> MpcSettings:
        """The plain settings of the ``centralized`` (for ``n_vehicles`` UAVs) or the
        ``decentralized`` controller (one agent's)."""
        centralized = controller == "centralized"
        section = self.centralized if centralized else self.decentralized
        return MpcSettings(
            horizon=self.horizon,
            dt_s=self.dt_s,
            weights=(
                self.centralized.to_weights(n_vehicles)
                if centralized
                else self.decentralized.to_weights()
            ),
            limits=InputLimits(self.thrust_min_n, self.thrust_max_n, self.torque_max_nm),
            state_bounds=_bounds(section.state_bounds),
            terminal_bounds=_bounds(section.terminal_bounds),
            qp_backend=self.qp_backend,
            late_after_s=self.late_after_s,
            prepared_yaw_tolerance_rad=self.prepared_yaw_tolerance_rad,
            delay_s=self.delay_s,
            integral_gain_per_s=self.integral_gain_per_s,
            force_observer_s=self.force_observer_s,
            force_observer_max_n=self.force_observer_max_n,
            rate_filter_weight=self.rate_filter_weight,
            rate_crossover_s=self.rate_crossover_s,
            reference_lead=ReferenceLead(*self.decentralized.reference_lead_s)
            if controller == "decentralized"
            else ReferenceLead(),
        )


class MocapSection(_Section):
    """The motion-capture source (a QTM RT server) and the state filter's tuning."""

    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 22223
    # The payload's body, then one per UAV (unset: "bar" or "payload", "uav1" … "uavN").
    bodies: Annotated[
        list[Annotated[str, Field(min_length=1)]],
        Field(min_length=MIN_VEHICLES + 1, max_length=MAX_VEHICLES + 1),
    ] = ["bar", "uav1", "uav2"]
    # How the frames come: "udp" (QTM's stream to a local port) or "tcp" (over the command
    # connection, which a sender off the path between QTM and us cannot inject into).
    transport: Literal["udp", "tcp"] = "udp"
    # The UDP port QTM's stream comes from; unset: learned from the first frame of each
    # session. Datagrams from any other port are dropped and counted. With sim.embedded the
    # world's server is used (as for host and port) and its port is learned.
    server_udp_port: Annotated[int, Field(ge=1, le=65535)] | None = None
    # Filter tuning (mocap/fusion.py): white-acceleration PSDs and measurement noise.
    # Lower PSDs smooth velocities and rates (the MPC weighs them) at the price of lag in
    # fast manoeuvres; these suit the bar's slow swing and the paper's gentle references
    # (measured with `simulate --scenario paper`, both controllers).
    position_accel_psd: PositiveFloat = 0.2
    angular_accel_psd: PositiveFloat = 2.0
    position_noise_m: PositiveFloat = 0.0005
    attitude_noise_deg: PositiveFloat = 0.1
    max_age_s: PositiveFloat = 0.05
    # The innovation gate (mocap/fusion.py): a pose further from a body's prediction than
    # ½·accel·h² + sigmas·σ, or turned further from its estimate than rate·h + sigmas·σ,
    # is refused (h: time since the body's last fused pose; σ: predicted and measurement
    # noise). docs/safety.md.
    gate_max_accel_mps2: PositiveFloat = 30.0
    gate_max_angular_rate_deg_s: PositiveFloat = 720.0
    gate_sigmas: PositiveFloat = 6.0
    # Lock the 20 ms deadlines to the mocap frames and start each tick on its frame's arrival
    # (supervisor/runtime/phase_lock.py): the frame then waits under a millisecond for its tick, not
    # up to a frame period; false: ticks by the clock alone.
    phase_lock: bool = True

    @model_validator(mode="after")
    def _distinct_bodies(self) -> MocapSection:
        if len(set(self.bodies)) != len(self.bodies):
            raise ValueError("mocap.bodies: distinct names (the payload, UAV 1, UAV 2, …)")
        return self


class SimMocapSection(_Section):
    """The simulated motion capture: rate, noise (1σ), latency and tracking losses."""

    rate_hz: PositiveFloat = 100.0
    position_sigma_m: NonNegativeFloat = 0.0005
    orientation_sigma_deg: NonNegativeFloat = 0.1
    latency_s: NonNegativeFloat = 0.005
    dropout_probability: Annotated[float, Field(ge=0.0, le=1.0)] = 0.002
    burst_probability: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    burst_frames: Annotated[
        list[Annotated[int, Field(ge=1)]], Field(min_length=2, max_length=2)
    ] = [
        10,
        50,
    ]

    @model_validator(mode="after")
    def _burst_range(self) -> SimMocapSection:
        if self.burst_frames[0] > self.burst_frames[1]:
            raise ValueError("sim.mocap.burst_frames must be [min, max] with min <= max")
        return self


class SimSection(_Section):
    """The embedded simulator's plant: its step, actuators and deliberate mismatch against
    the ``system`` section the controllers use (the plant is built from ``system`` first)."""

    # true: `serve` starts the simulated world (plant, PX4s, QTM) in its own process and
    # connects to it on loopback; false: it connects to the lab's real QTM and PX4s.
    embedded: bool = False
    # The address the world listens on (its QTM server, its simulated PX4s): loopback; a
    # test that puts an agent in a network namespace of its own names one both reach.
    host: Annotated[str, Field(pattern=r"^\d{1,3}(\.\d{1,3}){3}$")] = "127.0.0.1"
    # The world's flight controllers: "simulated" (our PX4 model, fast, no firmware) or
    # "px4_sitl" (one real PX4 v1.15.4 SITL process per UAV, driven by the plant).
    vehicles: Literal["simulated", "px4_sitl"] = "simulated"
    # An extracted PX4 SITL install (bin/px4, etc/); the env var UAVBAR_PX4_DIR overrides;
    # unset: the cache, filled from the project's firmware archive on first use.
    px4_dir: str | None = None
    # true: each real PX4 SITL writes a ULog of each flight, from arm to disarm, to
    # log.folder/px4/uavN/log/ (for PX4's own view of a flight; off: the writes cost a core).
    px4_ulog: bool = False
    seed: Annotated[int, Field(ge=0)] = 0
    step_s: PositiveFloat = 0.001
    motor_time_constant_s: NonNegativeFloat = 0.02
    uav_thrust_max_n: PositiveFloat = 30.0
    # The simulated PX4s' own calibration against the supervisor's vehicles.thrust_max_n:
    # true thrust = scale × commanded (1.0: the supervisor's calibration is right).
    px4_thrust_scale: PerVehicle = [1.0, 1.0]  # one per UAV (unset: 1.0 each)
    # The simulated PX4s refuse to arm without fresh external vision (the forwarded mocap),
    # as PX4 does when its estimator has no position.
    px4_require_vision: bool = True
    uav_mass_scale: PerVehicle = [1.0, 1.0]  # one per UAV (unset: 1.0 each)
    bar_mass_scale: PositiveFloat = 1.0
    bar_com_shift_m: FiniteFloat = 0.0
    drag_linear_n_s_per_m: NonNegativeFloat = 0.0
    wind_mean_mps: Vec3 = [0.0, 0.0, 0.0]
    wind_gust_std_mps: Annotated[list[NonNegativeFloat], Field(min_length=3, max_length=3)] = [
        0.0,
        0.0,
        0.0,
    ]
    mocap: SimMocapSection = SimMocapSection()


Port = Annotated[int, Field(ge=0, le=65535)]


class VehiclesSection(_Section):
    """The PX4s, one per UAV: MAVLink links, command mode and calibration (one value or one per
    vehicle). ``ports`` are the local UDP ports the links listen on (PX4's offboard/API
    link sends to 14540+i); ``addresses`` ("host:port"), when set, are contacted first."""

    # rates: thrust + body rates (SET_ATTITUDE_TARGET), what current PX4 takes over MAVLink
    # (v1.15 ignores actuator setpoints); actuator: thrust + torques, PX4 ≤ 1.13 (the paper's).
    command_mode: Literal["actuator", "rates"] = "rates"
    mocap_message: Literal["vision_position_estimate", "odometry"] = "vision_position_estimate"
    # The local address the links' UDP sockets bind: this computer's interface facing the
    # vehicles, so that no other network reaches them. Unset: loopback with sim.embedded
    # (the embedded world is on loopback); a lab must name its interface.
    bind_host: str | None = None
    # One per UAV (unset: 14540 + i and system ids 1 … N).
    ports: Annotated[list[Port], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)] = [
        14540,
        14541,
    ]
    addresses: (
        Annotated[list[str], Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES)] | None
    ) = None
    system_ids: Annotated[
        list[Annotated[int, Field(ge=1, le=255)]],
        Field(min_length=MIN_VEHICLES, max_length=MAX_VEHICLES),
    ] = [1, 2]
    # Thrust [N] at PX4's normalized 1.0 and torque [N m] at ±1.0: identify them per vehicle.
    thrust_max_n: PositiveFloat | PerVehicle = 26.0
    torque_max_nm: PositiveFloat | PerVehicle = 1.0
    ack_timeout_s: PositiveFloat = 0.5
    retries: Annotated[int, Field(ge=1, le=10)] = 3
    link_loss_s: PositiveFloat = 0.75
    # COM_OF_LOSS_T: how long PX4 waits for the next setpoint before its offboard-loss
    # failsafe (COM_OBL_RC_ACT = land) takes over. Short, so a held command is not flown
    # for long when the control loop stops.
    offboard_loss_timeout_s: Annotated[float, Field(ge=0.1, le=60.0)] = 0.5
    # PX4's event definitions (the firmware build's etc/extras/all_events.json.xz), to show
    # its reasons (arming refusals, failsafes) in words. The embedded world brings its own.
    px4_events: str | None = None
    # MAVLink 2 signing (docs/reference/mavlink-signing.md): each vehicle's own key, from
    # signing_keys (a file only its owner may read: `uavbar-supervisor keys` makes one);
    # PX4 gets it by SETUP_SIGNING before arming and from then on takes only signed frames.
    # A PX4 without a key yet is reached at vehicles.addresses (or the embedded world's).
    signing: bool = False
    signing_keys: str = "~/.config/uavbar-supervisor/signing-keys"

    @field_validator("bind_host")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                ipaddress.IPv4Address(value)
            except ValueError:
                raise ValueError(f"{value!r} is not an IPv4 address of this computer") from None
        return value

    @field_validator("addresses")
    @classmethod
    def _host_port(cls, values: list[str] | None) -> list[str] | None:
        for value in values or []:
            host, _, port = value.rpartition(":")
            if not host or not port.isdigit() or not 0 < int(port) < 65536:
                raise ValueError(f"{value!r} is not host:port")
        return values


class ApiSection(_Section):
    """The HTTP API and dashboard. ``token`` unset: the env var ``UAVBAR_TOKEN``, else one
    is generated and printed at start."""

    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=0, le=65535)] = 8000
    token: Annotated[str, Field(min_length=8)] | None = None
    allowed_hosts: list[Annotated[str, Field(min_length=1)]] | None = None
    """The names a request's Host header may carry (IP addresses always pass: DNS
    rebinding sends a name). Unset: localhost, this machine's host name and fully
    qualified name, and ``host``."""
    max_body_bytes: Annotated[int, Field(ge=1024, le=16 * 1024 * 1024)] = 65536
    """The largest request body read; a larger one is refused (413) before it is read."""
    tls_cert_file: str | None = None
    """A PEM certificate (chain): with ``tls_key_file`` the API serves HTTPS and WSS."""
    tls_key_file: str | None = None

    @model_validator(mode="after")
    def _both_tls_files(self) -> ApiSection:
        if (self.tls_cert_file is None) != (self.tls_key_file is None):
            raise ValueError("tls_cert_file and tls_key_file are set together or not at all")
        return self


class SafetySection(_Section):
    """Thresholds of the safety monitors that a setup may want to tune (docs/safety.md)."""

    max_tilt_deg: Annotated[float, Field(gt=0.0, lt=90.0)] = 45.0
    """A UAV tilted further than this in flight: abort. Setpoints whose equilibrium tilts
    a UAV beyond it, less ``control.tilt_margin_deg``, are refused."""
    max_bar_yaw_error_deg: Annotated[float, Field(ge=0.0, lt=180.0)] = 20.0
    """The bar's yaw this far from its reference while hovering or tracking under the
    decentralized MPC: the centralized MPC takes over. 0 turns the hand-over off."""
    slack_time_s: PositiveFloat = 0.5
    """A cable slack (shorter than its length by 5 cm) this long without a break, while
    hovering or tracking: abort."""
    slack_window_s: PositiveFloat = 10.0
    slack_in_window_s: PositiveFloat = 0.5
    """Slack episodes adding up to this much within the last ``slack_window_s``: abort
    (short episodes, repeated, never reach ``slack_time_s``)."""
    max_refused_poses: Annotated[int, Field(ge=1)] = 10
    """A body's poses refused this many times in a row in flight (the mocap's innovation
    gate, or a frozen stream): blind, each PX4 lands on its own. 10 = 0.1 s at 100 Hz, the
    coast limit."""

    @model_validator(mode="after")
    def _window_holds_its_slack(self) -> SafetySection:
        if self.slack_in_window_s > self.slack_window_s:
            raise ValueError("slack_in_window_s must not exceed slack_window_s")
        return self


class RatesSection(_Section):
    """How fast the reference may move (``supervisor.flight.reference_shaping``): the bar's
    speed and acceleration, yaws and θ_l."""

    position_mps: PositiveFloat = 0.3
    acceleration_mps2: PositiveFloat = 0.3
    yaw_deg_s: PositiveFloat = 20.0
    theta_l_deg_s: PositiveFloat = 10.0

    def to_limits(self) -> RateLimits:
        """The reference shaper's plain limits."""
        return RateLimits(
            position_mps=self.position_mps,
            acceleration_mps2=self.acceleration_mps2,
            yaw_radps=math.radians(self.yaw_deg_s),
            theta_l_radps=math.radians(self.theta_l_deg_s),
        )


class TakeoffRatesSection(RatesSection):
    """The reference's rates while the bar is lifted: slower, gentler."""

    position_mps: PositiveFloat = 0.25
    acceleration_mps2: PositiveFloat = 0.15


class AbortRatesSection(RatesSection):
    """The reference's rates in an abort: the bar is lowered a little faster."""

    position_mps: PositiveFloat = 0.4


class PdSection(_Section):
    """The UAVs' own PD controller (``controllers.uav_pd``), flown while the cables are
    slack by design (the climb before the lift, the descent after the bar is down)."""

    kp: PositiveFloat = 4.0
    """position gain [1/s²]"""
    kv: PositiveFloat = 3.0
    """velocity gain [1/s]"""
    kr: PositiveFloat = 60.0
    """attitude gain [1/s²]"""
    kw: PositiveFloat = 12.0
    """rate gain [1/s]"""
    max_tilt_deg: Annotated[float, Field(gt=0.0, lt=90.0)] = 25.0

    def to_gains(self) -> UavPdGains:
        """The PD controller's plain gains."""
        return UavPdGains(self.kp, self.kv, self.kr, self.kw, math.radians(self.max_tilt_deg))


class ControlSection(_Section):
    """How the supervisor flies: which setpoints it takes (``supervisor.flight.feasibility``),
    its flight phases and the reference's rates (``supervisor.flight.core.CoreSettings``)."""

    max_theta_l_deg: Annotated[float, Field(ge=0.0, lt=90.0)] = 75.0
    """The largest cable angle θ_l a setpoint may ask for."""
    thrust_margin: Annotated[float, Field(ge=0.0, lt=0.5)] = 0.10
    """A setpoint's equilibrium thrust must stay this fraction of ``mpc.thrust_max_n``
    inside the range ``mpc.thrust_min_n``..``mpc.thrust_max_n``, at both ends."""
    tilt_margin_deg: Annotated[float, Field(ge=0.0, lt=90.0)] = 10.0
    """A setpoint's equilibrium tilt must stay this far below ``safety.max_tilt_deg``."""

    takeoff_height_m: PositiveFloat = 1.0
    """How high the take-off lifts the bar above where it rested."""
    reached_position_m: PositiveFloat = 0.05
    reached_yaw_deg: PositiveFloat = 3.0
    """A setpoint is reached (its hold starts) with the bar this close to it."""
    descend_speed_mps: PositiveFloat = 0.3
    """The UAVs' descent once the bar is down."""
    settle_on_ground_s: NonNegativeFloat = 1.0
    """How long both UAVs stay at their ground height before the landing is over."""
    landing_clearance_m: NonNegativeFloat = 0.3
    """How far outward along the bar each UAV moves before descending beside its end."""
    bumpless_ticks: Annotated[int, Field(ge=1, le=500)] = 15
    """Ticks over which a controller switch blends the inputs."""
    rate_lookahead_steps: Annotated[int, Field(ge=0)] = 3
    """Which step of the MPC's predicted rates a rate-controlled PX4 is sent."""
    acceleration_feed_forward: bool = True
    """The reference carries its profile's acceleration: the UAVs' tilt and thrust that
    the payload's acceleration needs are in the equilibrium the MPC regulates to."""
    preview: bool = True
    """The MPC is given the reference at each stage of its horizon (where a move or a path
    will be), not only the reference now carried on."""
    path_jerk_mps3: PositiveFloat = 2.0
    """A path's jerk along it when its request names none."""
    flight_rates: RatesSection = RatesSection()
    takeoff_rates: TakeoffRatesSection = TakeoffRatesSection()
    abort_rates: AbortRatesSection = AbortRatesSection()
    pd: PdSection = PdSection()

    def feasibility(self) -> FeasibilitySettings:
        """The plain settings of the setpoint check."""
        return FeasibilitySettings(
            max_theta_l_rad=math.radians(self.max_theta_l_deg),
            thrust_margin=self.thrust_margin,
            tilt_margin_rad=math.radians(self.tilt_margin_deg),
        )


class LogSection(_Section):
    """Flight logs: one file per flight, named by its start time."""

    folder: str = "flight-logs"
    format: Literal["jsonl", "mcap"] = "mcap"
    """``jsonl`` (JSON Lines, one line per tick) or ``mcap`` (Foxglove's and our own
    channels: docs/flight-logs.md)."""
    min_free_mb: NonNegativeFloat = 100.0
    """Arming is refused while the log folder has less free space than this [MB] (a
    flight's log and mocap recording take a few MB a minute). Logging is best-effort: a
    disk that fills in flight stops the log, never the flight."""


class FoxgloveSection(_Section):
    """The live Foxglove view: a WebSocket server (foxglove.websocket.v1 or
    foxglove.sdk.v1) on the API's host streaming the flight log's channels to clients with
    the API token, ``ws://HOST:PORT/?token=TOKEN`` (docs/flight-logs.md)."""

    enabled: bool = False
    """Off unless asked for: while a client is subscribed, each tick builds, seals and
    queues its messages (docs/flight-logs.md)."""
    port: Annotated[int, Field(ge=0, le=65535)] = 8765
    """0: a free port, logged at start."""
    host: str | None = None
    """The interface to listen on. None: the API's host while that is loopback, else
    loopback all the same — the view has no TLS, so its token would cross the network in
    clear; name an interface here to open it to a network on purpose."""

    def bind_host(self, api_host: str) -> str:
        """Where the view listens, given the API's host."""
        if self.host is not None:
            return self.host
        return "127.0.0.1" if listens_beyond_loopback(api_host) else api_host


class AgentsSection(_Section):
    """The decentralized agents as processes of their own, one per vehicle, over Zenoh
    (docs/agents.md): ``serve`` is then their ground station."""

    enabled: bool = False
    spawn: bool = True
    """``serve`` starts the agents on this computer (the embedded simulator's way); false
    when each runs elsewhere (``uavbar-supervisor agent --vehicle I`` on its own computer)."""
    ground_endpoint: Annotated[str, Field(pattern=ZENOH_ENDPOINT)] = "tcp/127.0.0.1:0"
    """Where the ground station listens; port 0: a free one (only with ``spawn``)."""
    agent_endpoints: list[Annotated[str, Field(pattern=ZENOH_ENDPOINT)]] | None = None
    """Where each agent listens, UAV 1's first (its peers connect there). Unset: loopback,
    free ports (only with ``spawn``)."""
    fleet: Annotated[str, Field(pattern=r"^[A-Za-z0-9_-]{1,32}$")] = "lab"
    """The fleet's name in every key expression: two fleets on one network never mix."""
    ground_loss_hold_s: PositiveFloat = 3.0
    """Without the ground station, the agents hold the last setpoint this long, then land."""
    peer_timeout_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = 0.25
    """A peer (or the ground station) silent this long is lost."""
    share_plans: bool = True
    """Each agent tells its peers its planned inputs every tick and predicts their vehicles
    with them (false: with their equilibrium's): docs/agents.md, what it buys."""
    command_timeout_s: PositiveFloat = 8.0
    """The longest an operator request waits for every agent's answer (arming takes ~2 s)."""
    tls_folder: str | None = None
    """The fleet's certificates (``uavbar-supervisor fleet-certs``): Zenoh over TLS, each
    process known by its certificate, under access control (docs/agents.md, "Access").
    Required beyond loopback; then every endpoint is ``tls/``."""

    @model_validator(mode="after")
    def _ports_named_when_elsewhere(self) -> AgentsSection:
        if not self.spawn and self.ground_endpoint.endswith(":0"):
            raise ValueError("ground_endpoint: name its port when the agents run elsewhere")
        return self

    def security(self, identity: str, n_vehicles: int) -> FleetSecurity | None:
        """Process ``identity``'s TLS (None without ``tls_folder``); ConfigError when its
        files are not there."""
        if self.tls_folder is None:
            return None
        security = FleetSecurity(Path(self.tls_folder), identity, self.fleet, n_vehicles)
        missing = security.missing_files()
        if missing:
            raise ConfigError(
                f"agents.tls_folder: no {', '.join(path.name for path in missing)} in "
                f"{self.tls_folder} (uavbar-supervisor fleet-certs makes them)"
            )
        return security

    @model_validator(mode="after")
    def _tls_beyond_loopback(self) -> AgentsSection:
        endpoints = [self.ground_endpoint, *(self.agent_endpoints or [])]
        check_fleet_endpoints(endpoints, self.tls_folder)
        return self


def check_fleet_endpoints(endpoints: Sequence[str], tls_folder: str | None) -> None:
    """Refuse a fleet in clear beyond loopback, and a half-encrypted one (ValueError)."""
    clear = unprotected(endpoints)
    if clear:
        raise ValueError(
            f"{', '.join(clear)}: beyond loopback the fleet runs over TLS with access "
            "control: tls/HOST:PORT endpoints and agents.tls_folder (uavbar-supervisor "
            "fleet-certs makes its certificates)"
        )
    encrypted = [e for e in endpoints if e.startswith("tls/")]
    if encrypted and tls_folder is None:
        raise ValueError(f"{', '.join(encrypted)}: tls/ endpoints need agents.tls_folder")
    in_clear = [e for e in endpoints if not e.startswith("tls/")]
    if tls_folder is not None and in_clear:
        raise ValueError(
            "agents.tls_folder is set: every endpoint is tls/ (the fleet's access control "
            f"knows its members by their certificates), not {', '.join(in_clear)}"
        )


class Config(_Section):
    """One complete setup."""

    name: str = "unnamed"
    system: SystemSection
    arena: ArenaSection
    mpc: MpcSection
    mocap: MocapSection = MocapSection()
    vehicles: VehiclesSection = VehiclesSection()
    api: ApiSection = ApiSection()
    log: LogSection = LogSection()
    foxglove: FoxgloveSection = FoxgloveSection()
    safety: SafetySection = SafetySection()
    control: ControlSection = ControlSection()
    sim: SimSection = SimSection()
    agents: AgentsSection = AgentsSection()

    @model_validator(mode="before")
    @classmethod
    def _per_vehicle_defaults(cls, data: Any) -> Any:
        """Fill the per-vehicle keys a setup leaves unset with one entry per UAV of its
        system (the field defaults are the two-UAV bar's)."""
        n = _vehicles_described(data)
        if n is None:
            return data  # the system section's own errors will say why
        payload = "bar" if "payload" not in data["system"] else "payload"
        defaults: dict[str, dict[str, Any]] = {
            "mocap": {"bodies": [payload, *(f"uav{i}" for i in range(1, n + 1))]},
            "vehicles": {
                "ports": [14540 + k for k in range(n)],
                "system_ids": list(range(1, n + 1)),
            },
            "sim": {"px4_thrust_scale": [1.0] * n, "uav_mass_scale": [1.0] * n},
        }
        filled = dict(data)
        for section, keys in defaults.items():
            given = filled.get(section, {})
            if isinstance(given, dict):
                filled[section] = keys | given
        return filled

    @model_validator(mode="after")
    def _one_entry_per_vehicle(self) -> Config:
        n = self.system.n_vehicles
        v, sim = self.vehicles, self.sim
        per_vehicle: dict[str, Sequence[Any] | None] = {
            "vehicles.ports": v.ports,
            "vehicles.system_ids": v.system_ids,
            "vehicles.addresses": v.addresses,
            "agents.agent_endpoints": self.agents.agent_endpoints,
            "vehicles.thrust_max_n": v.thrust_max_n if isinstance(v.thrust_max_n, list) else None,
            "vehicles.torque_max_nm": (
                v.torque_max_nm if isinstance(v.torque_max_nm, list) else None
            ),
            "sim.px4_thrust_scale": sim.px4_thrust_scale,
            "sim.uav_mass_scale": sim.uav_mass_scale,
        }
        for key, values in per_vehicle.items():
            if values is not None and len(values) != n:
                raise ValueError(f"{key}: one per UAV ({n}), got {len(values)}")
        if len(self.mocap.bodies) != n + 1:
            raise ValueError(
                f"mocap.bodies: the payload's and one per UAV ({n + 1} names), "
                f"got {len(self.mocap.bodies)}"
            )
        self.mpc.centralized.check_for(n)
        return self

    @model_validator(mode="after")
    def _links_fit_the_world(self) -> Config:
        v = self.vehicles
        if self.sim.embedded and v.bind_host and not ipaddress.ip_address(v.bind_host).is_loopback:
            raise ValueError("vehicles.bind_host: the embedded world is on loopback (127.0.0.1)")
        if self.control.rate_lookahead_steps > self.mpc.horizon:
            raise ValueError("control.rate_lookahead_steps must not exceed mpc.horizon")
        if self.control.tilt_margin_deg >= self.safety.max_tilt_deg:
            raise ValueError(
                "control.tilt_margin_deg must be below safety.max_tilt_deg (no setpoint would"
                " be flyable)"
            )
        if self.sim.embedded and self.sim.vehicles == "px4_sitl" and v.signing:
            raise ValueError(
                "vehicles.signing: PX4 v1.15.4 SITL cannot sign (MAVLink signing came with v1.17)"
            )
        return self

    def mpc_settings(self, controller: str) -> MpcSettings:
        """The plain settings of ``controller`` for this setup's UAVs."""
        return self.mpc.settings(controller, self.system.n_vehicles)

    def per_vehicle(self, value: float | list[float]) -> tuple[float, ...]:
        """A per-vehicle key's value for each UAV (one value: the same for all)."""
        n = self.system.n_vehicles
        return tuple(value) if isinstance(value, list) else (value,) * n

    def setpoint_bounds(self) -> SetpointBounds:
        """What a setpoint's equilibrium must respect in this setup: the MPC's thrust range,
        the abort tilt and the ``control`` section's margins and θ_l maximum."""
        return SetpointBounds(
            self.mpc.thrust_min_n,
            self.mpc.thrust_max_n,
            math.radians(self.safety.max_tilt_deg),
            self.control.feasibility(),
        )

    def link_bind_host(self) -> str:
        """The address the vehicle links bind (loopback for the embedded world); raises
        ``ConfigError`` for a lab that has not named its interface."""
        if self.vehicles.bind_host is not None:
            return self.vehicles.bind_host
        if self.sim.embedded:
            return LOOPBACK
        raise ConfigError(
            "vehicles.bind_host: required for a lab (this computer's address on the "
            "vehicles' network); binding every interface would let any network reach them"
        )


def _vehicles_described(data: Any) -> int | None:
    """N of a raw setup: one UAV per attachment of ``[system.payload]``, else two (the bar);
    None when the system section is not yet a table to read it from."""
    system = data.get("system") if isinstance(data, dict) else None
    if not isinstance(system, dict):
        return None
    payload = system.get("payload")
    if payload is None:
        return MIN_VEHICLES
    attachments = payload.get("attachments") if isinstance(payload, dict) else None
    if not isinstance(attachments, list):
        return None
    return len(attachments) if MIN_VEHICLES <= len(attachments) <= MAX_VEHICLES else None


def _describe(error: ValidationError) -> str:
    lines = []
    for item in error.errors():
        key = ".".join(str(part) for part in item["loc"]) or "(top level)"
        message = item["msg"]
        if item["type"] == "extra_forbidden":
            message = "unknown key"
        elif item["type"] == "missing":
            message = "required key is missing"
        lines.append(f"{key}: {message}")
    return "invalid configuration:\n  " + "\n  ".join(lines)


def load_config(path: Path, overrides: Sequence[str] = ()) -> Config:
    """Read, merge, override and validate a setup. Raises ``ConfigError`` naming the key."""
    data = read_setup(path, overrides).data
    try:
        config = Config.model_validate(data)
    except ValidationError as error:
        raise ConfigError(_describe(error)) from None
    _check_finite(data, ())
    return config


def _check_finite(node: Any, path: tuple[str, ...]) -> None:
    """Reject NaN and inf anywhere, including keys pydantic would coerce silently."""
    if isinstance(node, dict):
        for key, value in node.items():
            _check_finite(value, (*path, str(key)))
    elif isinstance(node, list):
        for value in node:
            _check_finite(value, path)
    elif isinstance(node, float) and not math.isfinite(node):
        raise ConfigError(f"invalid configuration:\n  {'.'.join(path)}: must be finite")
