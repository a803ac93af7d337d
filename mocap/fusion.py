"""Rigid-body state estimation from motion-capture poses: pure, time is an argument.

Per rigid body a ``RigidBodyFilter`` turns timestamped ``BodyPose`` samples into a
``BodyState`` predicted to any requested time: position and velocity (arena frame, ENU-like,
z up), attitude as a quaternion and the paper's Z-Y-X Euler angles (eq. (2)), body rates
(FLU body frame), plus the age of the last measurement and tracked/healthy flags.

Model (per axis, identical for the three axes so one 2×2 covariance serves all three):

* translation — a constant-velocity Kalman filter, state (p, v), white-acceleration process
  noise of spectral density ``position_accel_psd`` and a position measurement of standard
  deviation ``position_noise_m``;
* rotation — the same constant-velocity filter on the attitude *error* (an error-state, or
  multiplicative, Kalman filter): the nominal attitude q turns at the body rate ω,
  q(t + h) = q(t) ⊗ exp(ω h), which is exact for a constant body rate; each measurement's
  innovation is the rotation vector of q_pred⁻¹ ⊗ q_meas, in the body frame. Rates thus come
  from quaternion differences, never from Euler-angle differences, so yaw crossing ±π
  causes no jump.

Samples older than (or as old as) the last one are ignored; untracked samples update nothing
but clear the ``tracked`` flag; after a dropout longer than ``reset_after_s`` the filter
restarts from the next sample instead of trusting a stale velocity. Every quaternion,
rotation and Euler conversion goes through ``geometry.frames``.

Innovation gate: a pose no rigid body can reach from the last estimate is refused, not
fused — a position further from the prediction p + v·h than ½·a_max·h² plus ``gate_sigmas``
standard deviations of the estimate's own error carried h ahead and of the measurement
noise, or an attitude turned further from the last estimate than ω_max·h plus as many
deviations (h: the time since the last fused sample; the physical bounds stand in for the
process noise). The bound grows with h, so a body that really moved while it was not seen
is taken back once it could have got there; taken back further from the prediction than
the filter's own spread allows, the filter restarts from it (its velocity is unknown).

A frame in which every tracked body repeats its previous pose bit for bit is no new
measurement when ``MocapFusion.refuse_repeats`` is set (in flight: a frozen pipeline
re-sends old poses with new frame numbers). Refused samples
leave the filter as it was, so the body ages as if the frame had not come; each filter counts
them by reason and how many in a row (``BodyState.refused_in_a_row``).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from geometry import frames
from geometry.arrays import FloatArray
from mocap.qtm_protocol import BodyPose, MocapFrame


@dataclass(frozen=True)
class FusionConfig:
    """Tuning of the filters. Units in the names; PSD = power spectral density.

    Defaults fit a QTM system at 100–300 Hz tracking quadrotors: sub-millimetre position noise
    (QTM residuals are typically 0.2–1 mm), ~0.1° attitude noise, and accelerations of a few
    m/s² and tens of rad/s² that the white-noise model has to absorb.
    """

    position_accel_psd: float = 4.0
    """Translational white-acceleration PSD q [(m/s²)²/Hz = m²/s³]."""
    position_noise_m: float = 5e-4
    """Measurement noise, 1σ per axis [m]."""
    angular_accel_psd: float = 100.0
    """Rotational white-acceleration PSD [(rad/s²)²/Hz = rad²/s³]."""
    attitude_noise_rad: float = 2e-3
    """Attitude measurement noise, 1σ per body axis [rad]."""
    initial_velocity_std_mps: float = 5.0
    """Prior 1σ of the velocity at the first sample [m/s]."""
    initial_rate_std_radps: float = 10.0
    """Prior 1σ of the body rates at the first sample [rad/s]."""
    max_age_s: float = 0.05
    """A body is healthy while tracked and its last measurement is younger than this [s]."""
    reset_after_s: float = 0.5
    """A gap longer than this restarts the filter from the next sample [s]."""
    max_prediction_s: float = 0.1
    """Predictions extrapolate at most this far from the last measurement [s]; older data
    is held there (and flagged unhealthy by ``max_age_s``) rather than run away."""
    time_source: Literal["capture", "receive"] = "capture"
    """Sample time of a frame: QTM's capture timestamp mapped onto the local clock by
    ``CaptureClock`` (removes network jitter), or the local receive time itself."""
    gate_max_accel_mps2: float = 30.0
    """The innovation gate's bound on a body's acceleration [m/s²]: 3 g, above what a
    quadrotor's thrust gives and what the bar's swing does, far below a 1 m jump in a frame."""
    gate_max_angular_rate_radps: float = math.radians(720.0)
    """The gate's bound on a body's turn rate [rad/s]: twice the fastest rate PX4's
    multicopter defaults command (MC_*RATE_MAX ≤ 360°/s)."""
    gate_sigmas: float = 6.0
    """Standard deviations of predicted error and measurement noise the gate allows on top
    of the physical bounds (a 3-D Gaussian is beyond 6σ about once in 10⁷ samples)."""

    def __post_init__(self) -> None:
        positive = (
            "position_accel_psd",
            "position_noise_m",
            "angular_accel_psd",
            "attitude_noise_rad",
            "initial_velocity_std_mps",
            "initial_rate_std_radps",
            "max_age_s",
            "reset_after_s",
            "gate_max_accel_mps2",
            "gate_max_angular_rate_radps",
            "gate_sigmas",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"FusionConfig.{name} must be finite and > 0, got {value}")
        if not (math.isfinite(self.max_prediction_s) and self.max_prediction_s >= 0.0):
            raise ValueError("FusionConfig.max_prediction_s must be finite and ≥ 0")


@dataclass(frozen=True, eq=False)
class BodyState:
    """A rigid body's estimated state at ``time_s`` (the requested tick time) [s].

    ``position_m``, ``velocity_mps``: shape (3,), arena frame. ``quaternion``: shape (4,),
    (w, x, y, z), body (FLU) → arena. ``euler_zyx_rad``: shape (3,), the paper's (φ, θ, ψ),
    ψ in (−π, π]. ``body_rates_radps``: shape (3,), (p, q, r) in the FLU body frame.
    ``angular_velocity_world_radps``: shape (3,), the same rotation rate in the arena frame.
    ``age_s``: time since the last tracked measurement (inf if none yet).
    ``tracked``: the newest sample had the body tracked. ``healthy``: tracked and
    ``age_s`` ≤ ``FusionConfig.max_age_s``. ``position_std_m``: predicted 1σ per axis.
    ``refused_in_a_row``: the newest samples refused (gate or repeat) since the last fused
    one, ``refusal`` why the last was (empty when none). Before the first tracked sample
    the arrays are NaN and both flags False.
    """

    name: str
    time_s: float
    position_m: FloatArray
    velocity_mps: FloatArray
    quaternion: FloatArray
    euler_zyx_rad: FloatArray
    body_rates_radps: FloatArray
    angular_velocity_world_radps: FloatArray
    age_s: float
    tracked: bool
    healthy: bool
    position_std_m: float
    refused_in_a_row: int = 0
    refusal: str = ""


REFUSAL_REASONS = ("position", "attitude", "repeated")
"""Why the fusion refuses a tracked sample: beyond the gate's reach in position or in
attitude, or a frame repeated bit for bit (``MocapFusion.refuse_repeats``)."""


class _ConstantVelocityAxes:
    """Three independent constant-velocity Kalman filters sharing one 2×2 covariance.

    ``mean``: shape (2, 3), rows (value, rate) per axis. The textbook discrete white-noise
    acceleration model: F = [[1, h], [0, 1]], Q = q·[[h³/3, h²/2], [h²/2, h]], H = [1, 0].
    The symmetric covariance is kept as three scalars (p00, p01, p11): at three filters
    per body and two frames per tick, numpy's per-call cost on 2×2 matrices dominated.
    """

    def __init__(self, accel_psd: float, noise_std: float, rate_std: float) -> None:
        self.q = accel_psd
        self.r = noise_std**2
        self.mean = np.zeros((2, 3))
        self.p00, self.p01, self.p11 = self.r, 0.0, rate_std**2

    def predict(self, h: float) -> None:
        q = self.q
        self.mean[0] += h * self.mean[1]
        p00, p01, p11 = self.p00, self.p01, self.p11
        self.p00 = p00 + 2.0 * h * p01 + h * h * p11 + q * h**3 / 3.0
        self.p01 = p01 + h * p11 + q * h * h / 2.0
        self.p11 = p11 + q * h

    def update(self, innovation: FloatArray) -> FloatArray:
        """Apply a measurement of the value row; returns the correction, shape (2, 3)."""
        p00, p01, p11 = self.p00, self.p01, self.p11
        S = p00 + self.r
        k0, k1 = p00 / S, p01 / S
        correction = np.empty((2, 3))
        correction[0] = k0 * innovation
        correction[1] = k1 * innovation
        self.mean += correction
        self.p00, self.p01, self.p11 = p00 - k0 * p00, p01 - k0 * p01, p11 - k1 * p01
        return correction

    def predicted_value_variance(self, h: float) -> float:
        return self.extrapolated_variance(h) + self.q * h**3 / 3.0

    def snapshot(self) -> dict[str, Any]:
        return {"mean": self.mean.tolist(), "p": [self.p00, self.p01, self.p11]}

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        self.mean = np.array(snapshot["mean"], dtype=float).reshape(2, 3)
        self.p00, self.p01, self.p11 = (float(v) for v in snapshot["p"])

    def extrapolated_variance(self, h: float) -> float:
        """The value's variance h ahead from the estimate's own uncertainty alone (no
        process noise: the innovation gate bounds the acceleration itself)."""
        return self.p00 + 2.0 * h * self.p01 + h * h * self.p11


def _nan(n: int) -> FloatArray:
    return np.full(n, math.nan)


class RigidBodyFilter:
    """The state estimator of one rigid body (see the module docstring).

    Feed it samples with ``update(pose, t_s)`` in any order; ask ``state_at(t_s)`` for
    the state predicted to a tick time. Times are seconds on one clock chosen by the caller.
    """

    def __init__(self, name: str, config: FusionConfig | None = None) -> None:
        self.name = name
        self.config = config or FusionConfig()
        self._translation: _ConstantVelocityAxes | None = None
        self._rotation: _ConstantVelocityAxes | None = None
        self._q = np.array([1.0, 0.0, 0.0, 0.0])
        self._last_measurement_s = -math.inf  # last *tracked* sample the filter used
        self._last_sample_s = -math.inf  # newest sample of any kind
        self._tracked = False
        self.updates = 0
        """Tracked samples used."""
        self.out_of_order = 0
        """Samples ignored for being older than (or as old as) the newest one."""
        self.untracked_samples = 0
        """Samples in which QTM did not track the body."""
        self.resets = 0
        """Restarts after a dropout longer than ``reset_after_s``."""
        self.refused: dict[str, int] = dict.fromkeys(REFUSAL_REASONS, 0)
        """Tracked samples refused, by reason (``REFUSAL_REASONS``)."""
        self.refused_in_a_row = 0
        self.last_refusal = ""

    @property
    def initialized(self) -> bool:
        """True once a tracked sample has been used."""
        return self._translation is not None

    def snapshot(self) -> dict[str, Any]:
        """Everything the filter's future output depends on, as JSON values (exact:
        ``restore`` on a filter of the same config continues bit for bit)."""
        axes = (self._translation, self._rotation)
        return {
            "axes": None if None in axes else [a.snapshot() for a in axes],  # type: ignore[union-attr]
            "q": self._q.tolist(),
            "last_measurement_s": self._last_measurement_s,
            "last_sample_s": self._last_sample_s,
            "tracked": self._tracked,
            "refused": dict(self.refused),
            "refused_in_a_row": self.refused_in_a_row,
            "last_refusal": self.last_refusal,
            "counts": [self.updates, self.out_of_order, self.untracked_samples, self.resets],
        }

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        """Continue from ``snapshot`` (``snapshot``'s, taken of a filter of this config)."""
        if snapshot["axes"] is None:
            self._translation = self._rotation = None
        else:
            self._translation, self._rotation = self._new_axes()
            self._translation.restore(snapshot["axes"][0])
            self._rotation.restore(snapshot["axes"][1])
        self._q = np.array(snapshot["q"], dtype=float)
        self._last_measurement_s = float(snapshot["last_measurement_s"])
        self._last_sample_s = float(snapshot["last_sample_s"])
        self._tracked = bool(snapshot["tracked"])
        self.refused = {reason: int(n) for reason, n in snapshot["refused"].items()}
        self.refused_in_a_row = int(snapshot["refused_in_a_row"])
        self.last_refusal = str(snapshot["last_refusal"])
        self.updates, self.out_of_order, self.untracked_samples, self.resets = (
            int(n) for n in snapshot["counts"]
        )

    def update(self, pose: BodyPose, t_s: float) -> bool:
        """Fuse one sample taken at ``t_s`` [s]; returns whether it was used."""
        if not math.isfinite(t_s) or t_s <= self._last_sample_s:
            self.out_of_order += 1
            return False
        self._last_sample_s = t_s
        if not pose.tracked:
            self.untracked_samples += 1
            self._tracked = False
            return False
        if self._translation is None or t_s - self._last_measurement_s > self.config.reset_after_s:
            if self._translation is not None:
                self.resets += 1
            self._initialize(pose, t_s)
            self._fused()
            return True
        assert self._rotation is not None
        h = t_s - self._last_measurement_s
        refusal = self._unreachable(pose, h)
        if refusal is not None:
            self._refuse(*refusal)
            return False
        if self.refused_in_a_row and self._unexpected(pose, h):
            # Taken back after refusals, where the filter did not expect it: the estimate it
            # was refused against is no guide to its velocity. Restart, as after a dropout.
            self.resets += 1
            self._initialize(pose, t_s)
            self._fused()
            return True
        self._fused()
        self._translation.predict(h)
        self._rotation.predict(h)
        omega = self._rotation.mean[1]
        q_pred = frames.quaternion_multiply(
            self._q, frames.quaternion_from_rotation_vector(omega * h)
        )
        self._translation.update(pose.position_m - self._translation.mean[0])
        # Innovation: the rotation from the predicted to the measured attitude, body frame.
        innovation = frames.rotation_vector_from_quaternion(
            frames.quaternion_multiply(frames.quaternion_conjugate(q_pred), pose.quaternion)
        )
        correction = self._rotation.update(innovation)
        q_new = frames.quaternion_multiply(
            q_pred, frames.quaternion_from_rotation_vector(correction[0])
        )
        self._q = q_new / np.linalg.norm(q_new)
        self._rotation.mean[0] = 0.0  # the attitude error is now in the nominal quaternion
        self._last_measurement_s = t_s
        return True

    def refuse_repeat(self, t_s: float) -> None:
        """A tracked sample at ``t_s`` [s] that repeats the last bit for bit, in a frozen
        stream: no measurement (the body ages), counted."""
        if math.isfinite(t_s) and t_s > self._last_sample_s:
            self._last_sample_s = t_s
        self._refuse("repeated", "repeated bit for bit: a frozen stream")

    def _refuse(self, reason: str, why: str) -> None:
        self.refused[reason] += 1
        self.refused_in_a_row += 1
        self.last_refusal = why

    def _fused(self) -> None:
        self._tracked = True
        self.updates += 1
        self.refused_in_a_row = 0
        self.last_refusal = ""

    def _unreachable(self, pose: BodyPose, h: float) -> tuple[str, str] | None:
        """Why no rigid body could be at ``pose`` ``h`` seconds after the last fused sample
        (reason, words), or None when it could (the module docstring's gate)."""
        assert self._translation is not None and self._rotation is not None
        c = self.config
        axes = self._translation
        predicted = axes.mean[0] + h * axes.mean[1]
        miss_m = float(np.linalg.norm(pose.position_m - predicted))
        spread_m = math.sqrt(axes.extrapolated_variance(h) + axes.r)
        reach_m = 0.5 * c.gate_max_accel_mps2 * h * h + c.gate_sigmas * spread_m
        if not miss_m <= reach_m:  # NaN is refused too
            return (
                "position",
                f"{miss_m:.3f} m from its prediction, {reach_m:.3f} m reachable in"
                f" {h * 1e3:.0f} ms",
            )
        turn = frames.quaternion_multiply(frames.quaternion_conjugate(self._q), pose.quaternion)
        turn_rad = float(np.linalg.norm(frames.rotation_vector_from_quaternion(turn)))
        rotation = self._rotation
        spread_rad = math.sqrt(rotation.p00 + rotation.r)  # the turn is from the estimate
        reach_rad = c.gate_max_angular_rate_radps * h + c.gate_sigmas * spread_rad
        if not turn_rad <= reach_rad:
            return (
                "attitude",
                f"turned {math.degrees(turn_rad):.0f}° from its estimate,"
                f" {math.degrees(reach_rad):.0f}° reachable in {h * 1e3:.0f} ms",
            )
        return None

    def _unexpected(self, pose: BodyPose, h: float) -> bool:
        """``pose`` beyond ``gate_sigmas`` of the filter's own predicted spread (its process
        noise included), ``h`` seconds after the last fused sample."""
        assert self._translation is not None
        axes = self._translation
        miss_m = float(np.linalg.norm(pose.position_m - (axes.mean[0] + h * axes.mean[1])))
        spread_m = math.sqrt(axes.predicted_value_variance(h) + axes.r)
        return miss_m > self.config.gate_sigmas * spread_m

    def _new_axes(self) -> tuple[_ConstantVelocityAxes, _ConstantVelocityAxes]:
        """Fresh translation and rotation filters, as the config tunes them."""
        c = self.config
        return (
            _ConstantVelocityAxes(
                c.position_accel_psd, c.position_noise_m, c.initial_velocity_std_mps
            ),
            _ConstantVelocityAxes(
                c.angular_accel_psd, c.attitude_noise_rad, c.initial_rate_std_radps
            ),
        )

    def _initialize(self, pose: BodyPose, t_s: float) -> None:
        self._translation, self._rotation = self._new_axes()
        self._translation.mean[0] = pose.position_m
        self._q = np.array(pose.quaternion, dtype=float)
        self._last_measurement_s = t_s

    def state_at(self, t_s: float) -> BodyState:
        """The state predicted to ``t_s`` [s] (the filter itself is not changed).

        The extrapolation horizon is clamped to ±``max_prediction_s`` around the last
        measurement; ``age_s`` is the true age, so a stale body is flagged, not hidden.
        """
        if self._translation is None or self._rotation is None:
            return BodyState(
                self.name, t_s, _nan(3), _nan(3), _nan(4), _nan(3), _nan(3), _nan(3),
                math.inf, False, False, math.nan,
            )  # fmt: skip
        age = t_s - self._last_measurement_s
        limit = self.config.max_prediction_s
        h = min(max(age, -limit), limit)
        position = self._translation.mean[0] + h * self._translation.mean[1]
        velocity = self._translation.mean[1].copy()
        omega = self._rotation.mean[1].copy()
        q = frames.quaternion_multiply(self._q, frames.quaternion_from_rotation_vector(omega * h))
        q = q / np.linalg.norm(q)
        if q[0] < 0.0:
            q = -q
        euler = frames.euler_zyx_from_quaternion(q)
        euler[2] = frames.wrap_angle(float(euler[2]))
        omega_world = frames.rotation_from_quaternion(q) @ omega
        healthy = self._tracked and age <= self.config.max_age_s
        std = math.sqrt(max(self._translation.predicted_value_variance(h), 0.0))
        return BodyState(
            self.name, t_s, position, velocity, q, euler, omega, omega_world,
            age, self._tracked, healthy, std, self.refused_in_a_row, self.last_refusal,
        )  # fmt: skip


class CaptureClock:
    """Maps QTM capture timestamps [µs] onto the local clock [s] (pure).

    The offset local − capture is the smallest one seen (the sample with the least network
    and scheduling delay), allowed to grow by ``drift_allowance`` seconds per second so that
    clock drift between the QTM computer and ours cannot freeze it (the default, 100 ppm, is
    above a PC crystal's tolerance; the price is up to that fraction of a sample period of
    extra delay on samples that arrive late). A timestamp going backwards means a new
    measurement and restarts the estimate.
    """

    def __init__(self, drift_allowance: float = 1e-4) -> None:
        self.drift_allowance = drift_allowance
        self._offset_s: float | None = None
        self._last_capture_s = -math.inf
        self._last_receive_s = -math.inf

    def to_local(self, timestamp_us: int, receive_time_s: float) -> float:
        """The local time [s] at which the frame stamped ``timestamp_us`` was captured."""
        capture_s = timestamp_us * 1e-6
        if not math.isfinite(receive_time_s):
            return capture_s
        sample_offset = receive_time_s - capture_s
        if self._offset_s is None or capture_s < self._last_capture_s:
            self._offset_s = sample_offset
        else:
            leak = self.drift_allowance * max(receive_time_s - self._last_receive_s, 0.0)
            self._offset_s = min(self._offset_s + leak, sample_offset)
        self._last_capture_s = capture_s
        self._last_receive_s = receive_time_s
        return capture_s + self._offset_s

    def snapshot(self) -> list[float | None]:
        return [self._offset_s, self._last_capture_s, self._last_receive_s]

    def restore(self, snapshot: list[float | None]) -> None:
        offset, last_capture, last_receive = snapshot
        self._offset_s = None if offset is None else float(offset)
        self._last_capture_s, self._last_receive_s = float(last_capture), float(last_receive)  # type: ignore[arg-type]


class MocapFusion:
    """One ``RigidBodyFilter`` per body name, fed whole ``MocapFrame``s (pure).

    ``update(frame)`` picks the sample time per ``FusionConfig.time_source``; bodies appear
    the first time a frame names them. ``states(t_s)`` predicts every body to a tick time.
    ``refuse_repeats``: a frame whose tracked bodies all repeat their previous poses bit for
    bit is not a measurement (set it while the bodies fly: at rest, and without measurement
    noise, a resting system repeats itself).
    """

    def __init__(self, config: FusionConfig | None = None, names: Iterable[str] = ()) -> None:
        self.config = config or FusionConfig()
        self.clock = CaptureClock()
        self.filters: dict[str, RigidBodyFilter] = {
            name: RigidBodyFilter(name, self.config) for name in names
        }
        self.refuse_repeats = False
        self.repeated_frames = 0
        """Frames refused as repeated."""
        self._previous: dict[str, bytes] = {}  # each body's last tracked pose, as bytes

    def snapshot(self) -> dict[str, Any]:
        """Everything the fusion's future estimates depend on, as JSON values: a fusion of
        the same config restored from it and fed the same frames gives the same estimates
        bit for bit (a flight's mocap replayed from where its recording starts:
        supervisor/logs/mocap_replay.py)."""
        return {
            "clock": self.clock.snapshot(),
            "refuse_repeats": self.refuse_repeats,
            "repeated_frames": self.repeated_frames,
            "previous": {name: key.hex() for name, key in self._previous.items()},
            "filters": {name: f.snapshot() for name, f in self.filters.items()},
        }

    def restore(self, snapshot: Mapping[str, Any]) -> None:
        """Continue from ``snapshot`` (taken of a fusion of this config)."""
        self.clock.restore(snapshot["clock"])
        self.refuse_repeats = bool(snapshot["refuse_repeats"])
        self.repeated_frames = int(snapshot["repeated_frames"])
        self._previous = {name: bytes.fromhex(key) for name, key in snapshot["previous"].items()}
        self.filters = {}
        for name, state in snapshot["filters"].items():
            self._filter(name).restore(state)

    def sample_time_s(self, frame: MocapFrame) -> float:
        """The time [s] ``update`` assigns to ``frame``."""
        if self.config.time_source == "receive":
            return frame.receive_time_s
        return self.clock.to_local(frame.timestamp_us, frame.receive_time_s)

    def update(self, frame: MocapFrame) -> float:
        """Fuse every body of ``frame`` (unless it is refused as a repeat); returns the
        sample time used [s]."""
        t_s, _ = self._fuse(frame)
        return t_s

    def plausible(self, frame: MocapFrame) -> MocapFrame:
        """Fuse ``frame``; return it with every pose the fusion did not take (refused, or
        older than the newest) as untracked: what may be passed on as a measurement."""
        _, taken = self._fuse(frame)
        bodies = {
            name: pose if name in taken else BodyPose.untracked(name)
            for name, pose in frame.bodies.items()
        }
        return replace(frame, bodies=bodies)

    def _fuse(self, frame: MocapFrame) -> tuple[float, set[str]]:
        """The sample time [s] and the bodies whose poses were fused."""
        t_s = self.sample_time_s(frame)
        if self._repeats_previous(frame) and self.refuse_repeats:
            self.repeated_frames += 1
            for name, pose in frame.bodies.items():
                if pose.tracked:
                    self._filter(name).refuse_repeat(t_s)
            return t_s, set()
        taken = {name for name, pose in frame.bodies.items() if self.update_pose(pose, t_s, name)}
        return t_s, taken

    def _repeats_previous(self, frame: MocapFrame) -> bool:
        """Every tracked body of ``frame`` (at least one) bit for bit as in its last tracked
        sample; remembers this frame's poses."""
        repeated: bool | None = None
        for name, pose in frame.bodies.items():
            if not pose.tracked:
                continue
            key = pose.position_m.tobytes() + pose.quaternion.tobytes()
            repeated = repeated is not False and self._previous.get(name) == key
            self._previous[name] = key
        return bool(repeated)

    def refused(self) -> dict[str, int]:
        """Tracked samples refused so far, every body together, by reason."""
        totals = dict.fromkeys(REFUSAL_REASONS, 0)
        for body_filter in self.filters.values():
            for reason, n in body_filter.refused.items():
                totals[reason] += n
        return totals

    def _filter(self, name: str) -> RigidBodyFilter:
        body_filter = self.filters.get(name)
        if body_filter is None:
            body_filter = self.filters[name] = RigidBodyFilter(name, self.config)
        return body_filter

    def update_pose(self, pose: BodyPose, t_s: float, name: str | None = None) -> bool:
        """Fuse one body's sample taken at ``t_s`` [s]; returns whether it was used."""
        return self._filter(name or pose.name).update(pose, t_s)

    def state(self, name: str, t_s: float) -> BodyState:
        """One body's state at ``t_s``; an unknown name gives the never-measured state."""
        body_filter = self.filters.get(name) or RigidBodyFilter(name, self.config)
        return body_filter.state_at(t_s)

    def states(self, t_s: float) -> Mapping[str, BodyState]:
        """Every body's state predicted to the tick time ``t_s`` [s]."""
        return {name: f.state_at(t_s) for name, f in self.filters.items()}
