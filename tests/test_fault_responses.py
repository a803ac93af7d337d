"""End to end, from a stable 1 m hover on the embedded simulator: what the supervisor does
about a fault injected into the world (docs/safety.md, the fault table). The world's own
view of the flight (sim/truth.py: worst tilt, fastest descent) is read from its log."""

from __future__ import annotations

import asyncio
import re
from pathlib import Path

import numpy as np
import pytest

from benchmarks.service import all_disarmed, in_mode, notices, running_service
from benchmarks.tick import world_truth
from geometry.state import payload_points
from supervisor.app.config import CONFIG_DIR, load_config
from supervisor.flight.modes import Mode
from supervisor.flight.phases import Phase
from supervisor.flight.safety import SafetyLimits
from supervisor.logs.flight_log import read_flight_log
from tests.test_faults_e2e import fault
from tests.test_px4_sitl import OFFBOARD_LOSS_TIMEOUT_S, freeze_flight_process
from tests.test_service import TOKEN, flight_logs, ready

pytestmark = pytest.mark.slow

TICK_MS = 20.0
AUTO_LAND = re.compile(r"PX4 (\d): mode AUTO\.LAND at ([\d.]+) s")


async def test_mocap_silent_briefly_is_flown_through_and_for_long_hands_over_to_px4(
    tmp_path: Path,
) -> None:
    """0.05 s of silence: nothing happens. 5 s: within one tick of the coast limit the
    supervisor stops streaming and each PX4 lands on its own (AUTO.LAND); both land and
    disarm, no UAV tilts beyond 30°, nothing descends faster than 1 m/s above 0.2 m."""
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await service.take_off(http)
        await asyncio.sleep(2.0)  # a stable hover
        await fault(http, kind="mocap_silent", duration_s=0.05)
        await asyncio.sleep(1.0)
        status = await service.status(http)
        assert status.mode is Mode.HOVER and status.streaming and not status.notices

        [silent] = (await fault(http, kind="mocap_silent", duration_s=5.0))["faults"]
        status = await service.wait_for(
            http, in_mode(Mode.PX4_LANDING), 5.0, "the hand-over to PX4"
        )
        assert not status.streaming
        assert "each PX4 lands on its own" in status.notices[-1].message
        await service.wait_for(
            http,
            lambda s: all(u.px4_mode == "AUTO.LAND" for u in s.uavs),
            2.0,
            "both PX4s landing",
        )
        # In world time, from the silence to each simulated PX4's AUTO.LAND (its own log).
        landing_s = {
            int(m[1]): float(m[2]) for line in service.output if (m := AUTO_LAND.search(line))
        }
        assert set(landing_s) == {1, 2}, landing_s
        limit_s = SafetyLimits().mocap_coast_s + 0.1
        assert max(landing_s.values()) - silent["started_s"] <= limit_s, (landing_s, silent)
        status = await service.wait_for(
            http, in_mode(Mode.DISARMED), 60.0, "landed and disarmed by PX4"
        )
        assert all_disarmed(status)
    [path] = flight_logs(tmp_path)
    log = read_flight_log(path)
    handed = log.modes.index("px4_landing")
    coast_ms = SafetyLimits().mocap_coast_s * 1e3
    # Blind for longer than the coast limit, by less than one tick.
    assert coast_ms < log.mocap_age_ms[handed] <= coast_ms + TICK_MS + 5.0
    assert np.all(np.asarray(log.mocap_age_ms[:handed]) <= coast_ms)
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth


@pytest.mark.parametrize("freeze_s", [0.3, 1.0, 5.0])  # issue 17's durations
async def test_a_frozen_flight_process_never_flips_a_uav_nor_commands_one_in_failsafe(
    tmp_path: Path, freeze_s: float
) -> None:
    """SIGSTOP the flight process mid-hover. Below PX4's offboard-loss timeout (0.5 s) the
    flight goes on; beyond it each PX4's failsafe lands, the supervisor resumes without a
    word to a vehicle in failsafe, hands over and follows the landing to the ground."""
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await service.take_off(http)
        await asyncio.sleep(2.0)
        status = await freeze_flight_process(service, http, freeze_s)
        if freeze_s >= OFFBOARD_LOSS_TIMEOUT_S:
            # Frozen as long as PX4's offboard-loss timeout: every PX4 is in its failsafe,
            # whatever it last reported, and is handed over before anything is sent.
            said = " ".join(notices(status))
            assert "beyond PX4's offboard-loss timeout (0.5 s)" in said, said
        status = await service.wait_for(http, in_mode(Mode.DISARMED), 60.0, "landed")
        await service.wait_for(http, all_disarmed, 10.0, "vehicles disarmed")
    assert not [line for line in service.output if "arrived in its failsafe" in line]
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth


async def test_arming_with_a_uav_a_metre_from_its_bar_end_is_refused_with_the_reason(
    tmp_path: Path,
) -> None:
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        await fault(http, kind="mocap_jump", body="uav1", offset_m=[1.0, 0.0, 0.0])
        await asyncio.sleep(0.5)
        refused = await http.post("/api/arm")
        assert refused.status_code == 409, refused.text
        assert re.search(r"cannot arm: UAV 1 stands 1\.\d\d m from its bar end", refused.text)
        await asyncio.sleep(1.5)  # a heartbeat later: no vehicle was armed meanwhile
        status = await service.status(http)
        assert status.mode is Mode.DISARMED and all_disarmed(status)
        assert (await http.delete("/api/sim/faults")).status_code == 200
        await asyncio.sleep(0.5)
        assert (await http.post("/api/arm")).status_code == 200
        assert (await http.post("/api/disarm")).status_code == 200


async def test_one_vehicle_lost_the_other_sets_the_bar_down_and_both_end_disarmed(
    tmp_path: Path,
) -> None:
    """Vehicle 1's link lost for good: it is left to its PX4's failsafe landing; UAV 2's
    own MPC sets its bar end down (phase ``set_down``), its cable taut all the way, and
    lands; nothing tilts beyond 30° or descends faster than 1 m/s. On the ground the mode
    stays ``disarming`` while vehicle 1 is not heard (arming says why); once the link is
    back both vehicles show themselves disarmed and so does the mode. (Cable 1 goes slack
    when its bar end touches the ground and UAV 1's PX4 lands on: that is the lost UAV's
    failsafe, not a fault.)"""
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await service.take_off(http)
        await asyncio.sleep(2.0)
        await fault(http, kind="link_lost", vehicle=1)
        status = await service.wait_for(
            http, lambda s: s.phase is Phase.SET_DOWN, 5.0, "UAV 2 setting the bar down"
        )
        assert status.mode is Mode.ABORT and status.controller == "decentralized"
        said = " ".join(notices(status))
        assert "vehicle 1 link lost: UAV 2 sets its bar end down alone" in said, said
        landed = await service.wait_for(
            http, in_mode(Mode.DISARMING), 60.0, "landed, vehicle 1 unheard"
        )
        assert "UAV 1 is not heard" in (landed.arm_blocked_by or ""), landed
        assert (await http.delete("/api/sim/faults")).status_code == 200
        await service.wait_for(
            http,
            lambda s: s.mode is Mode.DISARMED and all_disarmed(s),
            20.0,
            "both vehicles disarmed",
        )
    [path] = flight_logs(tmp_path)
    log = read_flight_log(path)
    start = log.modes.index("abort")
    end = log.plan_status.index("descend", start)
    params = load_config(CONFIG_DIR / "sim.toml").system.to_params()
    states = np.asarray(log.state)[start:end]
    attachments = params.payload.attachments_m
    slack_2 = [
        params.cable_lengths_m[1]
        - float(
            np.linalg.norm(params.layout.uav_position(x, 2) - payload_points(x, attachments)[1])
        )
        for x in states
    ]
    assert max(slack_2) < 0.02, max(slack_2)  # UAV 2's cable taut while it sets down
    assert payload_points(states[-1], attachments)[1][2] < 0.1  # and its end is down
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth  # UAV 1: its PX4's failsafe landing
    assert truth["max_descent_uav2_mps"] <= 0.5, truth  # what the supervisor flies
