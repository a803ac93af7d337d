"""Equilibria of N UAVs carrying one rigid payload: the payload level, its cables on a cone.

The statics (derived in ``docs/model.md``, "N cables: equilibria"): the payload hangs
level at yaw ψ_b, and every cable's line of action passes through one point C on the
vertical through the payload's CoM. Forces through one point on the weight's line have
no net moment about it, so the payload is in equilibrium as soon as the forces balance:
Σ V_i = m g and Σ H_i = 0, with V_i and H_i cable i's vertical and horizontal pull. The
vertical loads V are the least-norm deviation from the equal share m g / N that does so;
C's depth follows from the cone angle, chosen so that the mean of the cables'
cotangents is its cotangent. A symmetric geometry then has every cable at exactly the
cone angle. For the paper's two-cable bar this is Section IV's equilibrium, generalized
to any d1, d2, masses and cable lengths: the bar level with its cables in its vertical
plane, each carrying the vertical load (13), both the same horizontal pull
(m_b g / 2) tan θ_l, so that the cable angles equal θ_l (the cone angle) exactly when the
setup is symmetric (Proposition 1). Every UAV tilts its thrust along its own cable's
horizontal direction, whatever its yaw, which takes roll and pitch together.

Scalar and small numpy arithmetic only: a relinearized tick comes here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache

import numpy as np

from controllers.equilibria import EquilibriumError, tilt_to_euler
from controllers.formation_params import BAR_TOLERANCE_M, FormationParams
from controllers.vectors import cross3
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.state import AGENT_STATES, P_B, P_P, TH_B, UAV_BLOCK, V_B, V_P, W_B

_BALANCE_RTOL = 1e-9


@dataclass(frozen=True)
class FormationReference:
    """What the operator asks for: the payload's CoM [m] and yaw, each UAV's yaw, and the
    cone angle of the cables [rad] (θ_l's generalization).

    ``velocity_mps`` (default zero) makes it a steady translation of the whole formation
    (a relative equilibrium: with no drag, x_eq + v t solves the model with the same u_eq),
    so that the MPC tracks a moving reference without a velocity-induced lag.
    ``payload_yaw_rate_radps`` and ``uav_yaw_rates_radps`` (empty, the default: none
    turns; given as zeros once constructed) add the turn rates of a turning reference the
    same way: the formation turns about the payload's CoM and each UAV about its own
    vertical axis. That is a feed-forward, not an equilibrium: the centripetal and
    gyroscopic terms it leaves out are O(ψ̇²), 0.1 m/s² at 20°/s.
    ``cone_angle_rate_radps`` is how fast the cone angle moves: the UAVs' velocities along
    the equilibrium family (each cable swinging outward), a feed-forward in the same
    sense; without it a θ_l ramp is tracked with a lag of about two seconds (issue 19).
    ``acceleration_mps2`` (default zero) makes it a uniform acceleration of the whole
    formation, the payload level: each cable pulls its share of m (a + g) more, each UAV
    adds m_i a to its thrust, so that x_eq + v t + a t²/2 solves the model with the same
    u_eq — exactly for attachments level with the payload's CoM (a bar, a plate); with
    attachments above or below it, a level payload would need a moment no cable gives,
    and the equilibrium is a feed-forward.
    """

    payload_position_m: tuple[float, float, float]
    payload_yaw_rad: float
    uav_yaw_rad: tuple[float, ...]
    cone_angle_rad: float = 0.0
    velocity_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    payload_yaw_rate_radps: float = 0.0
    uav_yaw_rates_radps: tuple[float, ...] = ()
    cone_angle_rate_radps: float = 0.0
    acceleration_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not self.uav_yaw_rates_radps:
            # One spelling of "none turns", so that equal references compare equal.
            object.__setattr__(self, "uav_yaw_rates_radps", (0.0,) * len(self.uav_yaw_rad))

    def with_yaws(
        self, payload_yaw_rad: float, uav_yaw_rad: tuple[float, ...]
    ) -> FormationReference:
        """The same equilibrium family, turned to other yaw angles."""
        return replace(self, payload_yaw_rad=payload_yaw_rad, uav_yaw_rad=uav_yaw_rad)

    def at_rest(self) -> FormationReference:
        """The same reference with zero velocity, rates and acceleration (where it will
        stop)."""
        return FormationReference(
            self.payload_position_m, self.payload_yaw_rad, self.uav_yaw_rad, self.cone_angle_rad
        )


@dataclass(frozen=True)
class FormationLimits:
    """Bounds an equilibrium must respect: each UAV's thrust [N] and thrust tilt [rad]."""

    thrust_min_n: float
    thrust_max_n: float
    max_tilt_rad: float


@dataclass(frozen=True)
class ExternalForces:
    """Constant external loads in the world frame: the force ``payload_n`` [N] at the
    payload's CoM and the torque ``payload_torque_nm`` [N m] on it, ``uavs_n[i-1]`` [N] on
    UAV i (empty: none on any UAV). What the disturbance-force observer estimates
    (``controllers.force_observer``); hashable, so that equilibria under the same loads
    are computed once a tick."""

    payload_n: tuple[float, float, float] = (0.0, 0.0, 0.0)
    payload_torque_nm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    uavs_n: tuple[tuple[float, float, float], ...] = ()

    @classmethod
    def from_vector(cls, d: FloatArray) -> ExternalForces:
        """From d = (f_b, τ_b, f_1, …, f_N) (6 + 3N,), ``FormationModel.forced_dynamics``'s."""
        values = [float(v) for v in d]
        triples = [(values[k], values[k + 1], values[k + 2]) for k in range(0, len(values), 3)]
        return cls(triples[0], triples[1], tuple(triples[2:]))

    def vector(self, n_vehicles: int) -> FloatArray:
        """d = (f_b, τ_b, f_1, …, f_N) (6 + 3N,)."""
        d = np.zeros(6 + 3 * n_vehicles)
        d[0:3] = self.payload_n
        d[3:6] = self.payload_torque_nm
        for i, force in enumerate(self.uavs_n):
            d[6 + 3 * i : 9 + 3 * i] = force
        return d

    def on_uav(self, k: int) -> tuple[float, float, float]:
        """The force on UAV ``k + 1``."""
        return self.uavs_n[k] if self.uavs_n else (0.0, 0.0, 0.0)


NO_FORCES = ExternalForces()


@dataclass(frozen=True)
class FormationEquilibrium:
    """A fixed point of ``FormationModel`` and what it implies, per cable/UAV i = 1..N.

    ``x`` (12 + 12N,) and ``u`` (4N,) as in ``geometry.formation``; ``cable_angles_rad``
    from the vertical; ``tilts_rad`` of each UAV's thrust from the vertical;
    ``attachments_m`` the world positions e_i; ``payload_force_n[i-1]`` the force of the
    rest of the payload on attachment i as a point mass V_i / g accelerating with it (the
    decentralized model's ``f_ext``): the horizontal pull −H_i, and the share V_i / (g m)
    of an external force on the payload; ``payload_mass_share_kg[i-1]`` = V_i / g, the
    vertical load of cable i (the generalization of (13)). The arrays of the tuples are
    read-only.
    """

    x: FloatArray
    u: FloatArray
    tensions_n: tuple[float, ...]
    thrusts_n: tuple[float, ...]
    cable_angles_rad: tuple[float, ...]
    tilts_rad: tuple[float, ...]
    attachments_m: tuple[FloatArray, ...]
    payload_force_n: tuple[FloatArray, ...]
    payload_mass_share_kg: tuple[float, ...]
    acceleration_mps2: FloatArray

    @cached_property
    def layout(self) -> FormationLayout:
        """The layout of ``x`` and ``u``."""
        return FormationLayout(len(self.thrusts_n))

    def uav_position(self, i: int) -> FloatArray:
        """p_i of UAV ``i`` [m] (a copy)."""
        position: FloatArray = self.layout.uav_position(self.x, i).copy()
        return position

    def agent_state(self, i: int) -> FloatArray:
        """The decentralized agent ``i``'s x_i ∈ R^18 at this equilibrium: UAV i, and its
        attachment e_i with that point's velocity v_b + ω_b × (e_i − p_b)."""
        x = self.x
        return _agent_state(
            x[self.layout.uav_block(i)], self.attachments_m[i - 1], x[P_B], x[V_B], x[W_B]
        )

    def agent_input(self, i: int) -> FloatArray:
        """The decentralized agent ``i``'s u_i = (F_i, τ_i) at this equilibrium."""
        return self.u[self.layout.uav_input_slice(i)].copy()

    def agent(self, i: int) -> AgentEquilibrium:
        """What agent ``i`` needs of this equilibrium (``agent_equilibrium`` alone)."""
        return AgentEquilibrium(
            i,
            self.agent_state(i),
            self.agent_input(i),
            self.payload_force_n[i - 1],
            self.payload_mass_share_kg[i - 1],
            self.acceleration_mps2,
        )


@dataclass(frozen=True)
class AgentEquilibrium:
    """Decentralized agent ``i``'s part of a formation equilibrium: its x_i (18,) and
    u_i (4,), the horizontal pull of the rest of the payload on its attachment [N] (3,)
    and its cable's vertical load V_i / g [kg], and the formation's acceleration [m/s²]
    (3,). ``agent_equilibrium`` gives it without the other vehicles, so that an agent's
    tick does not grow with N."""

    i: int
    x: FloatArray
    u: FloatArray
    payload_force_n: FloatArray
    payload_mass_share_kg: float
    acceleration_mps2: FloatArray


def _agent_state(
    uav_block: FloatArray,
    attachment_m: FloatArray,
    payload_position_m: FloatArray,
    payload_velocity_mps: FloatArray,
    payload_rates_radps: FloatArray,
) -> FloatArray:
    x_i = np.zeros(AGENT_STATES)
    x_i[UAV_BLOCK] = uav_block
    x_i[P_P] = attachment_m
    x_i[V_P] = payload_velocity_mps + cross3(payload_rates_radps, attachment_m - payload_position_m)
    return x_i


@dataclass(frozen=True)
class _CableLoads:
    """The yaw-independent part: per cable, V_i [N], tan θ_i and d(tan θ_i)/d(cone)."""

    vertical_n: FloatArray
    tan_angle: FloatArray
    tan_angle_per_cone_rad: FloatArray
    balance_point_m: tuple[float, float]  # in the payload frame (``_balance_point``)
    accelerating_n: FloatArray  # the loads balanced about the CoM: what shares m a


def _check_reference(reference: FormationReference, n: int) -> None:
    rates = reference.uav_yaw_rates_radps
    if len(reference.uav_yaw_rad) != n or len(rates) != n:
        raise EquilibriumError(f"a formation of {n} UAVs needs {n} UAV yaws and yaw rates")
    values = (
        *reference.payload_position_m,
        reference.payload_yaw_rad,
        *reference.uav_yaw_rad,
        reference.cone_angle_rad,
        *reference.velocity_mps,
        reference.payload_yaw_rate_radps,
        *rates,
        reference.cone_angle_rate_radps,
        *reference.acceleration_mps2,
    )
    if not all(math.isfinite(v) for v in values):
        raise EquilibriumError("reference values must be finite")
    if not 0.0 <= reference.cone_angle_rad < math.pi / 2.0:
        raise EquilibriumError(
            f"cone angle = {math.degrees(reference.cone_angle_rad):.2f}° has no equilibrium: "
            "it must lie in [0°, 90°)"
        )


# The most a payload torque may move the point the cables' loads balance about, as a share
# of the nearest attachment's reach: beyond, a cable would carry next to nothing.
_MAX_BALANCE_SHIFT = 0.5
# The balance point is rounded to this [m], so that a tick's equilibria (its preview's
# stages) share their cable loads: 0.1 mm of a 0.4 kg bar's weight is 0.4 mN m.
_BALANCE_POINT_STEP_M = 1e-4


@lru_cache(maxsize=8)
def _balance_geometry(params: FormationParams) -> tuple[FloatArray | None, float]:
    """A bar's axis in its frame (None for other payloads), and the farthest the balance
    point may move [m]."""
    a = np.array(params.payload.attachments_m, dtype=float)[:, :2]
    axis = (a[-1] - a[0]) / np.linalg.norm(a[-1] - a[0]) if params.payload.is_bar else None
    reach = np.hypot(a[:, 0], a[:, 1])
    off_axis = reach[reach > BAR_TOLERANCE_M]
    largest = _MAX_BALANCE_SHIFT * float(off_axis.min()) if off_axis.size else 0.0
    return axis, largest


def _balance_point(
    params: FormationParams, reference: FormationReference, forces: ExternalForces
) -> tuple[float, float]:
    """Where, in the payload's frame [m], the cables' loads balance: the horizontal point at
    which the effective weight m (g + a_z) − f_b,z gives the moment of the payload torque's
    horizontal part (a torque τ is the weight moved by τ × e_z / W). The CoM (0, 0) without
    one; a bar's only along the bar ((5g): it has no moment about its axis); at most
    ``_MAX_BALANCE_SHIFT`` of the nearest attachment's reach."""
    tx, ty, _ = forces.payload_torque_nm
    payload = params.payload
    weight = payload.mass_kg * (params.gravity_mps2 + reference.acceleration_mps2[2])
    weight -= forces.payload_n[2]
    if (tx == 0.0 and ty == 0.0) or weight <= 0.0:
        return 0.0, 0.0
    cos_b, sin_b = math.cos(reference.payload_yaw_rad), math.sin(reference.payload_yaw_rad)
    dx, dy = ty / weight, -tx / weight
    shift_x, shift_y = cos_b * dx + sin_b * dy, -sin_b * dx + cos_b * dy
    axis, largest = _balance_geometry(params)
    if axis is not None:
        along = float(axis[0]) * shift_x + float(axis[1]) * shift_y
        shift_x, shift_y = along * float(axis[0]), along * float(axis[1])
    size = math.hypot(shift_x, shift_y)
    if size > largest:
        shift_x, shift_y = shift_x * largest / size, shift_y * largest / size
    step = _BALANCE_POINT_STEP_M
    return round(shift_x / step) * step, round(shift_y / step) * step


@lru_cache(maxsize=8)
def _cable_loads(
    params: FormationParams, cone_angle_rad: float, balance_point_m: tuple[float, float]
) -> _CableLoads:
    """V, tan θ_i and their cone-angle derivative, in the payload frame (yaw-free, so a
    held or turning reference reuses them tick after tick; the arrays are read-only), with
    the loads balancing about ``balance_point_m`` (``_balance_point``) rather than the CoM."""
    a = np.array(params.payload.attachments_m, dtype=float)
    a[:, :2] -= balance_point_m
    reach = np.hypot(a[:, 0], a[:, 1])  # |ρ_i|
    off_axis = reach > BAR_TOLERANCE_M
    t = math.tan(cone_angle_rad)
    # Mean cot θ_i = cot(cone) over the off-axis cables with tan θ_i = t m1 |ρ_i| / D_i,
    # D_i = 1 + t (m1 h_i − mh): C lies (1/t − mh)/m1 below the CoM.
    if off_axis.any():
        m1 = float(np.mean(1.0 / reach[off_axis]))
        mh = float(np.mean(a[off_axis, 2] / reach[off_axis]))
    elif t > 0.0:
        raise EquilibriumError(
            "every attachment is on the payload's vertical axis: only a cone angle of 0° "
            "has a level equilibrium"
        )
    else:
        m1 = mh = 0.0
    depth_factor = 1.0 + t * (m1 * a[:, 2] - mh)
    below = np.flatnonzero(off_axis & (depth_factor <= 0.0))
    if below.size:
        raise EquilibriumError(
            f"cone angle = {math.degrees(cone_angle_rad):.2f}° puts the point where the "
            f"cables' lines meet at or above cable {below[0] + 1}'s attachment: no equilibrium"
        )
    weight = params.payload.mass_kg * params.gravity_mps2
    inverse_depth = np.divide(1.0, depth_factor, out=np.zeros(len(a)), where=off_axis)
    horizontal = inverse_depth[:, None] * a[:, :2]
    # Σ V_i = m g and Σ V_i ρ_i / D_i = 0 (Σ H_i = 0; at t = 0 the moment balance).
    A = np.vstack((np.ones(len(a)), horizontal.T))
    b = np.array((weight, 0.0, 0.0))
    equal_share = np.full(len(a), weight / len(a))
    vertical = equal_share + np.linalg.lstsq(A, b - A @ equal_share, rcond=None)[0]
    if np.abs(A @ vertical - b).max() > _BALANCE_RTOL * weight * max(1.0, float(reach.max())):
        raise EquilibriumError(
            "the payload cannot hang level: no vertical loads on its cables balance its "
            "weight and moments"
        )
    pushing = np.flatnonzero(vertical <= 0.0)
    if pushing.size:
        i = int(pushing[0])
        raise EquilibriumError(
            f"cable {i + 1} would carry {vertical[i]:.3f} N of the payload's weight: its CoM "
            "lies outside the support of the attachments (or, with four cables or more, too "
            "near its edge for the least-norm load share)"
        )
    scale = m1 * reach * inverse_depth
    # A horizontal m a shared as the loads balanced about the CoM has no moment about it.
    accelerating = (
        _cable_loads(params, cone_angle_rad, (0.0, 0.0)).vertical_n
        if any(balance_point_m)
        else vertical
    )
    loads = _CableLoads(
        vertical_n=vertical,
        tan_angle=t * scale,
        tan_angle_per_cone_rad=scale * inverse_depth / math.cos(cone_angle_rad) ** 2,
        balance_point_m=balance_point_m,
        accelerating_n=accelerating,
    )
    for array in (loads.vertical_n, loads.tan_angle, loads.tan_angle_per_cone_rad):
        array.setflags(write=False)
    return loads


def formation_equilibrium(
    params: FormationParams,
    reference: FormationReference,
    limits: FormationLimits | None = None,
    *,
    remember: bool = True,
    forces: ExternalForces = NO_FORCES,
) -> FormationEquilibrium:
    """The equilibrium (x_eq, u_eq) for ``reference``, in closed form (one least-norm
    solve of at most three equations for the vertical loads).

    Raises ``EquilibriumError`` for a reference without one: a cone angle outside
    [0°, 90°) or one that puts the cables' common point above an attachment, a payload
    that cannot hang level or whose CoM lies outside its attachments' support (naming the
    cable), or, given ``limits``, a UAV whose thrust or tilt would break them (naming the
    UAV and the bound). A tick asks for the same reference more than once (safety,
    controller, the record), so recent answers are kept: callers get their own x and u.
    ``remember=False`` neither reads nor keeps them (a horizon of references asked once
    each would push out those asked again).

    ``forces`` (none by default) makes it the fixed point of the model under them
    (``FormationModel.forced_dynamics``): the payload still where the reference puts it,
    the cables carrying the payload's m (a + g) less its force, each UAV's thrust its own
    m_i (a + g) and its cable's pull less its force.
    """
    _check_reference(reference, params.n_vehicles)
    _check_forces(forces, params.n_vehicles)
    if not remember:
        return _equilibrium(params, reference, limits, forces)
    cached = _cached_equilibrium(params, reference, limits, forces)
    return replace(cached, x=cached.x.copy(), u=cached.u.copy())


@dataclass(frozen=True)
class _Vehicle:
    """UAV i's part of an equilibrium: its 12 states (p, v, Θ, ω), its thrust and cable."""

    block: tuple[float, ...]
    thrust_n: float
    tension_n: float
    cable_angle_rad: float
    tilt_rad: float
    attachment_m: tuple[float, float, float]
    payload_force_n: tuple[float, float, float]


def _check_forces(forces: ExternalForces, n: int) -> None:
    if forces.uavs_n and len(forces.uavs_n) != n:
        raise EquilibriumError(
            f"a formation of {n} UAVs takes {n} UAV forces, got {len(forces.uavs_n)}"
        )
    values = (
        *forces.payload_n,
        *forces.payload_torque_nm,
        *(v for force in forces.uavs_n for v in force),
    )
    if not all(math.isfinite(v) for v in values):
        raise EquilibriumError("external forces must be finite")


def _vehicle(
    params: FormationParams,
    reference: FormationReference,
    loads: _CableLoads,
    k: int,
    limits: FormationLimits | None,
    forces: ExternalForces,
) -> _Vehicle:
    """UAV ``k + 1``'s part of the equilibrium for ``reference`` under ``forces``: alone,
    since each cable's loads are known (``_cable_loads``)."""
    g = params.gravity_mps2
    psi_b, psi_b_rate = reference.payload_yaw_rad, reference.payload_yaw_rate_radps
    cos_b, sin_b = math.cos(psi_b), math.sin(psi_b)
    bx, by, bz = reference.payload_position_m
    vx, vy, vz = reference.velocity_mps
    ax, ay, az = params.payload.attachments_m[k]
    cable, uav = params.cable_lengths_m[k], params.uavs[k]
    rho_x, rho_y = cos_b * ax - sin_b * ay, sin_b * ax + cos_b * ay  # R(ψ_b) a_i, level
    # The cable leans away from the vertical through the point its loads balance about.
    cx, cy = loads.balance_point_m
    lean_x, lean_y = rho_x - (cos_b * cx - sin_b * cy), rho_y - (sin_b * cx + cos_b * cy)
    reach = math.hypot(lean_x, lean_y)
    out_x, out_y = (lean_x / reach, lean_y / reach) if reach > BAR_TOLERANCE_M else (0.0, 0.0)
    vertical, tan_angle = float(loads.vertical_n[k]), float(loads.tan_angle[k])
    static_angle = math.atan(tan_angle)
    sin_a, cos_a = math.sin(static_angle), math.cos(static_angle)
    # The cable's pull on the payload: the static one scaled by the effective gravity's
    # vertical part, and its share of the payload's horizontal m a (V_i / g, the load
    # balanced about the CoM). A force on the payload takes its share off: the cables
    # carry m (a − f_b / m + g).
    payload_mass = params.payload.mass_kg
    acc_x, acc_y, acc_z = (
        a - f / payload_mass
        for a, f in zip(reference.acceleration_mps2, forces.payload_n, strict=True)
    )
    lift = 1.0 + acc_z / g
    horizontal = lift * vertical * tan_angle
    accelerating = float(loads.accelerating_n[k])
    pull = (
        horizontal * out_x + accelerating * acc_x / g,
        horizontal * out_y + accelerating * acc_y / g,
        lift * vertical,
    )
    tension = math.hypot(*pull)
    n_x, n_y, n_z = pull[0] / tension, pull[1] / tension, pull[2] / tension
    angle = math.acos(n_z)
    end = (bx + rho_x, by + rho_y, bz + az)
    m = uav.mass_kg
    uav_acc, uav_force = reference.acceleration_mps2, forces.on_uav(k)
    thrust_vector = (
        m * uav_acc[0] + pull[0] - uav_force[0],
        m * uav_acc[1] + pull[1] - uav_force[1],
        m * (g + uav_acc[2]) + pull[2] - uav_force[2],
    )
    thrust = math.hypot(*thrust_vector)
    tilt = math.atan2(math.hypot(thrust_vector[0], thrust_vector[1]), thrust_vector[2])
    if limits is not None:
        _check_limits(limits, k + 1, thrust, tilt)
    yaw = reference.uav_yaw_rad[k]
    yaw_rate = reference.uav_yaw_rates_radps[k]
    roll, pitch = tilt_to_euler(thrust_vector, yaw)
    px, py = end[0] + cable * n_x, end[1] + cable * n_y
    # The formation turning about the payload's CoM at ψ̇_b, and the cable swinging
    # outward at θ̇_i = cos²θ_i d(tan θ_i)/d(cone) · cone rate: l θ̇_i ∂n_i/∂θ_i.
    swing = (
        cable * cos_a**2 * float(loads.tan_angle_per_cone_rad[k]) * reference.cone_angle_rate_radps
    )
    # A turn about the vertical at ψ̇, in the body frame: ψ̇ Rᵀ e_z, with R of (2).
    cos_pitch = math.cos(pitch)
    block = (
        px,
        py,
        end[2] + cable * n_z,
        vx - psi_b_rate * (py - by) + swing * cos_a * out_x,
        vy + psi_b_rate * (px - bx) + swing * cos_a * out_y,
        vz - swing * sin_a,
        roll,
        pitch,
        yaw,
        -yaw_rate * math.sin(pitch),
        yaw_rate * math.sin(roll) * cos_pitch,
        yaw_rate * math.cos(roll) * cos_pitch,
    )
    share = vertical / g
    payload_force = (
        share * uav_acc[0] - pull[0],
        share * uav_acc[1] - pull[1],
        share * (g + uav_acc[2]) - pull[2],
    )
    return _Vehicle(block, thrust, tension, angle, tilt, end, payload_force)


def _payload_motion(reference: FormationReference) -> tuple[FloatArray, ...]:
    """The payload's p_b, v_b, Θ_b and ω_b at the equilibrium for ``reference``."""
    return (
        np.array(reference.payload_position_m, dtype=float),
        np.array(reference.velocity_mps, dtype=float),
        np.array((0.0, 0.0, reference.payload_yaw_rad)),
        np.array((0.0, 0.0, reference.payload_yaw_rate_radps)),
    )


def _equilibrium(
    params: FormationParams,
    reference: FormationReference,
    limits: FormationLimits | None,
    forces: ExternalForces,
) -> FormationEquilibrium:
    layout = params.layout
    loads = _cable_loads(
        params, reference.cone_angle_rad, _balance_point(params, reference, forces)
    )
    vehicles = [
        _vehicle(params, reference, loads, k, limits, forces) for k in range(params.n_vehicles)
    ]
    x = np.zeros(layout.n_states)
    u = np.zeros(layout.n_inputs)
    x[P_B], x[V_B], x[TH_B], x[W_B] = _payload_motion(reference)
    for i, vehicle in enumerate(vehicles, start=1):
        x[layout.uav_block(i)] = vehicle.block
        u[layout.thrust_index(i)] = vehicle.thrust_n
    ends = tuple(np.array(v.attachment_m) for v in vehicles)
    rest_of_payload = tuple(np.array(v.payload_force_n) for v in vehicles)
    acceleration = np.array(reference.acceleration_mps2, dtype=float)
    for array in (*ends, *rest_of_payload, acceleration):
        array.setflags(write=False)
    g = params.gravity_mps2
    return FormationEquilibrium(
        x=x,
        u=u,
        tensions_n=tuple(v.tension_n for v in vehicles),
        thrusts_n=tuple(v.thrust_n for v in vehicles),
        cable_angles_rad=tuple(v.cable_angle_rad for v in vehicles),
        tilts_rad=tuple(v.tilt_rad for v in vehicles),
        attachments_m=ends,
        payload_force_n=rest_of_payload,
        payload_mass_share_kg=tuple(float(v) / g for v in loads.vertical_n),
        acceleration_mps2=acceleration,
    )


_cached_equilibrium = lru_cache(maxsize=8)(_equilibrium)


def agent_equilibrium(
    params: FormationParams,
    reference: FormationReference,
    i: int,
    limits: FormationLimits | None = None,
    forces: ExternalForces = NO_FORCES,
) -> AgentEquilibrium:
    """Agent ``i``'s part of ``formation_equilibrium(params, reference, limits,
    forces=forces)``, the same numbers without computing the other vehicles' (an agent's
    tick at any N); raises ``EquilibriumError`` as that does for this UAV and for the
    payload."""
    _check_reference(reference, params.n_vehicles)
    _check_forces(forces, params.n_vehicles)
    if not 1 <= i <= params.n_vehicles:
        raise EquilibriumError(f"UAVs are numbered 1 to {params.n_vehicles}, got {i}")
    return _cached_agent_equilibrium(params, reference, i, limits, forces)


@lru_cache(maxsize=8)
def _cached_agent_equilibrium(
    params: FormationParams,
    reference: FormationReference,
    i: int,
    limits: FormationLimits | None,
    forces: ExternalForces,
) -> AgentEquilibrium:
    loads = _cable_loads(
        params, reference.cone_angle_rad, _balance_point(params, reference, forces)
    )
    vehicle = _vehicle(params, reference, loads, i - 1, limits, forces)
    p_b, v_b, _, w_b = _payload_motion(reference)
    u_i = np.zeros(4)
    u_i[0] = vehicle.thrust_n
    agent = AgentEquilibrium(
        i,
        _agent_state(np.array(vehicle.block), np.array(vehicle.attachment_m), p_b, v_b, w_b),
        u_i,
        np.array(vehicle.payload_force_n),
        float(loads.vertical_n[i - 1]) / params.gravity_mps2,
        np.array(reference.acceleration_mps2, dtype=float),
    )
    for array in (agent.x, agent.u, agent.payload_force_n, agent.acceleration_mps2):
        array.setflags(write=False)
    return agent


def hanging_mass_shares_kg(params: FormationParams) -> tuple[float, ...]:
    """Each cable's share of the payload's mass [kg] when it hangs still on vertical cables
    (a cone angle of 0), V_i / g: the generalization of (13), m_b d_j / (d1 + d2)."""
    hanging = FormationReference((0.0, 0.0, 0.0), 0.0, (0.0,) * params.n_vehicles)
    return formation_equilibrium(params, hanging).payload_mass_share_kg


def _check_limits(limits: FormationLimits, i: int, thrust_n: float, tilt_rad: float) -> None:
    if thrust_n > limits.thrust_max_n:
        raise EquilibriumError(
            f"UAV {i} would need {thrust_n:.2f} N of thrust, above the maximum thrust "
            f"{limits.thrust_max_n:.2f} N"
        )
    if thrust_n < limits.thrust_min_n:
        raise EquilibriumError(
            f"UAV {i} would need {thrust_n:.2f} N of thrust, below the minimum thrust "
            f"{limits.thrust_min_n:.2f} N"
        )
    if tilt_rad > limits.max_tilt_rad:
        raise EquilibriumError(
            f"UAV {i} would tilt {math.degrees(tilt_rad):.1f}°, beyond the maximum tilt "
            f"{math.degrees(limits.max_tilt_rad):.1f}°"
        )
