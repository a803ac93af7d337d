"""End to end: ``uavbar-supervisor serve`` on the embedded simulator, over HTTP only."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from benchmarks.service import (
    RunningService,
    all_connected,
    all_disarmed,
    in_mode,
    notices,
    running_service,
)
from controllers.formation_params import FormationParams
from geometry.state import P_B, payload_points
from sim.px4_firmware import FirmwareError, resolve_px4_dir
from supervisor.app.config import CONFIG_DIR, load_config
from supervisor.flight.modes import Mode
from supervisor.flight.status import Status
from supervisor.logs.flight_log import FlightLog, read_flight_log

TOKEN = "e2e-token-0123456789"
SETPOINTS = [
    {"bar_position": [0.5, 0.3, 1.2], "bar_yaw": 0.4, "hold_s": 1.0},
    {"bar_position": [-0.3, 0.0, 1.0], "bar_yaw": -0.3, "uav_yaw": [0.0, -0.6], "hold_s": 1.0},
]
# From the last setpoint, 2.2 m through a bend at 1 m/s and 1 m/s² (issue 33).
PATH: dict[str, Any] = {
    "waypoints": [{"bar_position": [0.9, 0.0, 1.1]}, {"bar_position": [0.9, 1.0, 1.1]}],
    "speed_mps": 1.0,
    "accel_mps2": 1.0,
    "hold_s": 1.0,
}
PATH_END = {"bar_position": [0.9, 1.0, 1.1]}


def bar_error(status: Status, setpoint: dict[str, Any]) -> float:
    position = [v for v in status.bar.position if v is not None]
    if len(position) < 3:  # no estimate of it
        return math.inf
    return math.dist(position, setpoint["bar_position"])


def reached(setpoint: dict[str, Any]) -> Callable[[Status], bool]:
    return lambda status: bar_error(status, setpoint) < 0.05


def flight_logs(folder: Path) -> list[Path]:
    """The flight logs serve wrote (MCAP by default)."""
    return sorted(folder.glob("flight-*.mcap"))


async def ready(service: RunningService, http: httpx.AsyncClient) -> None:
    await service.wait_for(http, all_connected, 30.0, "healthy mocap and both links")


async def refused_without_token(service: RunningService) -> None:
    """Every mutating request without (or with a wrong) token: 401, nothing changes."""
    async with httpx.AsyncClient(base_url=service.url, timeout=10.0) as anonymous:
        before = (await anonymous.get("/api/status")).json()
        for path, body in [
            ("/api/arm", None),
            ("/api/land", None),
            ("/api/abort", None),
            ("/api/kill", {"confirm": True}),
            ("/api/mode", {"controller": "decentralized"}),
            ("/api/setpoints", {"bar_position": [0.0, 0.0, 1.0]}),
        ]:
            for headers in ({}, {"Authorization": "Bearer wrong"}):
                response = await anonymous.post(path, json=body, headers=headers)
                assert response.status_code == 401, path
        assert (await anonymous.delete("/api/setpoints")).status_code == 401
        after = (await anonymous.get("/api/status")).json()
    for key in ("mode", "controller", "armed", "setpoints"):
        assert after[key] == before[key], key


def require_px4() -> None:
    """Skip, saying why, when no PX4 SITL build can be found (sim/px4_firmware.py)."""
    try:
        resolve_px4_dir(None)
    except FirmwareError as missing:
        pytest.skip(f"real PX4 firmware not available: {missing}")


def slack_while_airborne(log: FlightLog, params: FormationParams) -> float:
    """The largest cable slack [m] the mocap saw while the bar was off the ground: cable
    length minus the UAV-to-bar-end distance."""
    worst = 0.0
    for x in log.state[np.asarray(log.state)[:, P_B][:, 2] > 0.1]:
        for i, end in enumerate(payload_points(x, params.payload.attachments_m), start=1):
            chord = float(np.linalg.norm(params.layout.uav_position(x, i) - end))
            worst = max(worst, params.cable_lengths_m[i - 1] - chord)
    return worst


@pytest.mark.slow
@pytest.mark.parametrize(
    "vehicles",
    ["simulated", pytest.param("px4_sitl", marks=[pytest.mark.px4, pytest.mark.px4_flight])],
)
async def test_a_whole_flight_over_http(tmp_path: Path, vehicles: str) -> None:
    """Arm, take off, fly two setpoints (the bar within 5 cm of each) and a path at 1 m/s
    to its end, switch to the decentralized MPC, land — on our simulated PX4s and on two
    real PX4 SITL instances."""
    if vehicles == "px4_sitl":
        require_px4()
    overrides = [f'sim.vehicles="{vehicles}"']
    async with (
        running_service(TOKEN, tmp_path, overrides) as service,
        service.client() as http,
    ):
        await ready(service, http)
        processes = (await service.status(http)).processes
        assert set(processes) == {"api", "flight", "world", "relay"}
        assert all(p.alive for p in processes.values())
        assert processes["flight"].pid == service.child_pid("uavbar-flight")
        assert processes["api"].pid == service.child_pid("uavbar-api")
        await refused_without_token(service)
        await service.take_off(http)
        response = await http.post("/api/setpoints", json=SETPOINTS)
        assert response.status_code == 200 and response.json()["queued"] == 2
        for index, setpoint in enumerate(SETPOINTS):
            await service.wait_for(http, reached(setpoint), 40.0, f"setpoint {index}")
        await service.wait_for(http, in_mode(Mode.HOVER), 40.0, "the queue to finish")
        queued = await http.post("/api/path", json=PATH)
        assert queued.status_code == 200 and queued.json()["duration_s"] > 2.2, queued.text
        begun = await service.wait_for(http, lambda s: s.path is not None, 10.0, "the path")
        assert begun.path is not None and begun.path.length_m > 2.2
        await service.wait_for(http, reached(PATH_END), 40.0, "the path's end")
        await service.wait_for(http, in_mode(Mode.HOVER), 40.0, "the path to be held")
        wait = "?wait_s=5"  # the REST answer comes once the controller flies
        switched = await http.post(f"/api/mode{wait}", json={"controller": "decentralized"})
        assert switched.status_code == 200 and switched.json()["mode"] == "hover"
        assert switched.json()["outcome"]["reached"], switched.text
        await asyncio.sleep(3.0)  # fly on the decentralized controller for a while
        status = await service.status(http)
        assert status.controller == "decentralized" and status.mode is Mode.HOVER
        # Still holding the bar near the setpoint: the decentralized agents, blind to the
        # bar's coupling, settle ~0.15 m off with unequal UAV yaws (the paper's Table III).
        assert bar_error(status, PATH_END) < 0.3
        await refused_without_token(service)
        landed = await http.post("/api/land?wait_s=90", timeout=100.0)
        assert landed.status_code == 200, landed.text  # answered once disarmed on the ground
        assert landed.json()["outcome"]["message"].startswith("landed and disarmed")
        status = await service.wait_for(http, lambda s: not s.log, 10.0, "the log closed")
        assert status.mode is Mode.DISARMED and all_disarmed(status)
        # Punctuality is the tick benchmark's figure (benchmarks.tick: 0 missed in its runs);
        # here a shared VM that loses its CPU for 50-110 ms at times may cost a deadline or
        # two, while a loop that keeps missing them (1 % of the ticks) fails.
        tick = status.tick
        assert tick.missed_deadlines <= 0.01 * tick.count, tick
        log_path = status.log or ""
    logs = flight_logs(tmp_path)
    assert len(logs) == 1 and not log_path  # the log closed with the flight
    log = read_flight_log(logs[0])
    assert {"takeoff", "hover", "tracking", "landing", "disarmed"} <= set(log.modes)
    assert set(log.controllers) == {"centralized", "decentralized"}
    # The thrust never jumps at the switch (bumpless transfer): compare tick to tick.
    switch = log.controllers.index("decentralized")
    jumps = np.abs(np.diff(log.inputs[switch - 5 : switch + 20, [0, 4]], axis=0))
    assert jumps.max() < 1.5
    assert slack_while_airborne(log, load_config(CONFIG_DIR / "sim.toml").system.to_params()) < 0.05


async def hovers_within_5_cm(service: RunningService, http: httpx.AsyncClient) -> None:
    """For 5 s the bar hovers within 5 cm of its reference."""
    errors = []
    for _ in range(50):
        status = await service.status(http)
        assert status.reference is not None, "hovering without a reference"
        errors.append(bar_error(status, {"bar_position": status.reference.bar_position}))
        await asyncio.sleep(0.1)
    assert status.mode is Mode.HOVER
    assert max(errors) < 0.05, max(errors)


@pytest.mark.slow
async def test_the_actuator_command_mode_hovers_within_5_cm(tmp_path: Path) -> None:
    """The simulated PX4s arm only on fresh external vision, so taking off at all shows the
    mocap is forwarded; then the bar hovers 5 s within 5 cm of its reference. (The rates
    mode, the default, in tests/test_lab_day.py.)"""
    overrides = ['vehicles.command_mode="actuator"', "sim.px4_require_vision=true"]
    async with (
        running_service(TOKEN, tmp_path, overrides) as service,
        service.client() as http,
    ):
        await service.take_off(http)
        await hovers_within_5_cm(service, http)


@pytest.mark.slow
async def test_a_vehicle_that_disarms_itself_before_take_off_disarms_the_system(
    tmp_path: Path,
) -> None:
    """PX4 disarms 10 s after an arm without take-off (COM_DISARM_PRFLT; our simulated PX4
    too): the supervisor follows, says why, and a take-off is refused."""
    async with running_service(TOKEN, tmp_path) as service, service.client() as http:
        await ready(service, http)
        assert (await http.post("/api/arm")).status_code == 200
        await asyncio.sleep(3.0)
        assert (await service.status(http)).mode is Mode.ARMED  # not before PX4 does
        status = await service.wait_for(http, in_mode(Mode.DISARMED), 20.0, "disarm")
        assert "disarmed by itself" in " ".join(notices(status))
        assert (await http.post("/api/takeoff")).status_code == 409
