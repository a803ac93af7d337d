"""The simulator's physics plant: N quadrotors (2 to 8) and a rigid payload on N elastic
cables — the paper's two UAVs and bar, or a plate or a frame hung by its corners.

This is the world the controllers are tested against, deliberately not the controllers'
model (Section II-B's rigid cables and planar bar rotation): here every body is a full
6-DOF rigid body, the cables are stiff unilateral spring-dampers that can go slack, the
motors lag and saturate, and everything can rest on the ground.

* UAVs: mass, full inertia tensor with gyroscopic terms, quaternion attitude
  (renormalized every step), thrust along body +z (FLU), body torque; first-order lag
  and saturation on the commands.
* Payload: a rigid body with a full inertia tensor (the bar may spin about its own axis);
  cable i is tied at its own attachment point (the bar's ends: d1 from the CoM for cable 1,
  d2 for cable 2).
* Cables: T = max(0, k s + c ṡ) while stretched, 0 when slack.
* Ground at z = 0: UAVs stand on their feet (or lie on their rotor tips), the payload on
  its contact points (the bar on its ends); penalty contact with friction and rolling
  resistance so resting is stable. The bodies do not collide with each other.
* Optional drag, wind and parameter mismatch (``sim/plant_params.py``), and external
  loads on any body — a steady push or a gust (``sim/loads.py``, ``add_load``).

Integration is fixed-step RK4 (1 kHz default) in numba kernels (``sim/plant_kernels.py``,
where the state-vector layout is documented). Frames: ENU arena (z up), FLU UAV bodies.
UAVs are numbered 1 to N as in the paper; the bodies are named "uav1" … "uavN" and "bar"
(or "payload" for a payload that is not the bar: ``PlantLayout``).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from geometry.arrays import FloatArray
from geometry.formation import MAX_VEHICLES, MIN_VEHICLES
from geometry.frames import (
    quaternion_from_rotation,
    rotation_from_euler_zyx,
    rotation_from_quaternion,
)
from sim import plant_kernels as pk
from sim.loads import ExternalLoad
from sim.plant_params import BarParams, ContactParams, PayloadBodyParams, PlantParams
from sim.plant_statics import (
    bar_axis,
    cable_forces_n,
    hanging_guess,
    no_roll,
    rotation_between,
    solve_hanging,
)
from sim.ports import AirframeState

BODY_SIZE = pk.BODY_SIZE
ACT_SIZE = pk.ACT_SIZE


@dataclass(frozen=True)
class PlantLayout:
    """Where the bodies and actuators of ``n_uavs`` UAVs and a payload named
    ``payload_name`` sit in the plant's state vector: UAV i (1 … N) is body i − 1, the
    payload body N, each ``BODY_SIZE`` entries; then each UAV's ``ACT_SIZE`` actuators."""

    n_uavs: int
    payload_name: str = "bar"

    def __post_init__(self) -> None:
        if not MIN_VEHICLES <= self.n_uavs <= MAX_VEHICLES:
            raise ValueError(f"the plant flies {MIN_VEHICLES} to {MAX_VEHICLES} UAVs")

    @functools.cached_property
    def uav_names(self) -> tuple[str, ...]:
        """("uav1", …, "uavN")."""
        return tuple(f"uav{i}" for i in range(1, self.n_uavs + 1))

    @functools.cached_property
    def body_names(self) -> tuple[str, ...]:
        """Every body in the state's order: the UAVs, then the payload."""
        return (*self.uav_names, self.payload_name)

    @property
    def state_size(self) -> int:
        """Length of the state vector."""
        return int(pk.state_size(self.n_uavs))

    @property
    def actuator_offset(self) -> int:
        """Where the actuators start in the state vector."""
        return int(pk.actuator_offset(self.n_uavs))

    def body_index(self, name: str) -> int:
        """The index of body ``name`` (ValueError if the plant has no such body)."""
        try:
            return self.body_names.index(name)
        except ValueError:
            raise ValueError(f"unknown body {name!r}; bodies are {self.body_names}") from None

    def uav_index(self, uav: int) -> int:
        """The index (0 … N − 1) of UAV ``uav`` (1 … N)."""
        if not 1 <= uav <= self.n_uavs:
            raise ValueError(f"UAVs are numbered 1 to {self.n_uavs}, got {uav}")
        return uav - 1

    def body_slice(self, name: str) -> slice:
        """The 13 entries of body ``name`` in the state vector: position ENU [m] (3),
        velocity ENU [m/s] (3), quaternion (w, x, y, z) body → ENU (4), body rates
        [rad/s] (3)."""
        start = self.body_index(name) * BODY_SIZE
        return slice(start, start + BODY_SIZE)

    def actuator_slice(self, uav: int) -> slice:
        """The 4 actuator entries of UAV ``uav``: lagged thrust [N], lagged body torque FLU
        [N m] (3)."""
        start = self.actuator_offset + self.uav_index(uav) * ACT_SIZE
        return slice(start, start + ACT_SIZE)


