"""End to end, from a stable 1 m hover on the embedded simulator: ``serve``'s processes
dying or stopping (docs/safety.md, "Beyond the tick"). The world's own view of the flight
(sim/truth.py) is read from its log."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
from pathlib import Path

import pytest

from benchmarks.service import all_disarmed, in_mode, notices, position_m, running_service
from benchmarks.tick import world_truth
from supervisor.flight.modes import Mode
from supervisor.flight.phases import Phase
from supervisor.flight.status import Status
from tests.test_service import TOKEN, reached

pytestmark = pytest.mark.slow

API_BACK_S = 5.0


async def _cli(*arguments: str) -> tuple[int, str, str]:
    """``uavbar-supervisor ARGUMENTS`` as a user runs it: exit status, stdout, stderr."""
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "supervisor.cli.main",
        *arguments,
        env={**os.environ, "UAVBAR_TOKEN": TOKEN},
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.PIPE,
    )
    out, err = await process.communicate()
    assert process.returncode is not None
    return process.returncode, out.decode(), err.decode()


async def test_abort_reaches_the_flight_process_without_the_api_and_a_killed_api_comes_back(
    tmp_path: Path,
) -> None:
    """With the API process frozen, ``uavbar-supervisor abort`` goes straight to the flight
    process and the abort lands the system; the API process killed, ``serve`` starts it
    again within 5 s and it reports the restart."""
    async with running_service(TOKEN, tmp_path) as service:
        async with service.client() as http:
            await service.take_off(http)
            await asyncio.sleep(2.0)
            api = service.child_pid("uavbar-api")
            os.kill(api, signal.SIGSTOP)
            try:
                code, out, err = await _cli("abort", "--url", service.url, "--json")
            finally:
                os.kill(api, signal.SIGKILL)  # a stopped process dies of SIGKILL too
            killed = time.monotonic()
        assert code == 0, err
        assert "sent straight to the flight process" in err
        answer = json.loads(out)
        assert answer["direct"] and answer["mode"] == "abort"
        assert answer["took_s"] < 0.5, answer

        # The kept-alive connection was the killed process's: a request sent just after
        # the kill may die with it (the abort returns well within the keep-alive expiry).
        # New connections wait in serve's backlog for the new API process.
        async with service.client() as http:
            status = await service.wait_for(
                http, lambda s: s.processes["api"].restarts == 1, 30.0, "the API back"
            )
            back_s = time.monotonic() - killed
            assert back_s <= API_BACK_S, back_s
            assert status.processes["api"].pid == service.child_pid("uavbar-api") != api
            assert status.mode in (Mode.ABORT, Mode.DISARMING, Mode.DISARMED), status.mode
            await service.wait_for(http, in_mode(Mode.DISARMED), 60.0, "landed")
    assert any("the api process died (killed by SIGKILL)" in line for line in service.output)
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth


async def test_a_killed_flight_process_leaves_the_vehicles_to_px4_and_arming_waits_for_them(
    tmp_path: Path,
) -> None:
    """SIGKILL the flight process mid-hover: each PX4's offboard-loss failsafe lands its
    UAV; the API stays up, ``serve`` starts the flight process again, which says why, shows
    the vehicles as PX4's (``px4_landing``, never ``disarmed``) and refuses to arm until
    both are heard landed and disarmed; then arming is accepted again."""
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await service.take_off(http)
        # From 1.6 m rather than 1 m: PX4's landing lasts longer than a restart of the flight
        # process on a busy machine (8 s seen with the rest of the suite alongside).
        high = {"bar_position": [0.0, 0.0, 1.6]}
        assert (await http.post("/api/setpoints", json=high)).status_code == 200, high
        await service.wait_for(http, reached(high), 40.0, "the bar at 1.6 m")
        await asyncio.sleep(2.0)
        os.kill(service.child_pid("uavbar-flight"), signal.SIGKILL)

        def back_never_saying_ground(s: Status) -> bool:
            assert s.mode is not Mode.DISARMED and s.phase is not Phase.GROUND, (s.mode, s.armed)
            return (
                s.processes["flight"].restarts == 1
                and not s.stale
                and all(u.px4_mode != "unknown" for u in s.uavs)  # a heartbeat heard
            )

        status = await service.wait_for(
            http, back_never_saying_ground, 30.0, "the flight process back"
        )
        said = " ".join(notices(status))
        assert "the flight process died (killed by SIGKILL)" in said, said
        refusals = 0
        while status.mode is not Mode.DISARMED:
            # Never safer than the truth: PX4's, until both are heard disarmed.
            assert status.mode is Mode.PX4_LANDING and status.phase is Phase.PX4, status
            assert not status.streaming  # it flies nothing
            assert status.arm_blocked_by, status
            refused = await http.post("/api/arm")
            if refused.status_code == 200:
                break  # both heard disarmed between the status read and the request
            assert refused.status_code == 409, refused.text
            assert "wait until every PX4 has landed and disarmed" in refused.text, refused.text
            refusals += 1
            await asyncio.sleep(0.2)
            status = await service.status(http)
        else:
            assert all_disarmed(status), status
            assert all(u.connected for u in status.uavs), status.uavs
            assert (await http.post("/api/arm")).status_code == 200
        assert refusals > 0, "the vehicles had disarmed before the flight process was back"
        status = await service.status(http)
        assert all(position_m(u.position)[2] < 0.2 for u in status.uavs), status.uavs
        assert (await http.post("/api/disarm")).status_code == 200
    truth = world_truth(service.output)
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 1.0, truth
