"""Fusion: motion recovered from poses, prediction to the tick, dropouts, yaw wrap, time."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest

from geometry import frames
from geometry.arrays import FloatArray
from mocap.fusion import CaptureClock, FusionConfig, MocapFusion, RigidBodyFilter
from mocap.qtm_protocol import (
    BodyPose,
    ComponentType,
    MocapFrame,
    frame_from_packet,
    packet_from_poses,
)

RATE_HZ = 100.0
P0 = np.array([1.0, -2.0, 1.5])
V = np.array([0.8, -0.3, 0.25])  # m/s, arena frame
Q0 = frames.quaternion_from_euler_zyx(0.2, -0.1, 2.9)  # yaw close to π on purpose
W = np.array([0.4, -0.3, 2.0])  # rad/s, FLU body frame


def truth(t: float) -> tuple[FloatArray, FloatArray]:
    """Constant velocity and constant body rate: q(t) = q0 ⊗ exp(ω t) is exact."""
    q = frames.quaternion_multiply(Q0, frames.quaternion_from_rotation_vector(W * t))
    return P0 + V * t, q


def pose_at(t: float, rng: np.random.Generator | None = None) -> BodyPose:
    position, q = truth(t)
    if rng is not None:
        position = position + rng.normal(0.0, 5e-4, 3)
        q = frames.quaternion_multiply(
            q, frames.quaternion_from_rotation_vector(rng.normal(0, 2e-3, 3))
        )
    return BodyPose.from_quaternion("uav1", position, q)


def attitude_error(q_a: FloatArray, q_b: FloatArray) -> float:
    relative = frames.quaternion_multiply(frames.quaternion_conjugate(q_a), q_b)
    return float(np.linalg.norm(frames.rotation_vector_from_quaternion(relative)))


def rms(errors: list[FloatArray]) -> float:
    return float(np.sqrt(np.mean(np.square(errors))))


def run(body: RigidBodyFilter, t_end: float, rng: np.random.Generator | None = None) -> float:
    t = 0.0
    for k in range(round(t_end * RATE_HZ) + 1):
        t = k / RATE_HZ
        body.update(pose_at(t, rng), t)
    return t


def test_noiseless_constant_velocity_and_rotation_are_recovered_exactly() -> None:
    body = RigidBodyFilter("uav1")
    t_last = run(body, 1.0)
    for dt in (0.0, 0.004, 0.013):  # tick times between and after samples
        state = body.state_at(t_last + dt)
        position, q = truth(t_last + dt)
        np.testing.assert_allclose(state.velocity_mps, V, atol=1e-9)
        np.testing.assert_allclose(state.body_rates_radps, W, atol=1e-9)
        np.testing.assert_allclose(state.position_m, position, atol=1e-9)
        assert attitude_error(state.quaternion, q) < 1e-9
        np.testing.assert_allclose(
            state.euler_zyx_rad, frames.euler_zyx_from_quaternion(q), atol=1e-9
        )
        np.testing.assert_allclose(
            state.angular_velocity_world_radps, frames.rotation_from_quaternion(q) @ W, atol=1e-9
        )
        assert state.tracked and state.healthy and state.age_s == pytest.approx(dt)
    assert body.updates == 101 and body.out_of_order == 0 and body.resets == 0


def test_convergence_is_fast_from_the_first_samples() -> None:
    body = RigidBodyFilter("uav1")
    run(body, 0.05)  # six samples
    state = body.state_at(0.05)
    np.testing.assert_allclose(state.velocity_mps, V, atol=1e-4)
    np.testing.assert_allclose(state.body_rates_radps, W, atol=1e-3)


def test_noisy_samples_give_sensible_estimates() -> None:
    rng = np.random.default_rng(12345)
    body = RigidBodyFilter("uav1")
    velocity_errors, rate_errors, position_errors = [], [], []
    for k in range(400):
        t = k / RATE_HZ
        body.update(pose_at(t, rng), t)
        if k >= 100:  # after the filter settled
            state = body.state_at(t)
            position, _ = truth(t)
            velocity_errors.append(state.velocity_mps - V)
            rate_errors.append(state.body_rates_radps - W)
            position_errors.append(state.position_m - position)
    # Raw finite differences of 0.5 mm / 2 mrad noise at 100 Hz would give 0.07 m/s / 0.28 rad/s.
    assert rms(velocity_errors) < 0.1
    assert rms(rate_errors) < 0.45
    assert rms(position_errors) < 5e-4  # better than the 0.5 mm measurement noise
    assert abs(float(np.mean(velocity_errors))) < 0.02  # unbiased


def test_yaw_wraps_without_a_jump_in_rates_or_euler() -> None:
    body = RigidBodyFilter("uav1")
    q_start = frames.quaternion_from_euler_zyx(0.0, 0.0, 3.0)
    yaw_rate = 3.0
    yaws, rates = [], []
    for k in range(500):  # 5 s at 3 rad/s: yaw goes from 3 to 18 rad, crossing ±π twice
        t = k / RATE_HZ
        q = frames.quaternion_multiply(
            q_start, frames.quaternion_from_rotation_vector(np.array([0.0, 0.0, yaw_rate * t]))
        )
        body.update(BodyPose.from_quaternion("b", np.zeros(3), q), t)
        state = body.state_at(t)
        if k >= 10:
            rates.append(state.body_rates_radps.copy())
            yaws.append(float(state.euler_zyx_rad[2]))
            expected = frames.wrap_angle(3.0 + yaw_rate * t)
            assert abs(frames.wrap_angle(yaws[-1] - expected)) < 1e-6
    np.testing.assert_allclose(
        np.array(rates), np.tile([0.0, 0.0, yaw_rate], (len(rates), 1)), atol=1e-6
    )
    assert all(-math.pi < y <= math.pi for y in yaws)
    assert sum(abs(b - a) > math.pi for a, b in itertools.pairwise(yaws)) >= 2  # wrapped


def test_prediction_to_the_tick_time_is_clamped() -> None:
    config = FusionConfig(max_prediction_s=0.05)
    body = RigidBodyFilter("uav1", config)
    t_last = run(body, 0.5)
    position_last, _ = truth(t_last)
    near = body.state_at(t_last + 0.02)
    np.testing.assert_allclose(near.position_m, position_last + 0.02 * V, atol=1e-9)
    far = body.state_at(t_last + 1.0)
    np.testing.assert_allclose(far.position_m, position_last + 0.05 * V, atol=1e-9)
    assert far.age_s == pytest.approx(1.0) and not far.healthy and far.tracked
    assert far.position_std_m > near.position_std_m > 0.0
    before = body.state_at(t_last - 0.01)  # a tick just before the newest sample
    np.testing.assert_allclose(before.position_m, truth(t_last - 0.01)[0], atol=1e-9)


def test_age_and_health_through_a_dropout() -> None:
    config = FusionConfig(max_age_s=0.05, reset_after_s=0.5)
    body = RigidBodyFilter("uav1", config)
    run(body, 0.3)
    assert body.state_at(0.3).healthy
    # QTM loses the body: untracked samples arrive, nothing is updated.
    for k in range(31, 41):
        body.update(BodyPose.untracked("uav1"), k / RATE_HZ)
    lost = body.state_at(0.40)
    assert not lost.tracked and not lost.healthy
    assert lost.age_s == pytest.approx(0.10)
    assert body.untracked_samples == 10
    # Frames stop altogether: the state only gets older.
    assert body.state_at(1.0).age_s == pytest.approx(0.7)
    # Back after a short dropout: healthy again, velocity still right.
    body.update(pose_at(0.42), 0.42)
    back = body.state_at(0.42)
    assert back.tracked and back.healthy and back.age_s == 0.0
    np.testing.assert_allclose(back.velocity_mps, V, atol=1e-6)
    assert body.resets == 0
    # Back after a long dropout: the filter restarts instead of trusting old velocity.
    body.update(pose_at(2.0), 2.0)
    assert body.resets == 1
    body.update(pose_at(2.01), 2.01)
    body.update(pose_at(2.02), 2.02)
    np.testing.assert_allclose(body.state_at(2.02).velocity_mps, V, atol=1e-3)


def test_out_of_order_and_duplicate_samples_are_ignored() -> None:
    body = RigidBodyFilter("uav1")
    t_last = run(body, 0.3)
    before = body.state_at(t_last)
    garbage = BodyPose.from_rotation("uav1", np.array([9.0, 9.0, 9.0]), np.eye(3))
    assert not body.update(garbage, t_last - 0.005)
    assert not body.update(garbage, t_last)  # same time again
    assert not body.update(garbage, math.nan)
    after = body.state_at(t_last)
    np.testing.assert_array_equal(after.position_m, before.position_m)
    np.testing.assert_array_equal(after.quaternion, before.quaternion)
    assert body.out_of_order == 3
    # An old *untracked* sample must not clear the tracked flag either.
    body.update(BodyPose.untracked("uav1"), t_last - 0.1)
    assert body.state_at(t_last).tracked


def test_never_measured_body_is_nan_and_unhealthy() -> None:
    body = RigidBodyFilter("bar")
    body.update(BodyPose.untracked("bar"), 0.0)
    state = body.state_at(1.0)
    assert not state.tracked and not state.healthy and state.age_s == math.inf
    assert np.isnan(state.position_m).all() and np.isnan(state.quaternion).all()
    assert not body.initialized


def test_capture_clock_removes_network_jitter() -> None:
    clock = CaptureClock()
    rng = np.random.default_rng(3)
    offset = 1000.0  # local clock − QTM clock
    for k in range(200):
        capture_s = k * 0.01
        latency = 0.002 + rng.exponential(0.003)
        mapped = clock.to_local(round(capture_s * 1e6), offset + capture_s + latency)
        if k > 50:
            # The mapping keeps only the smallest latency seen, not each datagram's jitter.
            assert mapped - (offset + capture_s) == pytest.approx(0.002, abs=1e-3)
    # A new measurement restarts QTM's clock: the offset is re-learned at once.
    mapped = clock.to_local(0, 5000.0)
    assert mapped == 5000.0
    assert clock.to_local(123, math.nan) == pytest.approx(123e-6)  # no receive time: as is


def test_mocap_fusion_feeds_frames_by_capture_or_receive_time() -> None:
    by_capture = MocapFusion(names=["uav1", "bar"])
    by_receive = MocapFusion(FusionConfig(time_source="receive"))
    for k in range(50):
        t = k / RATE_HZ
        jitter = 0.004 if k % 3 == 0 else 0.0  # network and scheduling delay
        frame = MocapFrame(
            k + 1,
            round(t * 1e6),
            {"uav1": pose_at(t), "bar": BodyPose.untracked("bar")},
            receive_time_s=100.0 + t + 0.001 + jitter,
        )
        by_capture.update(frame)
        by_receive.update(frame)
    t_tick = 100.0 + 0.49 + 0.001
    states = by_capture.states(t_tick)
    assert set(states) == {"uav1", "bar"}
    assert states["uav1"].healthy and not states["bar"].tracked
    # Capture timestamps make the jitter nearly irrelevant (only the clock-drift allowance
    # remains); receive times alone turn 4 ms of jitter into velocity error.
    capture_error = float(np.max(np.abs(states["uav1"].velocity_mps - V)))
    receive_error = float(np.max(np.abs(by_receive.state("uav1", t_tick).velocity_mps - V)))
    assert capture_error < 1e-3 < 2e-2 < receive_error
    assert by_capture.state("unknown", t_tick).age_s == math.inf
    assert by_receive.update(MocapFrame(99, 0, {}, receive_time_s=7.0)) == 7.0


def test_config_is_validated() -> None:
    with pytest.raises(ValueError, match="position_noise_m"):
        FusionConfig(position_noise_m=0.0)
    with pytest.raises(ValueError, match="max_prediction_s"):
        FusionConfig(max_prediction_s=-1.0)


# --- The innovation gate and repeated frames --------------------------------------------------


def hover_pose(t: float, rng: np.random.Generator, offset_m: float = 0.0) -> BodyPose:
    """A body hovering still, with the simulated mocap's noise (0.5 mm, 0.1°)."""
    position = np.array([0.5, 0.2, 1.0 + offset_m]) + rng.normal(0.0, 5e-4, 3)
    q = frames.quaternion_from_rotation_vector(rng.normal(0.0, math.radians(0.1), 3))
    return BodyPose.from_quaternion("uav1", position, q)


