"""End to end, from a stable 1 m hover on the embedded simulator: the mocap faults of issue 17
(a body lost, a frozen stream, a jump), each answered at its limit without a bad frame
reaching the MPC (docs/safety.md). Figures come from the flight log (each tick's mocap age)
and the status."""

from __future__ import annotations

import asyncio
import re
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks.service import all_disarmed, in_mode, running_service
from benchmarks.tick import world_truth
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
)
from supervisor.app.config import load_config
from supervisor.app.config_files import DEFAULT_SETUP
from supervisor.cli.output import format_status
from supervisor.flight.modes import Mode
from supervisor.flight.safety import Response, SafetyLimits
from supervisor.logs.flight_log import read_flight_log
from supervisor.logs.mocap_replay import check_flight, describe, flight_recording
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
            http, in_mode(Mode.PX4_LANDING), 5.0, "the hand-over to PX4"
        )
        assert not status.streaming
        message = status.notices[-1].message
        assert re.search(said, message) and "each PX4 lands on its own" in message, message
        refused = status.mocap.refused
        shown = format_status(status)  # what `uavbar-supervisor status` prints
        status = await service.wait_for(
            http, in_mode(Mode.DISARMED), 60.0, "landed and disarmed by PX4"
        )
        assert all_disarmed(status)
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
    for i in log.layout.vehicles:
        positions = log.layout.uav_position(log.state[hovering].T, i).T
        steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
        assert np.max(steps) < 0.02, (i, np.max(steps))
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert_the_flights_mocap_replays_as_flown(path)


def assert_the_flights_mocap_replays_as_flown(path: Path) -> None:
    """The mocap the flight process recorded during the flight, replayed on the flight's
    own clock (supervisor/logs/mocap_replay.py), gives the estimate the flight used at every
    tick, to 1e-9, and the safety monitors answer the replayed estimates as they answered
    live: the hand-over to PX4 at the same tick. ``uavbar-supervisor mocap check`` says so."""
    config = load_config(DEFAULT_SETUP)
    log = read_flight_log(path)
    estimates, comparison = check_flight(
        log, fusion_from_config(config), body_names_from_config(config), tolerance=1e-9
    )
    assert comparison.same, describe(path, comparison)
    assert flight_recording(log).duration_s > 10.0  # from the arm, through the take-off
    safety = flight_core_from_config(config, clock=time.perf_counter).safety
    handed_over = [
        k
        for k in range(1, len(estimates))
        if any(
            fault.response is Response.PX4_LAND
            for fault in safety.check(
                float(log.t_s[k]), estimates[k], Mode(log.modes[k - 1]), None, (True, True)
            )
        )
    ]
    assert handed_over and handed_over[0] == log.modes.index("px4_landing")
    said = subprocess.run(
        [sys.executable, "-m", "supervisor.cli.main", "mocap", "check", str(path)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert said.returncode == 0 and "the same as logged" in said.stdout, said