BAR_LAYOUT = PlantLayout(2)
"""The paper's two UAVs and bar; the module-level names below are its layout."""
BODY_NAMES = BAR_LAYOUT.body_names
STATE_SIZE = BAR_LAYOUT.state_size
ACT_OFFSET = BAR_LAYOUT.actuator_offset


def body_slice(name: str) -> slice:
    """``BAR_LAYOUT.body_slice``: body ``name`` of the two UAVs and the bar."""
    return BAR_LAYOUT.body_slice(name)


def actuator_slice(uav: int) -> slice:
    """``BAR_LAYOUT.actuator_slice``: UAV ``uav`` (1 or 2) of the two UAVs and the bar."""
    return BAR_LAYOUT.actuator_slice(uav)


def layout_of(params: PlantParams) -> PlantLayout:
    """The state layout of the plant of ``params``."""
    return PlantLayout(params.n_uavs, params.payload_name)


# --- Parameter packing -------------------------------------------------------------------


def _pack_contact(P: FloatArray, pb: int, contact: ContactParams) -> None:
    P[pb + pk.B_KN] = contact.stiffness_n_per_m
    P[pb + pk.B_CN] = contact.damping_n_s_per_m
    P[pb + pk.B_MU] = contact.friction_coefficient
    P[pb + pk.B_VEPS] = contact.stiction_velocity_mps
    P[pb + pk.B_CTMAX] = contact.friction_max_damping_n_s_per_m
    P[pb + pk.B_MUROLL] = contact.rolling_coefficient
    P[pb + pk.B_WEPS] = contact.rolling_velocity_radps
    P[pb + pk.B_CRMAX] = contact.rolling_max_damping_n_m_s


def pack_parameters(
    params: PlantParams, *, ground: bool = True, anchored: Sequence[bool] | None = None
) -> FloatArray:
    """The flat parameter vector the kernels read (layout: the G_*/B_*/C_*/L_* offsets of
    ``sim/plant_kernels.py``); ``anchored[i]`` holds UAV i + 1 still."""
    n = params.n_uavs
    held = _anchored(n, anchored)
    wind = params.wind
    n_wind = 0 if wind.is_calm else wind.n_components
    P = np.zeros(pk.parameter_size(n, n_wind))
    P[pk.G_NUAV] = n
    payload = params.payload_body()
    for b in range(n + 1):
        pb = int(pk.body_block(b))
        if b < n:
            uav = params.uavs[b]
            mass = uav.mass_kg
            J = np.array(uav.inertia_kgm2, dtype=float)
            points = np.array(uav.landing_gear_body_m + uav.frame_points_body_m, dtype=float)
            radius = 0.0
            contact = params.uav_contact
            drag = (uav.drag_linear_n_s_per_m, uav.drag_quadratic_n_s2_per_m2)
            P[pb + pk.B_ANCHOR] = 1.0 if held[b] else 0.0
        else:
            mass = payload.mass_kg
            J = np.array(payload.inertia_kgm2, dtype=float)
            points = np.array(payload.contact_points_body_m, dtype=float)
            radius = payload.contact_radius_m
            contact = params.bar_contact
            drag = (payload.drag_linear_n_s_per_m, payload.drag_quadratic_n_s2_per_m2)
        P[pb + pk.B_MASS] = mass
        P[pb + pk.B_J : pb + pk.B_J + 9] = J.ravel()
        P[pb + pk.B_JINV : pb + pk.B_JINV + 9] = np.linalg.inv(J).ravel()
        P[pb + pk.B_NCONT] = len(points)
        P[pb + pk.B_CPTS : pb + pk.B_CPTS + points.size] = points.ravel()
        P[pb + pk.B_CRAD] = radius
        _pack_contact(P, pb, contact)
        P[pb + pk.B_DRAG1], P[pb + pk.B_DRAG2] = drag
    for c in range(n):
        pc = int(pk.cable_block(n, c))
        cable = params.cables[c]
        P[pc + pk.C_L0] = cable.length_m
        P[pc + pk.C_K] = cable.stiffness_n_per_m
        P[pc + pk.C_C] = cable.damping_n_s_per_m
        P[pc + pk.C_UAVPT : pc + pk.C_UAVPT + 3] = params.uavs[c].cable_attachment_body_m
        P[pc + pk.C_PAYLOADPT : pc + pk.C_PAYLOADPT + 3] = payload.attachments_body_m[c]
        pl = int(pk.lag_block(n, c))
        P[pl + pk.L_TAU_F] = params.uavs[c].thrust_time_constant_s
        P[pl + pk.L_TAU_T] = params.uavs[c].torque_time_constant_s
    P[pk.G_GRAV] = params.gravity_mps2
    P[pk.G_GROUND] = 1.0 if ground else 0.0
    P[pk.G_NWIND] = n_wind
    ow = int(pk.wind_offset(n))
    P[ow : ow + 3] = wind.mean_velocity_mps
    if n_wind:
        amplitude, omega, phase = wind.components()
        base = ow + 3
        block = 3 * n_wind
        P[base : base + block] = amplitude.ravel()
        P[base + block : base + 2 * block] = omega.ravel()
        P[base + 2 * block : base + 3 * block] = phase.ravel()
    return P


