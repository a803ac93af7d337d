"""The motion-capture measurement model: schedule, latency, noise statistics, dropouts,
determinism."""

from __future__ import annotations

import math

import numpy as np
import pytest

from geometry.frames import quaternion_from_euler_zyx
from sim.measurement import MocapFrame, MocapModel, MocapParams, TrackingParams
from sim.plant import BODY_NAMES, BodyTruth, Plant, PlantTruth

NO_LOSS = TrackingParams(dropout_probability=0.0, burst_probability=0.0)
POSITIONS = {"uav1": (-0.7, 0.1, 1.5), "uav2": (0.8, -0.2, 1.6), "bar": (0.0, 0.0, 0.6)}
ATTITUDES = {"uav1": (0.1, -0.2, 0.5), "uav2": (0.0, 0.05, -2.0), "bar": (0.0, 0.3, 3.0)}


def still_truth(time_s: float) -> PlantTruth:
    """Three bodies at fixed, tilted poses."""
    bodies: dict[str, BodyTruth] = {
        name: BodyTruth(
            name,
            time_s,
            np.array(POSITIONS[name]),
            np.zeros(3),
            quaternion_from_euler_zyx(*ATTITUDES[name]),
            np.zeros(3),
        )
        for name in BODY_NAMES
    }
    return PlantTruth(time_s, bodies)


def run(model: MocapModel, n_frames: int) -> list[MocapFrame]:
    """Capture ``n_frames`` frames of still bodies, one per slot, and deliver them all."""
    frames = []
    for k in range(n_frames):
        frame = model.capture(still_truth(k / model.params.rate_hz))
        assert frame is not None
        frames.append(frame)
    assert model.poll(math.inf) == frames
    return frames


def quaternion_error_rad(q_true: np.ndarray, q_meas: np.ndarray) -> np.ndarray:
    """The body-frame rotation vector δ with q_meas = q_true ⊗ exp(δ/2) (small angles)."""
    w, x, y, z = q_true
    conj = np.array([w, -x, -y, -z])
    a, b = conj, q_meas
    dq = np.array(
        [
            a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
            a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
            a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
            a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
        ]
    )
    if dq[0] < 0.0:
        dq = -dq
    result: np.ndarray = 2.0 * dq[1:]
    return result


def test_frames_are_captured_at_the_configured_rate() -> None:
    """Driven at the plant's 1 kHz, a 100 Hz model captures every 10th step; slots
    missed between calls are skipped, not made up."""
    model = MocapModel(MocapParams(rate_hz=100.0))
    captured = [
        frame.frame_number
        for k in range(1000)
        if (frame := model.capture(still_truth(k * 0.001))) is not None
    ]
    assert captured == list(range(100))
    assert model.next_capture_time_s == pytest.approx(1.0)
    frame = model.capture(still_truth(1.055))  # slots 100–104 were never sampled
    assert frame is not None and frame.frame_number == 105
    assert model.capture(still_truth(1.058)) is None


def test_latency_holds() -> None:
    model = MocapModel(MocapParams(latency_s=0.005, tracking=NO_LOSS))
    frame = model.capture(still_truth(0.25))
    assert frame is not None
    assert frame.capture_time_s == 0.25 and frame.delivery_time_s == pytest.approx(0.255)
    assert model.poll(0.2549) == []
    assert model.pending == 1
    assert model.poll(0.255) == [frame]
    assert model.poll(1.0) == []
    # sample(): capture at the truth's time, deliver what is due at now_s.
    assert model.sample(still_truth(0.26), now_s=0.26) == []
    delivered = model.sample(still_truth(0.265), now_s=0.265)
    assert [f.capture_time_s for f in delivered] == [0.26]


def test_noise_statistics_match_the_configured_sigma() -> None:
    sigma_p, sigma_q = 0.0005, math.radians(0.1)
    model = MocapModel(
        MocapParams(position_sigma_m=sigma_p, orientation_sigma_rad=sigma_q, tracking=NO_LOSS)
    )
    frames = run(model, 6000)
    for name in BODY_NAMES:
        truth = still_truth(0.0).bodies[name]
        poses = [frame.pose(name) for frame in frames]
        assert all(pose is not None for pose in poses)
        position_error = np.array([p.position_m for p in poses if p]) - truth.position_m
        angle_error = np.array(
            [quaternion_error_rad(truth.quaternion, p.quaternion) for p in poses if p]
        )
        n = len(position_error)
        # Per axis: the sample σ is within 4 standard errors (σ/√(2n) ≈ 0.9 %) of σ,
        # the mean within 4 σ/√n of zero.
        for errors, sigma in ((position_error, sigma_p), (angle_error, sigma_q)):
            np.testing.assert_allclose(errors.std(axis=0), sigma, rtol=4.0 / math.sqrt(2 * n))
            assert np.all(np.abs(errors.mean(axis=0)) < 4.0 * sigma / math.sqrt(n))
        for pose in poses:
            assert pose is not None
            assert np.linalg.norm(pose.quaternion) == pytest.approx(1.0, abs=1e-12)
            assert pose.quaternion[0] >= 0.0


