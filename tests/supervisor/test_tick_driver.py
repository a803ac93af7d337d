"""The tick driver's part in the freeze rule (docs/safety.md): frames repeated bit for bit are
measurements on the ground — a resting system without noise may arm — and in flight a
frozen stream, handed to PX4 at the limit."""

from __future__ import annotations

import time

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from geometry import frames
from geometry.arrays import FloatArray
from geometry.state import TH_B, payload_position
from mocap.qtm_protocol import BodyPose, MocapFrame
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
)
from supervisor.app.config import load_config
from supervisor.flight.core import TickResult
from supervisor.flight.modes import Event, Mode
from supervisor.runtime.tick_driver import TickDriver
from tests.conftest import CONFIGS, resting_estimate

CONFIG = load_config(CONFIGS / "sim.toml")
PARAMS = CONFIG.system.to_params()
FRAME_S = 0.01


def poses_of(x: FloatArray) -> dict[str, BodyPose]:
    """Each body's pose in the state ``x``, as QTM would report it."""
    bar, uav1, uav2 = CONFIG.mocap.bodies
    pitch, yaw = x[TH_B][1:]
    poses = {bar: (payload_position(x), frames.quaternion_from_euler_zyx(0.0, pitch, yaw))}
    layout = PARAMS.layout
    for i, name in zip(layout.vehicles, (uav1, uav2), strict=True):
        poses[name] = (
            layout.uav_position(x, i),
            frames.quaternion_from_euler_zyx(*layout.uav_euler(x, i)),
        )
    return {name: BodyPose.from_quaternion(name, p, q) for name, (p, q) in poses.items()}


def frame(k: int, poses: dict[str, BodyPose]) -> MocapFrame:
    return MocapFrame(k, round(k * FRAME_S * 1e6), poses, k * FRAME_S + 0.005)


def driver() -> TickDriver:
    return TickDriver(
        flight_core_from_config(CONFIG, clock=time.thread_time),
        fusion_from_config(CONFIG),
        body_names_from_config(CONFIG),
    )


def fly(tick_driver: TickDriver, poses: dict[str, BodyPose], frames_k: range) -> list[TickResult]:
    """The same poses in every frame; a tick after every second frame."""
    results = []
    for k in frames_k:
        tick_driver.fusion.update(frame(k, poses))
        if k % 2:
            results.append(tick_driver.decide(k * FRAME_S + 0.006))
    return results


def test_a_resting_system_repeating_itself_exactly_may_arm() -> None:
    tick_driver = driver()
    fly(tick_driver, poses_of(resting_estimate(PARAMS).x), range(100))  # 1 s, no noise
    transition = tick_driver.core.request(Event.ARM, 1.0)
    assert transition.accepted, transition.reason
    assert tick_driver.fusion.repeated_frames == 0


def test_a_frozen_stream_in_flight_is_handed_to_px4_at_the_limit() -> None:
    tick_driver = driver()
    x = formation_equilibrium(PARAMS, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    poses = poses_of(x)
    tick_driver.fusion.update(frame(0, poses))
    tick_driver.core.start_in_hover(tick_driver.estimate_at(0.006), 0.0, (0.02, 0.07, 0.07))
    results = fly(tick_driver, poses, range(1, 30))  # frames 1… repeat frame 0
    modes = [r.mode for r in results]
    handed = results[modes.index(Mode.PX4_LANDING)]
    assert set(modes[: modes.index(Mode.PX4_LANDING)]) == {Mode.HOVER}
    limit = tick_driver.core.safety.limits.max_refused_poses
    # Frame 1 was taken too (repeats are refused from the first tick on): the run starts at
    # frame 2, and the tick after its 10th refused frame hands over.
    assert frame(limit + 1, poses).receive_time_s < handed.record.t_s <= (limit + 3) * FRAME_S
    assert 100.0 <= handed.record.mocap_age_ms <= 100.0 + 20.0
    [notice] = handed.notices
    assert "poses in a row refused (repeated bit for bit: a frozen stream)" in notice.text
    assert tick_driver.fusion.repeated_frames >= limit