def test_a_jump_no_body_can_make_is_refused_counted_and_never_fused() -> None:
    rng = np.random.default_rng(3)
    body = RigidBodyFilter("uav1")
    for k in range(100):
        assert body.update(hover_pose(k / RATE_HZ, rng), k / RATE_HZ)
    before = body.state_at(0.99).position_m
    for k in range(100, 105):  # 1 m up, 5 frames
        assert not body.update(hover_pose(k / RATE_HZ, rng, offset_m=1.0), k / RATE_HZ)
    state = body.state_at(1.04)
    assert np.linalg.norm(state.position_m - before) < 0.01
    assert state.refused_in_a_row == 5 and "m from its prediction" in state.refusal
    assert body.refused == {"position": 5, "attitude": 0, "repeated": 0}
    assert not state.healthy  # refused poses are no measurements: the body ages
    assert body.update(hover_pose(1.05, rng), 1.05)  # back: fused, the run ends
    after = body.state_at(1.05)
    assert after.refused_in_a_row == 0 and after.refusal == "" and after.healthy
    assert body.resets == 0  # where the filter expected it: no restart


def test_a_turn_no_body_can_make_is_refused() -> None:
    rng = np.random.default_rng(4)
    body = RigidBodyFilter("uav1")
    for k in range(50):
        body.update(hover_pose(k / RATE_HZ, rng), k / RATE_HZ)
    still = hover_pose(0.5, rng)
    flipped = frames.quaternion_multiply(  # a quarter turn in yaw within one frame
        still.quaternion, frames.quaternion_from_rotation_vector(np.array([0.0, 0.0, math.pi / 2]))
    )
    assert not body.update(BodyPose.from_quaternion("uav1", still.position_m, flipped), 0.5)
    assert body.refused["attitude"] == 1 and "turned 90°" in body.last_refusal