def _anchored(n_uavs: int, anchored: Sequence[bool] | None) -> tuple[bool, ...]:
    if anchored is None:
        return (False,) * n_uavs
    if len(anchored) != n_uavs:
        raise ValueError(f"anchored: one flag per UAV, {n_uavs}, not {len(anchored)}")
    return tuple(anchored)


# --- Value types ---------------------------------------------------------------------------


@dataclass(frozen=True)
class BodyTruth:
    """Ground truth of one body at ``time_s``: position and velocity of its CoM in ENU
    [m, m/s], unit quaternion (w, x, y, z) body → ENU, angular velocity in the body frame
    [rad/s] (all shape (3,) but the quaternion (4,))."""

    name: str
    time_s: float
    position_m: FloatArray
    velocity_mps: FloatArray
    quaternion: FloatArray
    body_rates_radps: FloatArray

    @property
    def rotation(self) -> FloatArray:
        """Rotation matrix body → ENU, shape (3, 3)."""
        return rotation_from_quaternion(self.quaternion)


@dataclass(frozen=True)
class PlantTruth:
    """Every body at one instant (what the motion-capture model samples)."""

    time_s: float
    bodies: Mapping[str, BodyTruth]


@dataclass(frozen=True)
class CableTruth:
    """Per cable (index i − 1: cable i, from UAV i to the payload): tension [N] (never
    negative), stretch beyond the rest length [m] (negative when slack), stretch rate
    [m/s], slack flags."""

    tension_n: tuple[float, ...]
    stretch_m: tuple[float, ...]
    stretch_rate_mps: tuple[float, ...]
    slack: tuple[bool, ...]


@dataclass(frozen=True)
class EnergyBreakdown:
    """Mechanical energy [J]: kinetic (translation + rotation), gravitational (zero at
    z = 0), cable springs and ground-contact springs."""

    kinetic_j: float
    gravitational_j: float
    cable_spring_j: float
    contact_spring_j: float

    @property
    def total_j(self) -> float:
        """The sum of all terms [J]."""
        return self.kinetic_j + self.gravitational_j + self.cable_spring_j + self.contact_spring_j


@dataclass(frozen=True)
class HoverTrim:
    """The saturated commands that hold a placed hanging configuration in equilibrium:
    per UAV (index i − 1: UAV i) thrust [N] and body torque FLU [N m] (shape (3,)), and
    the static cable tensions [N]."""

    thrust_n: tuple[float, ...]
    torque_nm: tuple[FloatArray, ...]
    tension_n: tuple[float, ...]


# --- Configurations --------------------------------------------------------------------------


def _set_pose(x: FloatArray, b: int, position_m: FloatArray, R: FloatArray | None = None) -> None:
    o = b * BODY_SIZE
    x[o : o + 3] = position_m
    x[o + 3 : o + 6] = 0.0
    x[o + 6 : o + 10] = (1.0, 0.0, 0.0, 0.0) if R is None else quaternion_from_rotation(R)
    x[o + 10 : o + 13] = 0.0


def _bar_resting_pose(
    bar: BarParams, contact: ContactParams, g: float, xy: tuple[float, float], yaw: float
) -> tuple[FloatArray, FloatArray]:
    """(CoM [m], rotation) of the bar resting on its two ends."""
    # Static end loads of a bar on two supports: N1 = m g d2/L, N2 = m g d1/L.
    k_bar = contact.stiffness_n_per_m
    z1 = bar.tube_radius_m - bar.mass_kg * g * bar.d2_m / bar.length_m / k_bar
    z2 = bar.tube_radius_m - bar.mass_kg * g * bar.d1_m / bar.length_m / k_bar
    pitch = -math.asin((z2 - z1) / bar.length_m)
    R = rotation_from_euler_zyx(0.0, pitch, yaw)
    com = np.array([xy[0], xy[1], 0.0])
    com[2] = z1 + (z2 - z1) * bar.d1_m / bar.length_m
    return com, R


