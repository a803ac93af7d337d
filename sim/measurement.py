"""A Qualisys-like motion-capture measurement model of the plant's rigid bodies.

Cameras capture the poses of "uav1", "uav2" and "bar" at a fixed rate; each captured frame
carries per-body position noise, orientation noise, occasional dropouts (single lost
frames and bursts, as when markers are occluded) and reaches the receiver a fixed latency
after capture. It is a pure component: time is an argument, nothing reads a clock, and
everything random comes from one seeded generator consumed a fixed amount per frame, so
a run is reproducible for a seed.

Use: every time the plant has advanced, ``capture(plant.truth())`` (it takes a frame when
one is due) and ``poll(now_s)`` for the frames delivered by ``now_s``; ``sample`` does
both. Positions are ENU metres (conversion to QTM's millimetres belongs to the QTM
server), quaternions (w, x, y, z) body → ENU with w ≥ 0.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from geometry.arrays import FloatArray
from sim.plant import PlantTruth

# Precedents for the defaults: Qualisys Miqus/Oqus systems track a well-marked rigid body
# with sub-millimetre position noise and about 0.1° orientation noise; 100 Hz is the
# stream rate used with PX4 in labs like KTH's; camera exposure + processing + UDP put
# the pose on the receiver 3–10 ms after capture.
DEFAULT_POSITION_SIGMA_M = 0.0005
DEFAULT_ORIENTATION_SIGMA_RAD = math.radians(0.1)


@dataclass(frozen=True)
class TrackingParams:
    """How often one body is lost. Each frame a new burst starts with probability
    ``burst_probability`` (a burst loses ``burst_frames`` = (min, max) consecutive
    frames, uniform, including the first); outside bursts a single frame is lost with
    probability ``dropout_probability``. The long-run lost fraction is
    f_b + (1 − f_b) p_drop with f_b = L̄ / ((1 − p_burst)/p_burst + L̄), L̄ the mean burst
    length."""

    dropout_probability: float = 0.002
    burst_probability: float = 0.0005
    burst_frames: tuple[int, int] = (10, 50)

    def __post_init__(self) -> None:
        for name in ("dropout_probability", "burst_probability"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"{name} must be in [0, 1], got {value}")
        low, high = self.burst_frames
        if not 1 <= low <= high:
            raise ValueError("burst_frames must be 1 ≤ min ≤ max")

    @property
    def lost_fraction(self) -> float:
        """The expected long-run fraction of frames in which the body is untracked."""
        b = self.burst_probability
        mean_burst = 0.5 * (self.burst_frames[0] + self.burst_frames[1])
        in_burst = 0.0 if b == 0.0 else mean_burst / ((1.0 - b) / b + mean_burst)
        return in_burst + (1.0 - in_burst) * self.dropout_probability


@dataclass(frozen=True)
class MocapParams:
    """The measurement model. Noise σ per axis: position [m]; orientation [rad] as a
    small rotation of the body frame (q_meas = q ⊗ exp(δ/2), δ ~ N(0, σ² I₃)). A frame
    captured at t is delivered at t + ``latency_s``. ``tracking`` applies to every body
    unless ``tracking_overrides`` names it."""

    rate_hz: float = 100.0
    position_sigma_m: float = DEFAULT_POSITION_SIGMA_M
    orientation_sigma_rad: float = DEFAULT_ORIENTATION_SIGMA_RAD
    latency_s: float = 0.005
    bodies: tuple[str, ...] = ("uav1", "uav2", "bar")
    tracking: TrackingParams = field(default_factory=TrackingParams)
    tracking_overrides: tuple[tuple[str, TrackingParams], ...] = ()
    seed: int = 0
    start_time_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.rate_hz > 0.0:
            raise ValueError("rate_hz must be > 0")
        for name in ("position_sigma_m", "orientation_sigma_rad", "latency_s"):
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"{name} must be ≥ 0")
        if not self.bodies or len(set(self.bodies)) != len(self.bodies):
            raise ValueError("bodies must be distinct names")
        unknown = {name for name, _ in self.tracking_overrides} - set(self.bodies)
        if unknown:
            raise ValueError(f"tracking_overrides name unknown bodies: {sorted(unknown)}")

    def tracking_for(self, body: str) -> TrackingParams:
        """The dropout model of ``body``."""
        return dict(self.tracking_overrides).get(body, self.tracking)


@dataclass(frozen=True)
class MocapPose:
    """A measured rigid-body pose: position ENU [m] (3,), quaternion (w, x, y, z) body →
    ENU (4,), unit, w ≥ 0."""

    position_m: FloatArray
    quaternion: FloatArray


@dataclass(frozen=True)
class MocapFrame:
    """One motion-capture frame: its number (the capture slot, counted from
    ``start_time_s`` at ``rate_hz``; numbers skip when slots were not captured), when it
    was captured and delivered [s], and per body its pose or None when untracked."""

    frame_number: int
    capture_time_s: float
    delivery_time_s: float
    poses: Mapping[str, MocapPose | None]

    def pose(self, body: str) -> MocapPose | None:
        """The pose of ``body`` in this frame, None if untracked."""
        return self.poses[body]


def _quaternion_product(a: FloatArray, b: FloatArray) -> FloatArray:
    """Hamilton product a ⊗ b of (w, x, y, z) quaternions."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


