"""The simulator's physics plant: two quadrotors and a bar on two elastic cables.

This is the world the controllers are tested against, deliberately not the controllers'
model (Section II-B's rigid cables and planar bar rotation): here every body is a full
6-DOF rigid body, the cables are stiff unilateral spring-dampers that can go slack, the
motors lag and saturate, and everything can rest on the ground.

* UAVs: mass, full inertia tensor with gyroscopic terms, quaternion attitude
  (renormalized every step), thrust along body +z (FLU), body torque; first-order lag
  and saturation on the commands.
* Bar: a rigid body with a full inertia tensor (it may spin about its own axis), CoM
  at d1 from end 1 and d2 from end 2; the cables are tied at the ends.
* Cables: T = max(0, k s + c ṡ) while stretched, 0 when slack.
* Ground at z = 0: UAVs stand on their feet (or lie on their rotor tips), the bar on its
  ends; penalty contact with friction and rolling resistance so resting is stable. The
  bodies do not collide with each other.
* Optional drag, wind and parameter mismatch (``sim/plant_params.py``), and external
  loads on any body — a steady push or a gust (``sim/loads.py``, ``add_load``).

Integration is fixed-step RK4 (1 kHz default) in numba kernels (``sim/plant_kernels.py``,
where the state-vector layout is documented). Frames: ENU arena (z up), FLU UAV bodies.
UAVs are numbered 1 and 2 as in the paper.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.optimize import root

from geometry.arrays import FloatArray
from geometry.frames import (
    quaternion_from_rotation,
    rotation_from_euler_zyx,
    rotation_from_quaternion,
)
from sim import plant_kernels as pk
from sim.loads import ExternalLoad
from sim.plant_params import ContactParams, PlantParams
from sim.ports import AirframeState

BodyName = Literal["uav1", "uav2", "bar"]
BODY_NAMES: tuple[BodyName, BodyName, BodyName] = ("uav1", "uav2", "bar")
BODY_INDEX: dict[str, int] = {name: i for i, name in enumerate(BODY_NAMES)}

# State layout, re-exported for callers of get_state/set_state (see sim/plant_kernels.py).
STATE_SIZE = pk.STATE_SIZE
BODY_SIZE = pk.BODY_SIZE
ACT_OFFSET = pk.ACT_OFFSET
ACT_SIZE = pk.ACT_SIZE


def body_slice(name: str) -> slice:
    """The 13 entries of body ``name`` in the state vector: position ENU [m] (3),
    velocity ENU [m/s] (3), quaternion (w, x, y, z) body → ENU (4), body rates [rad/s]
    (3)."""
    start = BODY_INDEX[name] * BODY_SIZE
    return slice(start, start + BODY_SIZE)


def actuator_slice(uav: int) -> slice:
    """The 4 actuator entries of UAV ``uav`` (1 or 2): lagged thrust [N], lagged body
    torque FLU [N m] (3)."""
    start = ACT_OFFSET + (_uav_index(uav)) * ACT_SIZE
    return slice(start, start + ACT_SIZE)


def _uav_index(uav: int) -> int:
    if uav not in (1, 2):
        raise ValueError(f"UAVs are numbered 1 and 2, got {uav}")
    return uav - 1


def _body_index(name: str) -> int:
    if name not in BODY_INDEX:
        raise ValueError(f"unknown body {name!r}; bodies are {BODY_NAMES}")
    return BODY_INDEX[name]


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
    params: PlantParams, *, ground: bool = True, anchored: tuple[bool, bool] = (False, False)
) -> FloatArray:
    """The flat parameter vector the kernels read (layout: the B_*/C_*/L_*/G_* offsets of
    ``sim/plant_kernels.py``)."""
    wind = params.wind
    n_wind = 0 if wind.is_calm else wind.n_components
    P = np.zeros(pk.parameter_size(n_wind))
    bar = params.bar
    for b in range(pk.N_BODIES):
        pb = b * pk.BODY_BLOCK
        if b < 2:
            uav = params.uavs[b]
            mass = uav.mass_kg
            J = np.array(uav.inertia_kgm2, dtype=float)
            points = np.array(uav.landing_gear_body_m + uav.frame_points_body_m, dtype=float)
            radius = 0.0
            contact = params.uav_contact
            drag = (uav.drag_linear_n_s_per_m, uav.drag_quadratic_n_s2_per_m2)
            P[pb + pk.B_ANCHOR] = 1.0 if anchored[b] else 0.0
        else:
            mass = bar.mass_kg
            J = bar.inertia_tensor_kgm2()
            points = np.array([[-bar.d1_m, 0.0, 0.0], [bar.d2_m, 0.0, 0.0]])
            radius = bar.tube_radius_m
            contact = params.bar_contact
            drag = (bar.drag_linear_n_s_per_m, bar.drag_quadratic_n_s2_per_m2)
        P[pb + pk.B_MASS] = mass
        P[pb + pk.B_J : pb + pk.B_J + 9] = J.ravel()
        P[pb + pk.B_JINV : pb + pk.B_JINV + 9] = np.linalg.inv(J).ravel()
        P[pb + pk.B_NCONT] = len(points)
        P[pb + pk.B_CPTS : pb + pk.B_CPTS + points.size] = points.ravel()
        P[pb + pk.B_CRAD] = radius
        _pack_contact(P, pb, contact)
        P[pb + pk.B_DRAG1], P[pb + pk.B_DRAG2] = drag
    ends = ((-bar.d1_m, 0.0, 0.0), (bar.d2_m, 0.0, 0.0))
    for c in range(2):
        pc = pk.OFF_CABLE + c * pk.CABLE_BLOCK
        cable = params.cables[c]
        P[pc + pk.C_L0] = cable.length_m
        P[pc + pk.C_K] = cable.stiffness_n_per_m
        P[pc + pk.C_C] = cable.damping_n_s_per_m
        P[pc + pk.C_UAVPT : pc + pk.C_UAVPT + 3] = params.uavs[c].cable_attachment_body_m
        P[pc + pk.C_BARPT : pc + pk.C_BARPT + 3] = ends[c]
        pl = pk.OFF_LAG + c * pk.LAG_BLOCK
        P[pl + pk.L_TAU_F] = params.uavs[c].thrust_time_constant_s
        P[pl + pk.L_TAU_T] = params.uavs[c].torque_time_constant_s
    P[pk.OFF_GLOBAL + pk.G_GRAV] = params.gravity_mps2
    P[pk.OFF_GLOBAL + pk.G_GROUND] = 1.0 if ground else 0.0
    P[pk.OFF_GLOBAL + pk.G_NWIND] = n_wind
    P[pk.OFF_WIND : pk.OFF_WIND + 3] = wind.mean_velocity_mps
    if n_wind:
        amplitude, omega, phase = wind.components()
        base = pk.OFF_WIND + 3
        block = 3 * n_wind
        P[base : base + block] = amplitude.ravel()
        P[base + block : base + 2 * block] = omega.ravel()
        P[base + 2 * block : base + 3 * block] = phase.ravel()
    return P


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
    """All three bodies at one instant (what the motion-capture model samples)."""

    time_s: float
    bodies: Mapping[str, BodyTruth]


@dataclass(frozen=True)
class CableTruth:
    """Per cable (index 0: cable 1, UAV 1 – bar end 1; index 1: cable 2): tension [N]
    (never negative), stretch beyond the rest length [m] (negative when slack), stretch
    rate [m/s], slack flags."""

    tension_n: tuple[float, float]
    stretch_m: tuple[float, float]
    stretch_rate_mps: tuple[float, float]
    slack: tuple[bool, bool]


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
    per UAV (index 0: UAV 1) thrust [N] and body torque FLU [N m] (shape (3,)), and the
    static cable tensions [N]."""

    thrust_n: tuple[float, float]
    torque_nm: tuple[FloatArray, FloatArray]
    tension_n: tuple[float, float]