def _payload_resting_pose(
    payload: PayloadBodyParams,
    contact: ContactParams,
    g: float,
    xy: tuple[float, float],
    yaw: float,
) -> tuple[FloatArray, FloatArray]:
    """(CoM [m], rotation) of a payload resting on all its contact points.

    Each point is a spring of the contact's stiffness k. With the payload's z axis tilted
    to (n_x, n_y, ·) (small, in its yawed frame) and its CoM at height p_z, point j (body
    (x_j, y_j, z_j), a sphere of radius r) sinks δ_j = r − z_j − p_z + n_x x_j + n_y y_j to
    first order, and the loads k δ_j carry the weight with no moment about the CoM: three
    linear equations in (p_z, n_x, n_y), least-norm for points on one line (no tilt across
    it). Raises ValueError when a point would have to pull.
    """
    points = np.array(payload.contact_points_body_m, dtype=float)
    base = payload.contact_radius_m - points[:, 2]
    rows = np.column_stack((-np.ones(len(points)), points[:, 0], points[:, 1]))
    # Σ δ_j = m g / k, Σ δ_j x_j = 0, Σ δ_j y_j = 0 with δ = base + rows @ (p_z, n_x, n_y).
    lever = np.vstack((np.ones(len(points)), points[:, 0], points[:, 1]))
    rhs = np.array([payload.mass_kg * g / contact.stiffness_n_per_m, 0.0, 0.0]) - lever @ base
    unknowns = np.linalg.lstsq(lever @ rows, rhs, rcond=None)[0]
    sink = base + rows @ unknowns
    if np.min(sink) < 0.0:
        raise ValueError(
            "the payload cannot rest on all its contact points (one would have to pull): "
            "its CoM is outside them, or they are far from level"
        )
    p_z, n_x, n_y = (float(v) for v in unknowns)
    z_axis = np.array([n_x, n_y, 1.0])
    tilt = rotation_between(np.array([0.0, 0.0, 1.0]), z_axis / np.linalg.norm(z_axis))
    return np.array([xy[0], xy[1], p_z]), rotation_from_euler_zyx(0.0, 0.0, yaw) @ tilt


def resting_state(
    params: PlantParams,
    payload_position_xy_m: tuple[float, float] = (0.0, 0.0),
    payload_yaw_rad: float = 0.0,
) -> FloatArray:
    """Everything at rest on the ground: the payload's CoM above ``payload_position_xy_m``
    at ``payload_yaw_rad`` (the bar's axis from ENU x), each UAV (yaw = the payload's)
    standing directly above its cable's attachment, cables slack. Bodies sit at their
    static contact penetration (feet assumed symmetric about the CoM) so nothing bounces
    at t = 0. Shape (``layout_of(params).state_size``,)."""
    g = params.gravity_mps2
    n = params.n_uavs
    x = np.zeros(layout_of(params).state_size)
    if params.payload is None:
        com, R = _bar_resting_pose(
            params.bar, params.bar_contact, g, payload_position_xy_m, payload_yaw_rad
        )
    else:
        com, R = _payload_resting_pose(
            params.payload, params.bar_contact, g, payload_position_xy_m, payload_yaw_rad
        )
    _set_pose(x, n, com, R)
    payload = params.payload_body()
    R_uav = rotation_from_euler_zyx(0.0, 0.0, payload_yaw_rad)
    for i, uav in enumerate(params.uavs):
        below = com + R @ np.array(payload.attachments_body_m[i], dtype=float)
        feet = np.array(uav.landing_gear_body_m, dtype=float)
        sink = uav.mass_kg * g / (len(feet) * params.uav_contact.stiffness_n_per_m)
        position = np.array([below[0], below[1], -feet[:, 2].min() - sink])
        _set_pose(x, i, position, R_uav)
    return x


def _attitude_from_thrust_direction(b3: FloatArray, yaw_rad: float) -> FloatArray:
    """The rotation whose body z is ``b3`` and whose Z-Y-X yaw (2) is ``yaw_rad``: body x
    lies in the vertical plane at heading ψ, so b1 ∝ (−sin ψ, cos ψ, 0) × b3."""
    c = np.array([-math.sin(yaw_rad), math.cos(yaw_rad), 0.0])
    b1 = np.cross(c, b3)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(b3, b1)
    return np.column_stack((b1, b2, b3))