def _perturbed(q: FloatArray, rotation_vector: FloatArray) -> FloatArray:
    """q ⊗ exp(δ/2): q rotated by the small body-frame rotation vector δ [rad];
    normalized, w ≥ 0."""
    angle = float(np.linalg.norm(rotation_vector))
    if angle > 0.0:
        dq = np.concatenate(
            ([math.cos(0.5 * angle)], math.sin(0.5 * angle) / angle * rotation_vector)
        )
        q = _quaternion_product(q, dq)
    q = q / np.linalg.norm(q)
    return q if q[0] >= 0.0 else -q


class MocapModel:
    """Takes frames of a plant's truth when they are due and delivers them after the
    latency. Stateful only in its clock-free schedule, its delivery queue, the dropout
    bursts in progress and its seeded generator."""

    def __init__(self, params: MocapParams | None = None) -> None:
        self._params = MocapParams() if params is None else params
        self._rng = np.random.default_rng(self._params.seed)
        self._next_slot = 0
        self._queue: deque[MocapFrame] = deque()
        self._burst_left = [0] * len(self._params.bodies)
        self._tracking = [self._params.tracking_for(body) for body in self._params.bodies]

    @property
    def params(self) -> MocapParams:
        """The model's parameters."""
        return self._params

    @property
    def next_capture_time_s(self) -> float:
        """When the next frame is due [s]."""
        return self._params.start_time_s + self._next_slot / self._params.rate_hz

    @property
    def next_delivery_time_s(self) -> float:
        """When the next frame reaches the receiver, if it is not dropped as a whole [s]."""
        if self._queue:
            return self._queue[0].delivery_time_s
        return self.next_capture_time_s + self._params.latency_s

    @property
    def pending(self) -> int:
        """Frames captured but not yet delivered."""
        return len(self._queue)

    def _slot(self, time_s: float) -> int:
        # A small tolerance so that a plant time of k·(1/rate) computed as steps × 1 ms
        # lands in slot k despite rounding.
        return math.floor((time_s - self._params.start_time_s) * self._params.rate_hz + 1e-6)

    def due(self, time_s: float) -> bool:
        """Whether a frame is due at ``time_s``: ``capture`` then takes one (callers skip
        building the plant's truth when it would not)."""
        return self._slot(time_s) >= self._next_slot

    def capture(self, truth: PlantTruth) -> MocapFrame | None:
        """Capture a frame of ``truth`` if one is due at ``truth.time_s`` (at most one per
        call; slots missed since the last capture are skipped, not made up). The frame is
        queued for delivery and also returned; None when no frame was due."""
        if not self.due(truth.time_s):
            return None
        slot = self._slot(truth.time_s)
        self._next_slot = slot + 1
        p = self._params
        n = len(p.bodies)
        # A fixed amount of randomness per frame, whatever is tracked: reproducible.
        noise = self._rng.standard_normal((n, 6))
        draws = self._rng.random((n, 2))
        lengths = [
            int(self._rng.integers(t.burst_frames[0], t.burst_frames[1] + 1))
            for t in self._tracking
        ]
        poses: dict[str, MocapPose | None] = {}
        for j, body in enumerate(p.bodies):
            if body not in truth.bodies:
                raise ValueError(f"truth has no body {body!r}")
            tracking = self._tracking[j]
            if self._burst_left[j] > 0:
                self._burst_left[j] -= 1
                poses[body] = None
                continue
            if draws[j, 0] < tracking.burst_probability:
                self._burst_left[j] = lengths[j] - 1
                poses[body] = None
                continue
            if draws[j, 1] < tracking.dropout_probability:
                poses[body] = None
                continue
            true = truth.bodies[body]
            position = true.position_m + p.position_sigma_m * noise[j, :3]
            quaternion = _perturbed(true.quaternion, p.orientation_sigma_rad * noise[j, 3:])
            poses[body] = MocapPose(position, quaternion)
        frame = MocapFrame(slot, truth.time_s, truth.time_s + p.latency_s, poses)
        self._queue.append(frame)
        return frame

    def poll(self, now_s: float) -> list[MocapFrame]:
        """The frames delivered by ``now_s`` (capture time + latency ≤ now_s), oldest
        first; each is returned once."""
        delivered = []
        # The same tolerance as the schedule: a latency of whole steps is on time.
        while self._queue and self._queue[0].delivery_time_s <= now_s + 1e-9:
            delivered.append(self._queue.popleft())
        return delivered

    def sample(self, truth: PlantTruth, now_s: float) -> list[MocapFrame]:
        """``capture(truth)`` then ``poll(now_s)``."""
        self.capture(truth)
        return self.poll(now_s)
