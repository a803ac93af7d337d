"""End to end, from a stable 1 m hover on the embedded simulator: the mocap faults of issue 17
(a body lost, a frozen stream, a jump), each answered at its limit without a bad frame
reaching the MPC (docs/safety.md). Figures come from the flight log (each tick's mocap age)
and the status."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.service import running_service
from benchmarks.tick import world_truth
from geometry.state import uav_position
from supervisor.cli.output import format_status
from supervisor.flight.safety import SafetyLimits
from supervisor.logs.flight_log import read_flight_log
from tests.test_fault_responses import TICK_MS
from tests.test_faults_e2e import fault
from tests.test_service import TOKEN, flight_logs

pytestmark = pytest.mark.slow

CASES: dict[str, tuple[dict[str, Any], str]] = {  # the fault's fields, what the notice says
    "mocap_body_lost": ({"body": "bar"}, r"bar stale or untracked \(1\d\d ms\)"),
    "mocap_freeze": ({}, r"\d+ poses in a row refused \(repeated bit for bit: a frozen stream\)"),
    "mocap_jump": (
        {"body": "uav1", "offset_m": [1.0, 0.0, 0.0]},
        r"uav1: \d+ poses in a row refused \((0\.9|1\.0)\d\d m from its prediction",
    ),
}


@pytest.mark.parametrize("kind", list(CASES))
async def test_a_lost_frozen_or_jumping_mocap_hands_over_to_px4_at_its_limit(
    tmp_path: Path, kind: str
) -> None:
    """1 s of the fault mid-hover: nothing bad is fused, the body ages, and within one tick
    of the coast limit (0.1 s, or as many refused poses in a row at 100 Hz) the supervisor
    stops streaming and each PX4 lands on its own; the notice says why, the status counts
    what was refused."""
    fields, said = CASES[kind]
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await service.take_off(http)
        await asyncio.sleep(2.0)  # a stable hover
        await fault(http, kind=kind, duration_s=1.0, **fields)
        status = await service.wait_for(
            http, lambda s: s["mode"] == "px4_landing", 5.0, "the hand-over to PX4"
        )
        assert not status["streaming"]
        message = status["notices"][-1]["message"]
        assert re.search(said, message) and "each PX4 lands on its own" in message, message
        refused: dict[str, Any] = status["mocap"]["refused"]
        shown = format_status(status)  # what `uavbar-supervisor status` prints
        status = await service.wait_for(
            http, lambda s: s["mode"] == "disarmed", 60.0, "landed and disarmed by PX4"
        )
        assert status["armed"] == [False, False]
    if kind == "mocap_freeze":
        assert refused["repeated"] >= 3 * SafetyLimits().max_refused_poses, refused
        assert "refused:" in shown and f"repeated {refused['repeated']}" in shown, shown
    if kind == "mocap_jump":
        assert refused["position"] >= SafetyLimits().max_refused_poses, refused
        assert "refused:" in shown and f"position {refused['position']}" in shown, shown
    [path] = flight_logs(tmp_path)
    log = read_flight_log(path)
    handed = log.modes.index("px4_landing")
    coast_ms = SafetyLimits().mocap_coast_s * 1e3
    age_ms = log.mocap_age_ms[handed]
    # Within a tick of the limit, as the issue asks: a frozen stream is handed over on its
    # 10th repeated frame, which a stall of this computer can bring a few ms early (96 ms).
    assert coast_ms - TICK_MS < age_ms <= coast_ms + TICK_MS + 5.0
    assert np.all(np.asarray(log.mocap_age_ms[:handed]) <= coast_ms)
    # No refused pose reached the estimate the MPC flew on: from the hover to the hand-over,
    # no tick-to-tick step of a UAV beyond what 20 ms of hovering allow (a jump is 1 m).
    hovering = [k for k in range(handed + 1) if log.modes[k] == "hover" or k == handed]
    for i in (1, 2):
        positions = uav_position(log.state[hovering].T, i).T
        steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        assert np.max(steps) < 0.02, (i, np.max(steps))
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