def test_the_gate_takes_a_body_back_once_it_could_have_got_there() -> None:
    """A body really elsewhere after a while (a relabelled body, a long occlusion): the
    reachable distance grows as ½·a·h², so it is fused again after about √(2 m / a)."""
    rng = np.random.default_rng(5)
    config = FusionConfig()
    body = RigidBodyFilter("uav1", config)
    for k in range(100):
        body.update(hover_pose(k / RATE_HZ, rng), k / RATE_HZ)
    last = 0.99
    taken = next(
        k / RATE_HZ
        for k in range(100, 200)
        if body.update(hover_pose(k / RATE_HZ, rng, offset_m=1.0), k / RATE_HZ)
    )
    physical_s = math.sqrt(2.0 * 1.0 / config.gate_max_accel_mps2)
    assert physical_s - 0.05 < taken - last <= physical_s + 0.01
    assert body.state_at(taken).position_m[2] > 1.9  # the new pose, not a blend
    assert body.resets == 1  # restarted there: the old estimate says nothing of its velocity
    k0 = round(taken * RATE_HZ) + 1
    kept = [body.update(hover_pose(k / RATE_HZ, rng, 1.0), k / RATE_HZ) for k in range(k0, k0 + 50)]
    assert all(kept), body.last_refusal
    assert np.linalg.norm(body.state_at((k0 + 49) / RATE_HZ).velocity_mps) < 0.3  # noise


