"""Parameters of the simulator's physics plant: frozen dataclasses, SI units in the names.

The defaults are the paper's lab (Section VI): Storm SRD370 quadrotors of 1.15 kg with
J = diag(0.0348, 0.0459, 0.0977) kg m², a hollow bar of 0.39 kg and 1.47 m whose CoM is
0.705 m from the end of cable 1 and 0.765 m from the end of cable 2, cables of about 1 m.
Every value that the paper does not give is marked "NOT in the paper" with the reason for
the chosen number. Beyond the paper, N UAVs (2 to 8) may carry any rigid payload
(``PayloadBodyParams``: a plate, a frame), one cable from each UAV to its own attachment.

Frames: arena ENU (z up); UAV body FLU (thrust along body +z); payload body frame with its
origin at the payload's CoM — the bar's x axis along the bar pointing from end 1 to end 2
(the paper's n_b).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from geometry.arrays import FloatArray
from geometry.formation import MAX_VEHICLES, MIN_VEHICLES

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]


def diagonal(values: Vec3) -> Mat3:
    """A 3 × 3 diagonal matrix as nested tuples (for inertia fields)."""
    a, b, c = values
    return ((a, 0.0, 0.0), (0.0, b, 0.0), (0.0, 0.0, c))


def as_mat3(J: FloatArray) -> Mat3:
    """A 3 × 3 array as nested tuples (for inertia fields)."""
    rows = [(float(r[0]), float(r[1]), float(r[2])) for r in J]
    return (rows[0], rows[1], rows[2])


def _check_inertia(name: str, inertia: Mat3) -> None:
    J = np.asarray(inertia, dtype=float)
    if J.shape != (3, 3) or not np.allclose(J, J.T, rtol=0.0, atol=1e-12):
        raise ValueError(f"{name}: inertia must be a symmetric 3 × 3 matrix")
    if np.linalg.eigvalsh(J).min() <= 0.0:
        raise ValueError(f"{name}: inertia must be positive definite")


def _check_positive(name: str, value: float) -> None:
    if not value > 0.0:
        raise ValueError(f"{name} must be > 0, got {value}")


def _check_non_negative(name: str, value: float) -> None:
    if not value >= 0.0:
        raise ValueError(f"{name} must be ≥ 0, got {value}")


# Section VI: J_i = diag(0.0348, 0.0459, 0.0977) kg m².
_SRD370_INERTIA_KGM2 = diagonal((0.0348, 0.0459, 0.0977))

# NOT in the paper: the SRD370's landing gear. Four feet 9 cm out along body x/y and 7 cm
# below the CoM, roughly its skids; only the footprint's size matters for resting.
_LANDING_GEAR_BODY_M: tuple[Vec3, ...] = (
    (0.09, 0.09, -0.07),
    (0.09, -0.09, -0.07),
    (-0.09, 0.09, -0.07),
    (-0.09, -0.09, -0.07),
)
# NOT in the paper: the rotor tips of a 370 mm (motor-to-motor diagonal) X frame, 3 cm
# above the CoM with the guards. They touch the ground only when the UAV tips over or
# lands upside down; without them a capsized UAV would sink through the floor.
_FRAME_POINTS_BODY_M: tuple[Vec3, ...] = (
    (0.13, 0.13, 0.03),
    (0.13, -0.13, 0.03),
    (-0.13, 0.13, 0.03),
    (-0.13, -0.13, 0.03),
)


@dataclass(frozen=True)
class UavBodyParams:
    """One quadrotor as the plant flies it.

    ``inertia_kgm2`` is the full body-frame (FLU) inertia tensor about the CoM.
    ``cable_attachment_body_m`` is where the cable is tied, in the body frame relative to
    the CoM (the paper assumes the CoM, Section II-B). ``landing_gear_body_m`` are the
    feet it stands on, ``frame_points_body_m`` other points of the airframe that touch
    the ground when it tips over (8 points at most in all). Commands are saturated to thrust ∈
    [0, ``thrust_max_n``] and |τ_k| ≤ ``torque_max_nm[k]``, then pass a first-order lag
    (time constant 0 means no lag). Drag acts at the CoM on the air-relative velocity:
    F = −(c₁ + c₂‖v_rel‖) v_rel.
    """

    mass_kg: float = 1.15
    inertia_kgm2: Mat3 = _SRD370_INERTIA_KGM2
    cable_attachment_body_m: Vec3 = (0.0, 0.0, 0.0)
    landing_gear_body_m: tuple[Vec3, ...] = _LANDING_GEAR_BODY_M
    frame_points_body_m: tuple[Vec3, ...] = _FRAME_POINTS_BODY_M
    # NOT in the paper: small-quadrotor motor/ESC time constants are 15–50 ms; 20 ms is
    # a brisk 370-size quad. The controller does not model the lag (a real mismatch).
    thrust_time_constant_s: float = 0.02
    torque_time_constant_s: float = 0.02
    # NOT in the paper: about 2.3× the hover thrust of UAV + half the bar (13.2 N), above
    # the controller's own 26 N limit so the controller's constraint is the active one.
    thrust_max_n: float = 30.0
    # The paper's input set U: ‖τ‖∞ ≤ 1 N m (Section VI).
    torque_max_nm: Vec3 = (1.0, 1.0, 1.0)
    drag_linear_n_s_per_m: float = 0.0
    drag_quadratic_n_s2_per_m2: float = 0.0

    def __post_init__(self) -> None:
        _check_positive("mass_kg", self.mass_kg)
        _check_inertia("uav", self.inertia_kgm2)
        if not 1 <= len(self.landing_gear_body_m) + len(self.frame_points_body_m) <= 8:
            raise ValueError("landing_gear_body_m + frame_points_body_m: 1 to 8 points")
        _check_non_negative("thrust_time_constant_s", self.thrust_time_constant_s)
        _check_non_negative("torque_time_constant_s", self.torque_time_constant_s)
        _check_positive("thrust_max_n", self.thrust_max_n)
        for value in self.torque_max_nm:
            _check_non_negative("torque_max_nm", value)
        _check_non_negative("drag_linear_n_s_per_m", self.drag_linear_n_s_per_m)
        _check_non_negative("drag_quadratic_n_s2_per_m2", self.drag_quadratic_n_s2_per_m2)


@dataclass(frozen=True)
class BarParams:
    """The bar: a rigid tube with a (possibly off-centre) CoM.

    End 1 is at (−d1, 0, 0) and end 2 at (d2, 0, 0) in the bar body frame, with
    d1 = ``com_from_end1_m`` and d2 = ``length_m − d1``. The cables are tied at the ends;
    on the ground the bar rests on its ends, each a sphere of ``tube_radius_m``.

    ``inertia_kgm2`` is the full body-frame inertia tensor about the CoM; ``None`` derives
    it from the geometry: m L²/12 + m (d1 − L/2)² about the perpendicular axes (a thin
    uniform tube seen from the shifted CoM, the estimate configs/kth_sml.toml uses for
    J_b = 0.0706) and m r² about the tube's axis (a thin-walled tube).
    """

    mass_kg: float = 0.39
    length_m: float = 1.47
    com_from_end1_m: float = 0.705
    # NOT in the paper: a 2 cm hollow tube. Only the axial inertia and the resting
    # contact depend on it.
    tube_radius_m: float = 0.01
    inertia_kgm2: Mat3 | None = None
    drag_linear_n_s_per_m: float = 0.0
    drag_quadratic_n_s2_per_m2: float = 0.0

    def __post_init__(self) -> None:
        _check_positive("bar mass_kg", self.mass_kg)
        _check_positive("bar length_m", self.length_m)
        if not 0.0 < self.com_from_end1_m < self.length_m:
            raise ValueError("com_from_end1_m must lie strictly inside the bar")
        _check_positive("tube_radius_m", self.tube_radius_m)
        if self.inertia_kgm2 is not None:
            _check_inertia("bar", self.inertia_kgm2)
        _check_non_negative("bar drag_linear_n_s_per_m", self.drag_linear_n_s_per_m)
        _check_non_negative("bar drag_quadratic_n_s2_per_m2", self.drag_quadratic_n_s2_per_m2)

    @property
    def d1_m(self) -> float:
        """Distance CoM → end 1 (cable 1) [m]."""
        return self.com_from_end1_m

    @property
    def d2_m(self) -> float:
        """Distance CoM → end 2 (cable 2) [m]."""
        return self.length_m - self.com_from_end1_m

    def inertia_tensor_kgm2(self) -> FloatArray:
        """The body-frame inertia tensor about the CoM, shape (3, 3)."""
        if self.inertia_kgm2 is not None:
            return np.array(self.inertia_kgm2, dtype=float)
        m, L = self.mass_kg, self.length_m
        offset = self.com_from_end1_m - 0.5 * L
        perpendicular = m * L * L / 12.0 + m * offset * offset
        axial = m * self.tube_radius_m**2
        return np.diag([axial, perpendicular, perpendicular])

    def payload_body(self) -> PayloadBodyParams:
        """The bar as a rigid payload: cables tied at the ends, resting on the ends."""
        ends = ((-self.d1_m, 0.0, 0.0), (self.d2_m, 0.0, 0.0))
        return PayloadBodyParams(
            mass_kg=self.mass_kg,
            inertia_kgm2=as_mat3(self.inertia_tensor_kgm2()),
            attachments_body_m=ends,
            contact_points_body_m=ends,
            contact_radius_m=self.tube_radius_m,
            drag_linear_n_s_per_m=self.drag_linear_n_s_per_m,
            drag_quadratic_n_s2_per_m2=self.drag_quadratic_n_s2_per_m2,
        )


@dataclass(frozen=True)
class PayloadBodyParams:
    """A rigid payload hung by N cables: mass, the full inertia tensor about its CoM in its
    own frame, and in that frame (origin at the CoM) the point where each cable is tied
    (``attachments_body_m[i-1]``: cable i, from UAV i) and the points it rests on, each a
    sphere of ``contact_radius_m`` (0: a point) — a plate's or a frame's corners, 1 to 8
    of them. Drag acts at the CoM as on a UAV."""

    mass_kg: float
    inertia_kgm2: Mat3
    attachments_body_m: tuple[Vec3, ...]
    contact_points_body_m: tuple[Vec3, ...]
    contact_radius_m: float = 0.0
    drag_linear_n_s_per_m: float = 0.0
    drag_quadratic_n_s2_per_m2: float = 0.0

    def __post_init__(self) -> None:
        _check_positive("payload mass_kg", self.mass_kg)
        _check_inertia("payload", self.inertia_kgm2)
        if not MIN_VEHICLES <= len(self.attachments_body_m) <= MAX_VEHICLES:
            raise ValueError(f"attachments_body_m: one per cable, {MIN_VEHICLES} to {MAX_VEHICLES}")
        if not np.any(np.array(self.attachments_body_m, dtype=float)):
            raise ValueError("the attachments must not all be at the payload's CoM")
        if not 1 <= len(self.contact_points_body_m) <= 8:
            raise ValueError("contact_points_body_m: 1 to 8 points")
        _check_non_negative("contact_radius_m", self.contact_radius_m)
        _check_non_negative("payload drag_linear_n_s_per_m", self.drag_linear_n_s_per_m)
        _check_non_negative("payload drag_quadratic_n_s2_per_m2", self.drag_quadratic_n_s2_per_m2)

    def with_mass_and_com_shift(self, mass_scale: float, com_shift_m: float) -> PayloadBodyParams:
        """This payload ``mass_scale`` times heavier (its inertia too) with its CoM moved
        by ``com_shift_m`` along its x axis: every point of its frame moves back by as much,
        and the inertia gains m δ² about y and z (the nominal tensor about the new CoM)."""
        shift = (com_shift_m, 0.0, 0.0)
        return dataclasses.replace(
            self,
            mass_kg=self.mass_kg * mass_scale,
            inertia_kgm2=_shifted_inertia(self.inertia_kgm2, self.mass_kg, mass_scale, com_shift_m),
            attachments_body_m=_moved(self.attachments_body_m, shift),
            contact_points_body_m=_moved(self.contact_points_body_m, shift),
        )


@dataclass(frozen=True)
class CableParams:
    """One cable: a massless unilateral spring-damper of rest length ``length_m``.

    Tension T = max(0, k s + c ṡ) while the stretch s > 0, else 0 (slack): a cable never
    pushes.
    """

    # NOT in the paper: read off Fig. 1 / the video as about one metre (as kth_sml.toml).
    length_m: float = 1.0
    # NOT in the paper: a 1 m braided line has EA/L ~ 10⁴–10⁵ N/m. 10⁴ N/m stretches
    # 0.2 mm under the bar's weight (rigid for the controller) while the stiffest cable
    # mode (the bar's end on its cable, ~0.06 kg effective) stays at ω h ≈ 0.4 for RK4 at
    # 1 kHz, well inside its stability limit of 2.8.
    stiffness_n_per_m: float = 1.0e4
    # NOT in the paper: damping ratio ≈ 0.2 on that mode, so snatch loads ring down in
    # a few tens of milliseconds as a real line's internal friction does.
    damping_n_s_per_m: float = 10.0

    def __post_init__(self) -> None:
        _check_positive("cable length_m", self.length_m)
        _check_positive("cable stiffness_n_per_m", self.stiffness_n_per_m)
        _check_non_negative("cable damping_n_s_per_m", self.damping_n_s_per_m)


@dataclass(frozen=True)
class ContactParams:
    """Ground contact at z = 0, per contact point (a foot, or a bar end).

    Normal force N = max(0, k δ − c ż) for penetration δ > 0 (never pulls). Friction is
    regularized Coulomb, F_t = −μ N v_t / √(‖v_t‖² + v_reg²) with v_reg =
    max(``stiction_velocity_mps``, μN / ``friction_max_damping_n_s_per_m``): below
    v_reg it is viscous, which stops sliding but lets a body creep under a sustained
    tangential load smaller than μN (a known limit of regularized friction). The slope
    cap keeps the contact stable for RK4 at 1 kHz during impacts. Rolling resistance
    τ = −μ_r N r ω / √(‖ω‖² + ω_reg²) (r the contact radius) stops a round body rolling
    forever; ω_reg is capped the same way by ``rolling_max_damping_n_m_s``.
    """

    stiffness_n_per_m: float
    damping_n_s_per_m: float
    friction_coefficient: float
    stiction_velocity_mps: float = 0.005
    friction_max_damping_n_s_per_m: float = 100.0
    rolling_coefficient: float = 0.0
    rolling_velocity_radps: float = 0.05
    rolling_max_damping_n_m_s: float = 0.02

    def __post_init__(self) -> None:
        _check_positive("contact stiffness_n_per_m", self.stiffness_n_per_m)
        _check_non_negative("contact damping_n_s_per_m", self.damping_n_s_per_m)
        _check_non_negative("friction_coefficient", self.friction_coefficient)
        _check_positive("stiction_velocity_mps", self.stiction_velocity_mps)
        _check_positive("friction_max_damping_n_s_per_m", self.friction_max_damping_n_s_per_m)
        _check_non_negative("rolling_coefficient", self.rolling_coefficient)
        _check_positive("rolling_velocity_radps", self.rolling_velocity_radps)
        _check_positive("rolling_max_damping_n_m_s", self.rolling_max_damping_n_m_s)


# NOT in the paper, chosen for RK4 at 1 kHz. UAV on four feet: 1.2·10⁴ N/m per foot sinks
# 0.24 mm at rest, bounces at ω ≈ 200 rad/s (ω h = 0.2), damping ratio ≈ 0.7. Friction
# of skids on a lab floor, μ ≈ 0.6; the slope cap gives a sliding decay ≤ 10³ /s.
UAV_CONTACT = ContactParams(
    stiffness_n_per_m=1.2e4,
    damping_n_s_per_m=80.0,
    friction_coefficient=0.6,
    friction_max_damping_n_s_per_m=250.0,
)
# Bar on its two ends: 5·10³ N/m per end sinks 0.4 mm; its pitch mode on the ground is
# ω ≈ 280 rad/s. Rolling resistance μ_r = 0.02 stops the tube rolling in about a second.
# It suits a plate or a frame of about a kilogram on three or four corners as well (sinks
# < 0.5 mm, bounces at ω ≈ 150 rad/s); point corners (radius 0) do not roll.
BAR_CONTACT = ContactParams(
    stiffness_n_per_m=5.0e3,
    damping_n_s_per_m=30.0,
    friction_coefficient=0.5,
    friction_max_damping_n_s_per_m=50.0,
    rolling_coefficient=0.02,
)


@dataclass(frozen=True)
class WindParams:
    """A deterministic wind field, uniform in space: w(t) = mean + Σ_j a_j sin(ω_j t + φ_j)
    per axis, ``n_components`` sinusoids per axis with frequencies log-uniform in
    ``gust_band_hz``, random phases and amplitudes scaled so each axis' gust has standard
    deviation ``gust_std_mps``; all drawn from ``seed``. Wind acts only through the
    bodies' drag (zero drag coefficients: no wind force)."""

    mean_velocity_mps: Vec3 = (0.0, 0.0, 0.0)
    gust_std_mps: Vec3 = (0.0, 0.0, 0.0)
    gust_band_hz: tuple[float, float] = (0.05, 1.0)
    n_components: int = 4
    seed: int = 0

    def __post_init__(self) -> None:
        for value in self.gust_std_mps:
            _check_non_negative("gust_std_mps", value)
        low, high = self.gust_band_hz
        if not 0.0 < low <= high:
            raise ValueError("gust_band_hz must be 0 < low ≤ high")
        if self.n_components < 1:
            raise ValueError("n_components must be ≥ 1")

    @property
    def is_calm(self) -> bool:
        """No wind at all."""
        return not any(self.mean_velocity_mps) and not any(self.gust_std_mps)

    def components(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(amplitude [m/s], angular frequency [rad/s], phase [rad]), each shape
        (3, n_components); deterministic for ``seed``."""
        rng = np.random.default_rng(self.seed)
        K = self.n_components
        low, high = self.gust_band_hz
        freq_hz = np.exp(rng.uniform(math.log(low), math.log(high), size=(3, K)))
        phase = rng.uniform(0.0, 2.0 * math.pi, size=(3, K))
        # Equal amplitudes a per component: the variance of Σ a sin(·) is K a²/2.
        amplitude = np.repeat(
            np.asarray(self.gust_std_mps, dtype=float)[:, None] * math.sqrt(2.0 / K), K, axis=1
        )
        return amplitude, 2.0 * math.pi * freq_hz, phase


@dataclass(frozen=True)
class MismatchParams:
    """Deliberate differences between the plant and the nominal parameters it was built
    from: scale factors on the masses (inertias scale with them), one per UAV, and a shift
    of the payload's CoM along its x axis [m] (the bar's: towards end 2)."""

    uav_mass_scale: tuple[float, ...] = (1.0, 1.0)
    bar_mass_scale: float = 1.0
    bar_com_shift_m: float = 0.0

    @classmethod
    def random(
        cls, seed: int, mass_sigma_rel: float = 0.05, com_sigma_m: float = 0.02, n_uavs: int = 2
    ) -> MismatchParams:
        """Gaussian mass errors (relative σ) and CoM shift (σ [m]) for ``n_uavs`` UAVs,
        deterministic for ``seed``; scale factors are clipped to [0.5, 1.5]."""
        rng = np.random.default_rng(seed)
        scales = np.clip(1.0 + mass_sigma_rel * rng.standard_normal(n_uavs + 1), 0.5, 1.5)
        shift = float(com_sigma_m * rng.standard_normal())
        return cls(tuple(float(s) for s in scales[:n_uavs]), float(scales[n_uavs]), shift)


@dataclass(frozen=True)
class PlantParams:
    """Everything the plant needs. ``step_s`` is the fixed RK4 step (1 kHz default).

    N = len(``uavs``) UAVs (2 to 8) carry the payload, cable i from UAV i. The payload is
    ``payload`` when given, else ``bar`` (then N = 2); ``bar_contact`` is the payload's
    ground contact at each of its contact points either way. The bodies are named "uav1"
    … "uavN" and "bar", or "payload" for a payload that is not ``bar``.
    """

    uavs: tuple[UavBodyParams, ...] = (UavBodyParams(), UavBodyParams())
    bar: BarParams = field(default_factory=BarParams)
    cables: tuple[CableParams, ...] = (CableParams(), CableParams())
    uav_contact: ContactParams = UAV_CONTACT
    bar_contact: ContactParams = BAR_CONTACT
    wind: WindParams = field(default_factory=WindParams)
    gravity_mps2: float = 9.81
    step_s: float = 0.001
    payload: PayloadBodyParams | None = None

    def __post_init__(self) -> None:
        _check_non_negative("gravity_mps2", self.gravity_mps2)
        _check_positive("step_s", self.step_s)
        n = len(self.uavs)
        if not MIN_VEHICLES <= n <= MAX_VEHICLES:
            raise ValueError(f"the plant flies {MIN_VEHICLES} to {MAX_VEHICLES} UAVs, not {n}")
        attachments = len(self.payload_body().attachments_body_m)
        if len(self.cables) != n or attachments != n:
            raise ValueError(
                f"{n} UAVs need {n} cables and {n} attachments on the payload, not "
                f"{len(self.cables)} and {attachments}"
            )

    @property
    def n_uavs(self) -> int:
        """N."""
        return len(self.uavs)

    @property
    def payload_name(self) -> str:
        """The payload body's name: "bar", or "payload" for one that is not ``bar``."""
        return "bar" if self.payload is None else "payload"

    def payload_body(self) -> PayloadBodyParams:
        """The payload as a rigid body (``payload``, or ``bar``'s)."""
        return self.bar.payload_body() if self.payload is None else self.payload

    def with_mismatch(self, mismatch: MismatchParams) -> PlantParams:
        """These parameters with ``mismatch`` applied (masses and inertias scaled, the
        payload's CoM shifted; an explicit inertia is shifted by the parallel-axis
        theorem)."""
        if len(mismatch.uav_mass_scale) != self.n_uavs:
            raise ValueError(
                f"{len(mismatch.uav_mass_scale)} UAV mass scales for {self.n_uavs} UAVs"
            )
        uavs = tuple(
            dataclasses.replace(
                uav,
                mass_kg=uav.mass_kg * scale,
                inertia_kgm2=_scaled(uav.inertia_kgm2, scale),
            )
            for uav, scale in zip(self.uavs, mismatch.uav_mass_scale, strict=True)
        )
        if self.payload is not None:
            payload = self.payload.with_mass_and_com_shift(
                mismatch.bar_mass_scale, mismatch.bar_com_shift_m
            )
            return dataclasses.replace(self, uavs=uavs, payload=payload)
        bar = self.bar
        inertia: Mat3 | None = None
        if bar.inertia_kgm2 is not None:
            inertia = _shifted_inertia(
                bar.inertia_kgm2, bar.mass_kg, mismatch.bar_mass_scale, mismatch.bar_com_shift_m
            )
        bar = dataclasses.replace(
            bar,
            mass_kg=bar.mass_kg * mismatch.bar_mass_scale,
            com_from_end1_m=bar.com_from_end1_m + mismatch.bar_com_shift_m,
            inertia_kgm2=inertia,
        )
        return dataclasses.replace(self, uavs=uavs, bar=bar)


def _scaled(inertia: Mat3, scale: float) -> Mat3:
    return as_mat3(np.array(inertia, dtype=float) * scale)


def _shifted_inertia(inertia: Mat3, mass_kg: float, mass_scale: float, shift_m: float) -> Mat3:
    J = np.array(inertia) * mass_scale
    # Moving the reference point by δ along x adds m δ² about y and z.
    extra = mass_kg * mass_scale * shift_m**2
    J[1, 1] += extra
    J[2, 2] += extra
    return as_mat3(J)


def _moved(points: tuple[Vec3, ...], shift: Vec3) -> tuple[Vec3, ...]:
    """``points`` seen from an origin moved by ``shift``."""
    return tuple((p[0] - shift[0], p[1] - shift[1], p[2] - shift[2]) for p in points)