def hanging_state(
    params: PlantParams,
    uav_positions_m: Sequence[FloatArray],
    uav_yaws_rad: Sequence[float] | None = None,
) -> tuple[FloatArray, HoverTrim]:
    """The system hovering at rest: UAV CoMs at ``uav_positions_m`` (ENU [m], one of shape
    (3,) per UAV) with yaws ``uav_yaws_rad`` (default 0), the payload hanging below in
    static equilibrium on its stretched cables (a bar without roll about its own axis),
    each UAV tilted so its thrust balances its weight and its cable, the actuators already
    at the trim. Returns the state (``layout_of(params).state_size``,) and the trim; the
    trim is exact unless it exceeds a saturation.

    Raises ValueError when a UAV is a cable's length or more to the side of its
    attachment, no equilibrium is found, or the one found has a slack cable.
    """
    n = params.n_uavs
    p = [np.asarray(position, dtype=float).reshape(3) for position in uav_positions_m]
    yaws = (0.0,) * n if uav_yaws_rad is None else tuple(float(yaw) for yaw in uav_yaws_rad)
    if len(p) != n or len(yaws) != n:
        raise ValueError(f"{n} UAVs need {n} positions and yaws, not {len(p)} and {len(yaws)}")
    g = params.gravity_mps2
    payload = params.payload_body()
    weight = payload.mass_kg * g
    attachments = np.array(payload.attachments_body_m, dtype=float)
    attach_uav = [np.array(u.cable_attachment_body_m, dtype=float) for u in params.uavs]
    k = np.array([c.stiffness_n_per_m for c in params.cables])
    l0 = np.array([c.length_m for c in params.cables])
    axis = bar_axis(attachments)
    R_uav = [rotation_from_euler_zyx(0.0, 0.0, yaw) for yaw in yaws]
    anchors = np.array([p[c] + R_uav[c] @ attach_uav[c] for c in range(n)])
    # Every cable taut in the guess matters: at zero tension a pendulum's lateral
    # stiffness vanishes and the Jacobian is singular. Each starts stretched by the whole
    # weight.
    com, R = hanging_guess(anchors, attachments, l0 + weight / k, yaws[0])
    for _ in range(50):
        com, R = solve_hanging(com, R, anchors, attachments, k, l0, weight)
        if axis is not None:
            R = no_roll(axis, R @ axis)
        lengths = np.linalg.norm(anchors - (com + attachments @ R.T), axis=1)
        for c in range(n):
            if lengths[c] <= l0[c]:
                raise ValueError(f"no hanging equilibrium with every cable taut (cable {c + 1})")
        forces = cable_forces_n(com, R, anchors, attachments, k, l0)
        new_R = []
        for c, uav in enumerate(params.uavs):
            # The cable pulls the UAV by −f; its thrust carries weight and cable.
            lift = uav.mass_kg * g * np.array([0.0, 0.0, 1.0]) + forces[c]
            new_R.append(_attitude_from_thrust_direction(lift / np.linalg.norm(lift), yaws[c]))
        # Off-CoM attachments move with the attitude: iterate to the fixed point.
        change = max(float(np.max(np.abs(new_R[c] - R_uav[c]))) for c in range(n))
        R_uav = new_R
        anchors = np.array([p[c] + R_uav[c] @ attach_uav[c] for c in range(n)])
        if change < 1e-12:
            break
    else:
        raise ValueError("hanging equilibrium: UAV attitudes did not converge")
    layout = layout_of(params)
    x = np.zeros(layout.state_size)
    _set_pose(x, n, com, R)
    forces = cable_forces_n(com, R, anchors, attachments, k, l0)
    thrusts: list[float] = []
    torques: list[FloatArray] = []
    for c, uav in enumerate(params.uavs):
        _set_pose(x, c, p[c], R_uav[c])
        thrust_vec = uav.mass_kg * g * np.array([0.0, 0.0, 1.0]) + forces[c]
        thrust = min(float(np.linalg.norm(thrust_vec)), uav.thrust_max_n)
        # Trim torque cancels the cable's moment about the CoM: τ = −r_a × Rᵀ(−f).
        torque = np.cross(attach_uav[c], R_uav[c].T @ forces[c])
        limit = np.array(uav.torque_max_nm, dtype=float)
        torque = np.clip(torque, -limit, limit)
        a = layout.actuator_slice(c + 1)
        x[a.start] = thrust
        x[a.start + 1 : a.stop] = torque
        thrusts.append(thrust)
        torques.append(torque)
    tensions = tuple(float(np.linalg.norm(f)) for f in forces)
    return x, HoverTrim(tuple(thrusts), tuple(torques), tensions)


# --- The plant ---------------------------------------------------------------------------------