def test_the_gate_passes_what_a_body_can_do_with_the_simulated_noise() -> None:
    """20 m/s² of acceleration and 570°/s of yaw rate, with 0.5 mm and 0.1° of noise, for
    20 s at 100 Hz: not one pose refused."""
    rng = np.random.default_rng(6)
    body = RigidBodyFilter("uav1", FusionConfig(position_accel_psd=0.2, angular_accel_psd=2.0))
    amplitude_m, omega = 0.2, 10.0  # a = A ω² = 20 m/s²
    for k in range(2000):
        t = k / RATE_HZ
        position = np.array([amplitude_m * math.sin(omega * t), 0.0, 1.0]) + rng.normal(
            0.0, 5e-4, 3
        )
        q = frames.quaternion_multiply(
            frames.quaternion_from_euler_zyx(0.0, 0.0, 10.0 * t),
            frames.quaternion_from_rotation_vector(rng.normal(0.0, math.radians(0.1), 3)),
        )
        assert body.update(BodyPose.from_quaternion("uav1", position, q), t), (t, body.last_refusal)
    assert body.refused == {"position": 0, "attitude": 0, "repeated": 0}


def frame_of(k: int, poses: dict[str, BodyPose]) -> MocapFrame:
    return MocapFrame(k, round(k * 1e6 / RATE_HZ), poses, k / RATE_HZ + 0.005)


def test_frames_repeated_bit_for_bit_are_no_measurements_when_refused() -> None:
    rng = np.random.default_rng(7)
    fusion = MocapFusion(FusionConfig(time_source="receive"))
    poses = {"uav1": hover_pose(0.0, rng), "bar": hover_pose(0.0, rng)}
    fusion.update(frame_of(0, poses))
    fusion.update(frame_of(1, poses))  # on the ground a repeat is a measurement
    assert fusion.filters["uav1"].updates == 2 and fusion.repeated_frames == 0
    fusion.refuse_repeats = True
    for k in range(2, 12):
        fusion.update(frame_of(k, poses))
    assert fusion.repeated_frames == 10
    assert fusion.refused() == {"position": 0, "attitude": 0, "repeated": 20}
    state = fusion.state("uav1", 11 / RATE_HZ + 0.005)
    assert state.age_s == pytest.approx(0.1) and not state.healthy
    assert state.refused_in_a_row == 10 and "frozen" in state.refusal
    # One body moved: the frame is new, and every body in it is fused.
    fusion.update(frame_of(12, {"uav1": hover_pose(0.12, rng), "bar": poses["bar"]}))
    assert fusion.state("bar", 0.125).refused_in_a_row == 0