def _lost(frames: list[MocapFrame], name: str) -> np.ndarray:
    return np.array([frame.pose(name) is None for frame in frames])


def test_single_dropouts_happen_at_the_configured_rate() -> None:
    p = 0.05
    tracking = TrackingParams(dropout_probability=p, burst_probability=0.0)
    frames = run(MocapModel(MocapParams(tracking=tracking, seed=11)), 10_000)
    for name in BODY_NAMES:
        lost = _lost(frames, name)
        assert lost.mean() == pytest.approx(p, abs=4.0 * math.sqrt(p * (1 - p) / len(lost)))


def test_dropout_bursts_have_their_length_and_rate() -> None:
    """Bursts only: every outage lasts at least the minimum burst, and the lost fraction
    is the renewal-process value of ``TrackingParams.lost_fraction``."""
    tracking = TrackingParams(dropout_probability=0.0, burst_probability=0.01, burst_frames=(5, 15))
    expected = tracking.lost_fraction
    assert expected == pytest.approx(10.0 / (99.0 + 10.0))
    frames = run(MocapModel(MocapParams(tracking=tracking, seed=4)), 10_000)
    fractions = []
    for name in BODY_NAMES:
        lost = _lost(frames, name).astype(int)
        edges = np.diff(np.concatenate(([0], lost, [0])))
        lengths = np.nonzero(edges == -1)[0] - np.nonzero(edges == 1)[0]
        assert len(lengths) > 50
        assert lengths.min() >= 5
        fractions.append(lost.mean())
    # ~270 bursts in all: their count and lengths make the fraction's σ ≈ 6 %.
    assert float(np.mean(fractions)) == pytest.approx(expected, rel=0.2)


def test_dropouts_per_body() -> None:
    params = MocapParams(
        tracking=NO_LOSS,
        tracking_overrides=(
            ("bar", TrackingParams(dropout_probability=0.2, burst_probability=0.0)),
        ),
    )
    frames = run(MocapModel(params), 2000)
    assert not _lost(frames, "uav1").any() and not _lost(frames, "uav2").any()
    assert _lost(frames, "bar").mean() == pytest.approx(0.2, abs=0.04)
    with pytest.raises(ValueError):
        MocapParams(tracking_overrides=(("nobody", NO_LOSS),))


def _signature(frames: list[MocapFrame]) -> list[tuple[float, ...] | None]:
    out: list[tuple[float, ...] | None] = []
    for frame in frames:
        for name in BODY_NAMES:
            pose = frame.pose(name)
            out.append(None if pose is None else (*pose.position_m, *pose.quaternion))
    return out


def test_deterministic_for_a_seed() -> None:
    tracking = TrackingParams(dropout_probability=0.05, burst_probability=0.01)
    first = _signature(run(MocapModel(MocapParams(tracking=tracking, seed=3)), 500))
    assert first == _signature(run(MocapModel(MocapParams(tracking=tracking, seed=3)), 500))
    assert first != _signature(run(MocapModel(MocapParams(tracking=tracking, seed=4)), 500))


def test_measures_the_plant() -> None:
    """Against the real plant hovering: every delivered pose is within 6σ of the truth
    at its capture time."""
    plant = Plant()
    plant.place_hanging((np.array([-0.9, 0.0, 1.8]), np.array([0.9, 0.0, 1.8])), (0.2, -0.1))
    model = MocapModel(MocapParams(tracking=NO_LOSS))
    truths = {}
    delivered: list[MocapFrame] = []
    for _ in range(50):
        plant.advance(0.01)
        truths[round(plant.time_s, 6)] = plant.truth()
        delivered += model.sample(plant.truth(), plant.time_s)
    assert len(delivered) == 49  # the last frame is still in flight
    for frame in delivered:
        truth = truths[round(frame.capture_time_s, 6)]
        for name in BODY_NAMES:
            pose = frame.pose(name)
            assert pose is not None
            true = truth.bodies[name]
            assert np.max(np.abs(pose.position_m - true.position_m)) < 6 * 0.0005
            error = quaternion_error_rad(true.quaternion, pose.quaternion)
            assert np.max(np.abs(error)) < 6 * math.radians(0.1)