class UavPort:
    """One UAV of a ``Plant`` as its flight controller sees it (``sim.ports.AirframePort``)."""

    def __init__(self, plant: Plant, uav: int) -> None:
        self._plant = plant
        self._uav = uav

    @property
    def number(self) -> int:
        """1 … N."""
        return self._uav

    def state(self) -> AirframeState:
        """The current ground truth of this UAV."""
        truth = self._plant.body(f"uav{self._uav}")
        return AirframeState(
            time_s=truth.time_s,
            position_m=truth.position_m,
            velocity_mps=truth.velocity_mps,
            quaternion=truth.quaternion,
            body_rates_radps=truth.body_rates_radps,
            on_ground=self._plant.on_ground(self._uav),
        )

    def command(self, thrust_n: float, torque_nm: FloatArray) -> None:
        """Demand thrust [N] and body torque FLU [N m], held until the next call; the
        plant saturates and lags them."""
        self._plant.command(self._uav, thrust_n, torque_nm)


class Plant:
    """The physics plant, stepped with fixed-step RK4.

    ``ground=False`` removes the ground (free fall). ``anchored[i]`` holds UAV i+1 still
    as a kinematic anchor (tests: a payload hanging from fixed points); an anchored UAV's
    velocity and rates are kept at zero. ``state`` (``layout.state_size``,) defaults to
    ``resting_state(params)``. Time starts at ``time_s``.
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        *,
        ground: bool = True,
        anchored: Sequence[bool] | None = None,
        state: FloatArray | None = None,
        time_s: float = 0.0,
    ) -> None:
        self._params = PlantParams() if params is None else params
        self._layout = layout_of(self._params)
        n = self._layout.n_uavs
        self._anchored = list(_anchored(n, anchored))
        self._P = pack_parameters(self._params, ground=ground, anchored=self._anchored)
        self._x = np.zeros(self._layout.state_size)
        self._cmd = np.zeros(n * ACT_SIZE)
        self._ext = np.zeros((n + 1) * pk.EXT_SIZE)
        self._loads: list[ExternalLoad] = []
        self._t0_s = time_s
        self._steps = 0
        self._diag = np.zeros(pk.diagnostics_size(n))
        self._diag_fresh = False
        self._ports = tuple(UavPort(self, i) for i in range(1, n + 1))
        self.set_state(resting_state(self._params) if state is None else state)

    # -- time and stepping --

    @property
    def params(self) -> PlantParams:
        """The plant's (true) parameters."""
        return self._params

    @property
    def layout(self) -> PlantLayout:
        """Its bodies' names and their places in the state vector."""
        return self._layout

    @property
    def step_s(self) -> float:
        """The RK4 step [s]."""
        return self._params.step_s

    @property
    def time_s(self) -> float:
        """Simulated time [s] (start time + steps × step, so it never drifts)."""
        return self._t0_s + self._steps * self._params.step_s

    def step(self, n_steps: int = 1) -> None:
        """Advance ``n_steps`` RK4 steps with the commands held. Raises FloatingPointError
        if the state stops being finite."""
        if n_steps < 0:
            raise ValueError("n_steps must be ≥ 0")
        h = self._params.step_s
        while n_steps > 0:
            chunk = self._load_chunk(n_steps)
            pk.advance(self._x, self._P, self._cmd, self._ext, self.time_s, h, chunk)
            self._steps += chunk
            n_steps -= chunk
        self._diag_fresh = False
        # One sum instead of a test per entry: NaN or ±inf anywhere makes it non-finite.
        if not math.isfinite(float(self._x.sum())):
            raise FloatingPointError(f"plant state is not finite at t = {self.time_s:.3f} s")

    def _load_chunk(self, n_steps: int) -> int:
        """Set the external loads for the next steps and say for how many of them (at most
        ``n_steps``) they hold: up to the next start or end of a steady load, one step at a
        time while a gust acts (its value at the step's middle)."""
        self._ext[:] = 0.0
        if not self._loads:
            return n_steps
        h = self._params.step_s
        now = self.time_s
        chunk = n_steps
        for load in self._loads:
            for edge in (load.start_s, load.ends_s):
                if edge > now + 1e-9 * h and math.isfinite(edge):
                    chunk = min(chunk, max(1, math.ceil((edge - now) / h - 1e-6)))
            scale = load.scale(now + 0.5 * h)
            if scale == 0.0:
                continue
            if load.profile == "gust":
                chunk = 1
            e = self._layout.body_index(load.body) * pk.EXT_SIZE
            self._ext[e : e + 3] += scale * np.asarray(load.force_n)
            self._ext[e + 3 : e + 6] += scale * np.asarray(load.torque_nm)
        return chunk

    # -- external loads --

    @property
    def loads(self) -> tuple[ExternalLoad, ...]:
        """The external loads in effect or to come, oldest first."""
        return tuple(self._loads)

    def add_load(self, load: ExternalLoad) -> None:
        """Act with ``load`` from its ``start_s`` (plant time) on; loads add up. ValueError
        if the plant has no such body."""
        self._layout.body_index(load.body)
        self._loads.append(load)

    def remove_load(self, load: ExternalLoad) -> None:
        """Stop ``load`` now (ValueError if it is not one of ``loads``)."""
        self._loads.remove(load)

    def clear_loads(self) -> None:
        """No external load any more."""
        self._loads.clear()

    def external_load(
        self, name: str, time_s: float | None = None
    ) -> tuple[FloatArray, FloatArray]:
        """The external force [N] and torque [N m] (world frame) on body ``name`` at
        ``time_s`` (default now), all loads added up."""
        t = self.time_s if time_s is None else time_s
        force, torque = np.zeros(3), np.zeros(3)
        for load in self._loads:
            if load.body == name:
                scale = load.scale(t)
                force += scale * np.asarray(load.force_n)
                torque += scale * np.asarray(load.torque_nm)
        return force, torque

    def advance(self, duration_s: float) -> int:
        """Advance by ``duration_s`` rounded to a whole number of steps; returns the number
        of steps taken (the time advanced is that times ``step_s``)."""
        n_steps = round(duration_s / self._params.step_s)
        self.step(n_steps)
        return n_steps

    # -- inputs --

    def uav(self, i: int) -> UavPort:
        """UAV ``i`` (1 … N) as an ``AirframePort``."""
        return self._ports[self._layout.uav_index(i)]

    def command(self, uav: int, thrust_n: float, torque_nm: FloatArray) -> None:
        """Hold thrust [N] and body torque FLU [N m] on UAV ``uav`` (1 … N) after
        saturation: thrust to [0, thrust_max], each torque axis to ±torque_max."""
        i = self._layout.uav_index(uav)
        torque = [float(v) for v in np.asarray(torque_nm, dtype=float).reshape(3)]
        if not all(math.isfinite(v) for v in (thrust_n, *torque)):
            raise ValueError(f"non-finite command for UAV {uav}: {thrust_n}, {torque}")
        params = self._params.uavs[i]
        self._cmd[4 * i] = min(max(float(thrust_n), 0.0), params.thrust_max_n)
        for axis, (value, limit) in enumerate(zip(torque, params.torque_max_nm, strict=True)):
            self._cmd[4 * i + 1 + axis] = min(max(value, -limit), limit)

    def commanded(self, uav: int) -> tuple[float, FloatArray]:
        """The saturated command held on UAV ``uav``: (thrust [N], torque [N m] (3,))."""
        i = self._layout.uav_index(uav)
        return float(self._cmd[4 * i]), self._cmd[4 * i + 1 : 4 * i + 4].copy()

    def actuator(self, uav: int) -> tuple[float, FloatArray]:
        """What the rotors produce now, after the lag: (thrust [N], torque [N m] (3,))."""
        s = self._layout.actuator_slice(uav)
        values = self._x[s]
        return float(values[0]), values[1:].copy()

    # -- ground truth --

    def body(self, name: str) -> BodyTruth:
        """Ground truth of body ``name`` (of ``layout.body_names``); arrays are copies."""
        o = self._layout.body_index(name) * BODY_SIZE
        x = self._x
        return BodyTruth(
            name=name,
            time_s=self.time_s,
            position_m=x[o : o + 3].copy(),
            velocity_mps=x[o + 3 : o + 6].copy(),
            quaternion=x[o + 6 : o + 10].copy(),
            body_rates_radps=x[o + 10 : o + 13].copy(),
        )

    def truth(self) -> PlantTruth:
        """All bodies now."""
        return PlantTruth(self.time_s, {name: self.body(name) for name in self._layout.body_names})

    def _diagnostics(self) -> FloatArray:
        if not self._diag_fresh:
            pk.diagnostics(self._x, self._P, self._diag)
            self._diag_fresh = True
        return self._diag

    def cables(self) -> CableTruth:
        """Cable tensions, stretch and slack flags now."""
        d = self._diagnostics()
        n = self._layout.n_uavs

        def per_cable(block: int) -> FloatArray:
            values: FloatArray = d[block * n : (block + 1) * n]
            return values

        return CableTruth(
            tension_n=tuple(float(v) for v in per_cable(pk.D_TENSION)),
            stretch_m=tuple(float(v) for v in per_cable(pk.D_STRETCH)),
            stretch_rate_mps=tuple(float(v) for v in per_cable(pk.D_STRETCH_RATE)),
            slack=tuple(bool(v > 0.5) for v in per_cable(pk.D_SLACK)),
        )

    def _touches(self, body: int) -> bool:
        return bool(self._diagnostics()[pk.D_ON_GROUND * self._layout.n_uavs + body] > 0.5)

    def on_ground(self, uav: int) -> bool:
        """Whether a foot (or a rotor tip) of UAV ``uav`` (1 … N) touches the ground."""
        return self._touches(self._layout.uav_index(uav))

    def payload_on_ground(self) -> bool:
        """Whether a contact point of the payload (an end of the bar) touches the ground."""
        return self._touches(self._layout.n_uavs)

    def energy(self) -> EnergyBreakdown:
        """Mechanical energy now [J]."""
        d = self._diagnostics()
        e = int(pk.energy_offset(self._layout.n_uavs))
        return EnergyBreakdown(
            kinetic_j=float(d[e + pk.D_KINETIC]),
            gravitational_j=float(d[e + pk.D_GRAVITY]),
            cable_spring_j=float(d[e + pk.D_CABLE_SPRING]),
            contact_spring_j=float(d[e + pk.D_CONTACT_SPRING]),
        )

    # -- configuration --

    def get_state(self) -> FloatArray:
        """A copy of the state vector, shape (``layout.state_size``,); layout in
        ``sim/plant_kernels.py`` (``layout.body_slice``, ``layout.actuator_slice``)."""
        return self._x.copy()

    def set_state(self, state: FloatArray, time_s: float | None = None) -> None:
        """Replace the state (quaternions are normalized; anchored UAVs get zero velocity
        and rates) and optionally restart the clock at ``time_s``."""
        x = np.array(state, dtype=float).reshape(self._layout.state_size)
        if not np.all(np.isfinite(x)):
            raise ValueError("state must be finite")
        for b, name in enumerate(self._layout.body_names):
            q = x[b * BODY_SIZE + 6 : b * BODY_SIZE + 10]
            norm = float(np.linalg.norm(q))
            if norm < 1e-9:
                raise ValueError(f"quaternion of {name} is zero")
            q /= norm
        for i, anchored in enumerate(self._anchored):
            if anchored:
                x[i * BODY_SIZE + 3 : i * BODY_SIZE + 6] = 0.0
                x[i * BODY_SIZE + 10 : i * BODY_SIZE + 13] = 0.0
        self._x = x
        if time_s is not None:
            self._t0_s = time_s
            self._steps = 0
        self._diag_fresh = False

    def set_body(
        self,
        name: str,
        *,
        position_m: FloatArray | None = None,
        velocity_mps: FloatArray | None = None,
        quaternion: FloatArray | None = None,
        body_rates_radps: FloatArray | None = None,
    ) -> None:
        """Overwrite some of one body's state (ENU [m], [m/s]; (w, x, y, z); body
        [rad/s])."""
        x = self.get_state()
        o = self._layout.body_index(name) * BODY_SIZE
        for offset, value, size in (
            (0, position_m, 3),
            (3, velocity_mps, 3),
            (6, quaternion, 4),
            (10, body_rates_radps, 3),
        ):
            if value is not None:
                x[o + offset : o + offset + size] = np.asarray(value, dtype=float).reshape(size)
        self.set_state(x)

    def set_anchored(self, uav: int, anchored: bool) -> None:
        """Hold UAV ``uav`` still as a kinematic anchor (its velocity and rates are
        zeroed), or release it."""
        i = self._layout.uav_index(uav)
        self._anchored[i] = anchored
        self._P[pk.body_block(i) + pk.B_ANCHOR] = 1.0 if anchored else 0.0
        self.set_state(self._x)

    def place_resting(
        self,
        payload_position_xy_m: tuple[float, float] = (0.0, 0.0),
        payload_yaw_rad: float = 0.0,
    ) -> None:
        """Put everything at rest on the ground (``resting_state``), motors stopped."""
        self._cmd[:] = 0.0
        self.set_state(resting_state(self._params, payload_position_xy_m, payload_yaw_rad))

    def place_hanging(
        self,
        uav_positions_m: Sequence[FloatArray],
        uav_yaws_rad: Sequence[float] | None = None,
    ) -> HoverTrim:
        """Put the system in hover equilibrium (``hanging_state``) and hold the trim
        commands, which are returned."""
        x, trim = hanging_state(self._params, uav_positions_m, uav_yaws_rad)
        self.set_state(x)
        for i, (thrust, torque) in enumerate(zip(trim.thrust_n, trim.torque_nm, strict=True)):
            self.command(i + 1, thrust, torque)
        return trim