# --- Configurations --------------------------------------------------------------------------


def _set_pose(x: FloatArray, b: int, position_m: FloatArray, R: FloatArray | None = None) -> None:
    o = b * BODY_SIZE
    x[o : o + 3] = position_m
    x[o + 3 : o + 6] = 0.0
    x[o + 6 : o + 10] = (1.0, 0.0, 0.0, 0.0) if R is None else quaternion_from_rotation(R)
    x[o + 10 : o + 13] = 0.0


def resting_state(
    params: PlantParams,
    bar_position_xy_m: tuple[float, float] = (0.0, 0.0),
    bar_yaw_rad: float = 0.0,
) -> FloatArray:
    """Everything at rest on the ground: the bar's CoM above ``bar_position_xy_m``, its
    axis at ``bar_yaw_rad`` from ENU x, each UAV (yaw = bar yaw) standing directly above
    its cable's bar end, cables slack. Bodies sit at their static contact penetration
    (feet assumed symmetric about the CoM) so nothing bounces at t = 0. Shape
    (STATE_SIZE,)."""
    g = params.gravity_mps2
    bar = params.bar
    x = np.zeros(STATE_SIZE)
    # Static end loads of a bar on two supports: N1 = m g d2/L, N2 = m g d1/L.
    k_bar = params.bar_contact.stiffness_n_per_m
    z1 = bar.tube_radius_m - bar.mass_kg * g * bar.d2_m / bar.length_m / k_bar
    z2 = bar.tube_radius_m - bar.mass_kg * g * bar.d1_m / bar.length_m / k_bar
    pitch = -math.asin((z2 - z1) / bar.length_m)
    R_bar = rotation_from_euler_zyx(0.0, pitch, bar_yaw_rad)
    axis = R_bar[:, 0]
    com = np.array([bar_position_xy_m[0], bar_position_xy_m[1], 0.0])
    com[2] = z1 + (z2 - z1) * bar.d1_m / bar.length_m
    _set_pose(x, 2, com, R_bar)
    ends = (com - bar.d1_m * axis, com + bar.d2_m * axis)
    R_uav = rotation_from_euler_zyx(0.0, 0.0, bar_yaw_rad)
    for i, uav in enumerate(params.uavs):
        feet = np.array(uav.landing_gear_body_m, dtype=float)
        sink = uav.mass_kg * g / (len(feet) * params.uav_contact.stiffness_n_per_m)
        position = np.array([ends[i][0], ends[i][1], -feet[:, 2].min() - sink])
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


