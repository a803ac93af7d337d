"""The shipped recording (20 s of the simulator's stream during a hover, 0.3 s of it silent)
as a regression test: replayed over real sockets into the supervisor's client, the fusion's
estimate, tick by tick, and the safety monitors' responses are those of the recording's
packets fed directly, and the dropout fires what it fired live (``make_recording.py``)."""

from __future__ import annotations

import asyncio
import json
import math
import time
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mocap.client import QtmClient
from mocap.qtm_protocol import DataPacket, MocapFrame
from mocap.recording import Recording, read_recording
from sim.qtm_replay import QtmReplayServer
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
)
from supervisor.app.config import Config, load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.flight.estimation import Estimate, estimate_state
from supervisor.flight.modes import Mode
from supervisor.flight.safety import Response

DATA = Path(__file__).resolve().parents[1] / "data"
TICK_S = 0.02

pytestmark = pytest.mark.slow


def on_capture_clock(frames: Iterable[MocapFrame]) -> list[MocapFrame]:
    """Frames without their receive time: the fusion then times them by QTM's capture
    timestamps alone. The receive times are the one thing a replay cannot reproduce (they
    are the replaying machine's clock); every frame time the fusion uses is otherwise the
    capture time plus the smallest receive offset, a constant of the run."""
    return [replace(frame, receive_time_s=math.nan) for frame in frames]


def tick_by_tick(config: Config, frames: list[MocapFrame]) -> list[tuple[float, Estimate]]:
    """The estimate at every 20 ms tick from the first frame to the last, each tick fusing
    the frames captured up to it, as the flight process does."""
    fusion = fusion_from_config(config)
    names = body_names_from_config(config)
    first_s, last_s = frames[0].timestamp_us * 1e-6, frames[-1].timestamp_us * 1e-6
    estimates = []
    pending = iter(frames)
    frame: MocapFrame | None = next(pending)
    for k in range(int((last_s - first_s) / TICK_S) + 1):
        t_s = first_s + k * TICK_S
        while frame is not None and frame.timestamp_us * 1e-6 <= t_s:
            fusion.update(frame)
            frame = next(pending, None)
        estimates.append((t_s, estimate_state(fusion.states(t_s), names)))
    return estimates


def responses(config: Config, estimates: list[tuple[float, Estimate]]) -> list[list[str]]:
    """The safety monitors' faults at each tick, hovering ("monitor: response")."""
    safety = flight_core_from_config(config, clock=time.perf_counter).safety
    return [
        [
            f"{f.monitor}: {f.response.value}"
            for f in safety.check(t, e, Mode.HOVER, None, (True, True))
        ]
        for t, e in estimates
    ]


async def replayed(recording: Recording) -> list[MocapFrame]:
    async with (
        QtmReplayServer(recording, host="127.0.0.1", port=0) as server,
        # Room for every frame: this loop, starved for a second on a loaded machine, would
        # otherwise find only the newest 256 (the flight process's own bound).
        QtmClient("127.0.0.1", server.port, max_queue=sum(1 for _ in recording.frames())) as client,
    ):
        frames: list[MocapFrame] = []
        async with asyncio.timeout(recording.duration_s + 30.0):
            while not server.finished.is_set():
                await asyncio.sleep(0.1)
                frames += client.drain()
            await asyncio.sleep(0.2)  # the last datagrams on their way
        return frames + client.drain()


async def test_a_replay_gives_the_recordings_estimate_and_safety_response() -> None:
    recording = read_recording(DATA / "hover-dropout.qtm.gz")
    live = json.loads((DATA / "hover-dropout.live.json").read_text())
    config = load_config(DEFAULT_SETUP)
    direct = on_capture_clock(recording.frames())
    frames = on_capture_clock(await replayed(recording))
    assert [f.frame_number for f in frames] == [f.frame_number for f in direct]

    want, got = tick_by_tick(config, direct), tick_by_tick(config, frames)
    assert len(got) == len(want) > 900  # 20 s
    for (t_a, a), (t_b, b) in zip(got, want, strict=True):
        assert t_a == t_b
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
        assert a.age_s == pytest.approx(b.age_s, abs=1e-9)
        assert (a.unhealthy, a.refused) == (b.unhealthy, b.refused)

    fired, expected = responses(config, got), responses(config, want)
    assert fired == expected
    blind = [k for k, faults in enumerate(fired) if f"mocap: {Response.PX4_LAND.value}" in faults]
    assert blind, "the recorded dropout fired nothing"
    # What fired live: PX4's landing from the tick where the mocap was 0.1 s old. The live
    # time is on the recorder's clock (the flight process's, the same machine); the ticks
    # here are on QTM's capture clock, offset by the recording's smallest delay.
    offset_s = min(
        p.arrival_s - d.timestamp_us * 1e-6
        for p, d in recording.decoded()
        if isinstance(d, DataPacket)
    )
    first_blind_s = got[blind[0]][0] + offset_s
    assert abs(first_blind_s - live["px4_landing_t_s"]) <= 2 * TICK_S
    assert "stale or untracked" in live["notice"] and "each PX4 lands on its own" in live["notice"]