def test_noisy_frames_as_the_qtm_stream_carries_them_never_repeat() -> None:
    """Sub-millimetre noise through QTM's float32 millimetres: a resting body's poses still
    differ in every frame, so refusing repeats never refuses a live stream."""
    rng = np.random.default_rng(8)
    fusion = MocapFusion()
    fusion.refuse_repeats = True
    for k in range(1000):
        packet = packet_from_poses(
            k + 1, k * 10_000, ("uav1",), {"uav1": hover_pose(0.0, rng)}, [ComponentType.SIX_D]
        )
        fusion.update(frame_from_packet(packet, ("uav1",), k / RATE_HZ))
    assert fusion.repeated_frames == 0 and fusion.filters["uav1"].updates == 1000


# --- Snapshots: a flight's fusion continued from where its mocap recording starts ------------


def eventful_frames(rng: np.random.Generator) -> list[MocapFrame]:
    """Two bodies, one never tracked at first, with jitter, a jump the gate refuses,
    repeats and a dropout: every kind of state the fusion keeps."""
    frames_: list[MocapFrame] = []
    for k in range(300):
        t = k / RATE_HZ
        uav = pose_at(t, rng)
        if 100 <= k < 104:
            uav = BodyPose.from_quaternion("uav1", uav.position_m + 1.0, uav.quaternion)
        bar = hover_pose(t, rng) if k >= 20 and not 150 <= k < 180 else BodyPose.untracked("bar")
        if 200 <= k < 205 and frames_:
            uav, bar = frames_[-1].bodies["uav1"], frames_[-1].bodies["bar"]
        jitter = rng.exponential(0.002)
        frames_.append(
            MocapFrame(k + 1, round(t * 1e6), {"uav1": uav, "bar": bar}, 50.0 + t + jitter)
        )
    return frames_


@pytest.mark.parametrize("cut", [0, 10, 102, 160, 202, 299])
def test_a_fusion_restored_from_a_snapshot_continues_bit_for_bit(cut: int) -> None:
    frames_ = eventful_frames(np.random.default_rng(11))
    config = FusionConfig()
    live = MocapFusion(config, names=["uav1", "bar"])
    live.refuse_repeats = True
    for frame in frames_[:cut]:
        live.update(frame)
    snapshot = json.loads(json.dumps(live.snapshot()))  # as a flight log's header keeps it
    replayed = MocapFusion(config, names=["uav1", "bar"])
    replayed.restore(snapshot)
    for frame in frames_[cut:]:
        live.update(frame)
        replayed.update(frame)
        t = frame.receive_time_s + 0.003
        for name in ("uav1", "bar"):
            a, b = live.state(name, t), replayed.state(name, t)
            np.testing.assert_array_equal(a.position_m, b.position_m)
            np.testing.assert_array_equal(a.velocity_mps, b.velocity_mps)
            np.testing.assert_array_equal(a.quaternion, b.quaternion)
            np.testing.assert_array_equal(a.body_rates_radps, b.body_rates_radps)
            assert (a.age_s, a.healthy, a.refused_in_a_row) == (
                b.age_s,
                b.healthy,
                b.refused_in_a_row,
            )
    assert replayed.refused() == live.refused() and replayed.repeated_frames == live.repeated_frames
    assert live.refused()["position"] > 0 and live.repeated_frames > 0  # the events happened


def test_a_snapshot_taken_of_another_fusion_changes_what_follows() -> None:
    """The comparison above can fail: restored from a snapshot taken earlier than the cut,
    the estimates differ."""
    frames_ = eventful_frames(np.random.default_rng(11))
    live, replayed = MocapFusion(), MocapFusion()
    for frame in frames_[:50]:
        live.update(frame)
    early = live.snapshot()
    for frame in frames_[50:60]:
        live.update(frame)
    replayed.restore(early)
    for frame in frames_[60:80]:
        live.update(frame)
        replayed.update(frame)
    t = frames_[79].receive_time_s
    assert not np.array_equal(
        live.state("uav1", t).velocity_mps, replayed.state("uav1", t).velocity_mps
    )