def _bar_pose(z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(CoM [m], rotation) of the bar from (x, y, z, yaw, pitch); no roll about its axis."""
    return z[:3], rotation_from_euler_zyx(0.0, float(z[4]), float(z[3]))


def hanging_state(
    params: PlantParams,
    uav_positions_m: tuple[FloatArray, FloatArray],
    uav_yaws_rad: tuple[float, float] = (0.0, 0.0),
) -> tuple[FloatArray, HoverTrim]:
    """The system hovering at rest: UAV CoMs at ``uav_positions_m`` (ENU [m], each shape
    (3,)) with yaws ``uav_yaws_rad``, the bar hanging below in static equilibrium on its
    stretched cables (no roll about its own axis), each UAV tilted so its thrust balances
    its weight and its cable, the actuators already at the trim. Returns the state
    (STATE_SIZE,) and the trim; the trim is exact unless it exceeds a saturation.

    Raises ValueError when the UAVs are too far apart for the cables (more than the bar
    plus both cables) or no equilibrium is found.
    """
    p = [np.asarray(position, dtype=float).reshape(3) for position in uav_positions_m]
    g = params.gravity_mps2
    bar = params.bar
    ends_body = (np.array([-bar.d1_m, 0.0, 0.0]), np.array([bar.d2_m, 0.0, 0.0]))
    attach_body = [np.array(u.cable_attachment_body_m, dtype=float) for u in params.uavs]
    R_uav = [rotation_from_euler_zyx(0.0, 0.0, yaw) for yaw in uav_yaws_rad]
    k = [c.stiffness_n_per_m for c in params.cables]
    l0 = [c.length_m for c in params.cables]

    def cable_forces(z: FloatArray, anchors: list[FloatArray]) -> list[FloatArray]:
        # Two-sided springs here: smooth for the solver (the max(0, ·) kink has a zero
        # Jacobian on the slack side); a compressed cable is rejected afterwards.
        com, R = _bar_pose(z)
        forces = []
        for c in range(2):
            d = anchors[c] - (com + R @ ends_body[c])
            dist = float(np.linalg.norm(d))
            forces.append(k[c] * (dist - l0[c]) * d / dist)
        return forces

    def residual(z: FloatArray, anchors: list[FloatArray]) -> FloatArray:
        _, R = _bar_pose(z)
        forces = cable_forces(z, anchors)
        force = forces[0] + forces[1] - np.array([0.0, 0.0, bar.mass_kg * g])
        torque = sum(np.cross(R @ ends_body[c], forces[c]) for c in range(2))
        # The torque about the bar's own axis vanishes (the ends lie on it).
        return np.concatenate([force, [float(torque @ R[:, 1]), float(torque @ R[:, 2])]])

    anchors = [p[c] + R_uav[c] @ attach_body[c] for c in range(2)]
    span = anchors[1] - anchors[0]
    horizontal = math.hypot(span[0], span[1])
    yaw = math.atan2(span[1], span[0]) if horizontal > 1e-9 else uav_yaws_rad[0]
    overhang = 0.5 * (horizontal - bar.length_m)
    if abs(overhang) >= min(l0):
        raise ValueError(
            f"no hanging equilibrium: attachment points {horizontal:.3f} m apart for a "
            f"{bar.length_m} m bar on {min(l0)} m cables"
        )
    # Initial guess: each end below its anchor on a cable stretched by about the bar's
    # weight. Both cables taut matters: at zero tension the pendulum's lateral stiffness
    # vanishes and the Jacobian is singular.
    end_z = [
        anchors[c][2] - math.sqrt(l0[c] ** 2 - overhang**2) - bar.mass_kg * g / k[c]
        for c in range(2)
    ]
    rise = max(-1.0, min(1.0, (end_z[1] - end_z[0]) / bar.length_m))
    axis = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    mid = 0.5 * (anchors[0] + anchors[1])
    com0 = mid + (bar.d1_m - 0.5 * bar.length_m) * axis
    com0[2] = end_z[0] + (end_z[1] - end_z[0]) * bar.d1_m / bar.length_m
    z = np.array([com0[0], com0[1], com0[2], yaw, -math.asin(rise)])
    tensions = (0.0, 0.0)
    for _ in range(50):
        solution = root(residual, z, args=(anchors,), method="hybr", tol=1e-14)
        z = solution.x
        if np.max(np.abs(residual(z, anchors))) > 1e-8 * max(1.0, bar.mass_kg * g):
            raise ValueError(f"no hanging equilibrium found: {solution.message}")
        forces = cable_forces(z, anchors)
        com, R_bar = _bar_pose(z)
        for c in range(2):
            if np.linalg.norm(anchors[c] - (com + R_bar @ ends_body[c])) <= l0[c]:
                raise ValueError(f"no hanging equilibrium with both cables taut (cable {c + 1})")
        tensions = (float(np.linalg.norm(forces[0])), float(np.linalg.norm(forces[1])))
        new_R = []
        for c, uav in enumerate(params.uavs):
            # The cable pulls the UAV by −f; its thrust carries weight and cable.
            lift = uav.mass_kg * g * np.array([0.0, 0.0, 1.0]) + forces[c]
            new_R.append(
                _attitude_from_thrust_direction(lift / np.linalg.norm(lift), uav_yaws_rad[c])
            )
        # Off-CoM attachments move with the attitude: iterate to the fixed point.
        change = max(float(np.max(np.abs(new_R[c] - R_uav[c]))) for c in range(2))
        R_uav = new_R
        anchors = [p[c] + R_uav[c] @ attach_body[c] for c in range(2)]
        if change < 1e-12:
            break
    else:
        raise ValueError("hanging equilibrium: UAV attitudes did not converge")
    x = np.zeros(STATE_SIZE)
    com, R_bar = _bar_pose(z)
    _set_pose(x, 2, com, R_bar)
    forces = cable_forces(z, anchors)
    thrusts: list[float] = []
    torques: list[FloatArray] = []
    for c, uav in enumerate(params.uavs):
        _set_pose(x, c, p[c], R_uav[c])
        thrust_vec = uav.mass_kg * g * np.array([0.0, 0.0, 1.0]) + forces[c]
        thrust = min(float(np.linalg.norm(thrust_vec)), uav.thrust_max_n)
        # Trim torque cancels the cable's moment about the CoM: τ = −r_a × Rᵀ(−f).
        torque = np.cross(attach_body[c], R_uav[c].T @ forces[c])
        limit = np.array(uav.torque_max_nm, dtype=float)
        torque = np.clip(torque, -limit, limit)
        a = ACT_OFFSET + c * ACT_SIZE
        x[a] = thrust
        x[a + 1 : a + 4] = torque
        thrusts.append(thrust)
        torques.append(torque)
    trim = HoverTrim((thrusts[0], thrusts[1]), (torques[0], torques[1]), tensions)
    return x, trim


# --- The plant ---------------------------------------------------------------------------------


class UavPort:
    """One UAV of a ``Plant`` as its flight controller sees it (``sim.ports.AirframePort``)."""

    def __init__(self, plant: Plant, uav: int) -> None:
        self._plant = plant
        self._uav = uav

    @property
    def number(self) -> int:
        """1 or 2."""
        return self._uav

    def state(self) -> AirframeState:
        """The current ground truth of this UAV."""
        truth = self._plant.body("uav1" if self._uav == 1 else "uav2")
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
    as a kinematic anchor (tests: a bar hanging from fixed points); an anchored UAV's
    velocity and rates are kept at zero. ``state`` (STATE_SIZE,) defaults to
    ``resting_state(params)``. Time starts at ``time_s``.
    """

    def __init__(
        self,
        params: PlantParams | None = None,
        *,
        ground: bool = True,
        anchored: tuple[bool, bool] = (False, False),
        state: FloatArray | None = None,
        time_s: float = 0.0,
    ) -> None:
        self._params = PlantParams() if params is None else params
        self._P = pack_parameters(self._params, ground=ground, anchored=anchored)
        self._anchored = list(anchored)
        self._x = np.zeros(STATE_SIZE)
        self._cmd = np.zeros(2 * ACT_SIZE)
        self._ext = np.zeros(pk.N_BODIES * pk.EXT_SIZE)
        self._loads: list[ExternalLoad] = []
        self._t0_s = time_s
        self._steps = 0
        self._diag = np.zeros(pk.DIAG_SIZE)
        self._diag_fresh = False
        self._ports = (UavPort(self, 1), UavPort(self, 2))
        self.set_state(resting_state(self._params) if state is None else state)

    # -- time and stepping --

    @property
    def params(self) -> PlantParams:
        """The plant's (true) parameters."""
        return self._params

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
        if not np.all(np.isfinite(self._x)):
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
            e = BODY_INDEX[load.body] * pk.EXT_SIZE
            self._ext[e : e + 3] += scale * np.asarray(load.force_n)
            self._ext[e + 3 : e + 6] += scale * np.asarray(load.torque_nm)
        return chunk

    # -- external loads --

    @property
    def loads(self) -> tuple[ExternalLoad, ...]:
        """The external loads in effect or to come, oldest first."""
        return tuple(self._loads)

    def add_load(self, load: ExternalLoad) -> None:
        """Act with ``load`` from its ``start_s`` (plant time) on; loads add up."""
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
        """UAV ``i`` (1 or 2) as an ``AirframePort``."""
        return self._ports[_uav_index(i)]

    def command(self, uav: int, thrust_n: float, torque_nm: FloatArray) -> None:
        """Hold thrust [N] and body torque FLU [N m] on UAV ``uav`` (1 or 2) after
        saturation: thrust to [0, thrust_max], each torque axis to ±torque_max."""
        i = _uav_index(uav)
        torque = np.asarray(torque_nm, dtype=float).reshape(3)
        if not (math.isfinite(thrust_n) and np.all(np.isfinite(torque))):
            raise ValueError(f"non-finite command for UAV {uav}: {thrust_n}, {torque}")
        params = self._params.uavs[i]
        limit = np.array(params.torque_max_nm, dtype=float)
        self._cmd[4 * i] = min(max(float(thrust_n), 0.0), params.thrust_max_n)
        self._cmd[4 * i + 1 : 4 * i + 4] = np.clip(torque, -limit, limit)

    def commanded(self, uav: int) -> tuple[float, FloatArray]:
        """The saturated command held on UAV ``uav``: (thrust [N], torque [N m] (3,))."""
        i = _uav_index(uav)
        return float(self._cmd[4 * i]), self._cmd[4 * i + 1 : 4 * i + 4].copy()

    def actuator(self, uav: int) -> tuple[float, FloatArray]:
        """What the rotors produce now, after the lag: (thrust [N], torque [N m] (3,))."""
        s = actuator_slice(uav)
        values = self._x[s]
        return float(values[0]), values[1:].copy()

    # -- ground truth --

    def body(self, name: str) -> BodyTruth:
        """Ground truth of ``name`` ("uav1", "uav2" or "bar"); arrays are copies."""
        o = _body_index(name) * BODY_SIZE
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
        return PlantTruth(self.time_s, {name: self.body(name) for name in BODY_NAMES})

    def _diagnostics(self) -> FloatArray:
        if not self._diag_fresh:
            pk.diagnostics(self._x, self._P, self._diag)
            self._diag_fresh = True
        return self._diag

    def cables(self) -> CableTruth:
        """Cable tensions, stretch and slack flags now."""
        d = self._diagnostics()
        return CableTruth(
            tension_n=(float(d[pk.D_TENSION]), float(d[pk.D_TENSION + 1])),
            stretch_m=(float(d[pk.D_STRETCH]), float(d[pk.D_STRETCH + 1])),
            stretch_rate_mps=(float(d[pk.D_STRETCH_RATE]), float(d[pk.D_STRETCH_RATE + 1])),
            slack=(bool(d[pk.D_SLACK] > 0.5), bool(d[pk.D_SLACK + 1] > 0.5)),
        )

    def on_ground(self, uav: int) -> bool:
        """Whether a foot of UAV ``uav`` (1 or 2) touches the ground."""
        return bool(self._diagnostics()[pk.D_ON_GROUND + _uav_index(uav)] > 0.5)

    def bar_on_ground(self) -> bool:
        """Whether an end of the bar touches the ground."""
        return bool(self._diagnostics()[pk.D_ON_GROUND + 2] > 0.5)

    def energy(self) -> EnergyBreakdown:
        """Mechanical energy now [J]."""
        d = self._diagnostics()
        return EnergyBreakdown(
            kinetic_j=float(d[pk.D_KINETIC]),
            gravitational_j=float(d[pk.D_GRAVITY]),
            cable_spring_j=float(d[pk.D_CABLE_SPRING]),
            contact_spring_j=float(d[pk.D_CONTACT_SPRING]),
        )

    # -- configuration --

    def get_state(self) -> FloatArray:
        """A copy of the state vector, shape (STATE_SIZE,); layout in
        ``sim/plant_kernels.py`` (``body_slice``, ``actuator_slice``)."""
        return self._x.copy()

    def set_state(self, state: FloatArray, time_s: float | None = None) -> None:
        """Replace the state (quaternions are normalized; anchored UAVs get zero velocity
        and rates) and optionally restart the clock at ``time_s``."""
        x = np.array(state, dtype=float).reshape(STATE_SIZE)
        if not np.all(np.isfinite(x)):
            raise ValueError("state must be finite")
        for b in range(pk.N_BODIES):
            q = x[b * BODY_SIZE + 6 : b * BODY_SIZE + 10]
            norm = float(np.linalg.norm(q))
            if norm < 1e-9:
                raise ValueError(f"quaternion of {BODY_NAMES[b]} is zero")
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
        o = _body_index(name) * BODY_SIZE
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
        i = _uav_index(uav)
        self._anchored[i] = anchored
        self._P[i * pk.BODY_BLOCK + pk.B_ANCHOR] = 1.0 if anchored else 0.0
        self.set_state(self._x)

    def place_resting(
        self, bar_position_xy_m: tuple[float, float] = (0.0, 0.0), bar_yaw_rad: float = 0.0
    ) -> None:
        """Put everything at rest on the ground (``resting_state``), motors stopped."""
        self._cmd[:] = 0.0
        self.set_state(resting_state(self._params, bar_position_xy_m, bar_yaw_rad))

    def place_hanging(
        self,
        uav_positions_m: tuple[FloatArray, FloatArray],
        uav_yaws_rad: tuple[float, float] = (0.0, 0.0),
    ) -> HoverTrim:
        """Put the system in hover equilibrium (``hanging_state``) and hold the trim
        commands, which are returned."""
        x, trim = hanging_state(self._params, uav_positions_m, uav_yaws_rad)
        self.set_state(x)
        for i in (1, 2):
            self.command(i, trim.thrust_n[i - 1], trim.torque_nm[i - 1])
        return trim
