"""An API served by uvicorn on loopback, over a real tick core behind the real channels
(the flight process's links and clock are left out: these tests are about the API)."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import math
import shutil
import socket
import ssl
import subprocess
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from api.app import create_app
from api.guard import HttpPolicy
from api.server import HttpServer, TlsFiles, bind
from supervisor.app.assembly import arena_from_config, flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.core import FlightCore
from supervisor.flight.operator_requests import Reply, Request, handle_request
from supervisor.flight.status import TickSummary
from supervisor.flight.telemetry import MocapView, ShellView, build_telemetry
from supervisor.ipc.channel import Channel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.messages import TelemetryMessage
from supervisor.ipc.server import serve_requests
from supervisor.vehicles.types import VehicleView
from tests.conftest import CONFIGS, resting_estimate

TOKEN = "test-token-123"


def ticks(count: int) -> TickSummary:
    """``count`` ticks run, none timed (the fixture publishes, it does not tick)."""
    return TickSummary(
        count=count,
        missed_deadlines=0,
        compute_ms_p50=None,
        compute_ms_p99=None,
        lateness_ms_p99=None,
        latency_ms_p50=None,
        latency_ms_p99=None,
    )


@dataclass
class ApiUnderTest:
    url: str
    core: FlightCore
    flight: FlightClient
    http: httpx.AsyncClient

    async def post(self, path: str, json: Any = None, token: str | None = TOKEN) -> httpx.Response:
        headers = {"Authorization": f"Bearer {token}"} if token is not None else {}
        return await self.http.post(path, json=json, headers=headers)


@contextlib.asynccontextmanager
async def serve_api(
    policy: HttpPolicy | None = None, tls: TlsFiles | None = None
) -> AsyncIterator[ApiUnderTest]:
    """The API behind ``policy`` (default: the token, loopback) on a free loopback port."""
    config = load_config(CONFIGS / "sim.toml")
    core = flight_core_from_config(config, clock=time.perf_counter)
    core.tick(0.0, resting_estimate(config.system.to_params()))  # ready to arm
    pairs = [socket.socketpair() for _ in range(2)]
    flight_side = [await Channel.open(b) for _, b in pairs]
    commands, urgent = [await Channel.open(a) for a, _ in pairs]
    flight = FlightClient(commands, urgent)

    async def handle(request: Request) -> Reply:
        return handle_request(core, request, time.monotonic())

    async def publish() -> None:
        vehicle = VehicleView(connected=True, armed=False, px4_mode="POSCTL")
        mocap = MocapView(connected=True, rate_hz=100.0, frames=0, dropped=0)
        shell = ShellView(streaming=False)
        for count in itertools.count(1):  # numbered, so that a skipped message shows
            message = build_telemetry(
                core, None, None, (vehicle, vehicle), mocap, ticks(count), shell, time.monotonic()
            )
            flight_side[0].send(TelemetryMessage(status=message))
            await asyncio.sleep(0.04)

    params, arena = config.system.to_params(), arena_from_config(config)
    # The client shares this event loop, so its own work would read as the server's load:
    # shedding is off unless a test asks for it (test_http_guard's, and benchmarks.api_load).
    unshed = HttpPolicy(TOKEN, shed_lag_s=math.inf)
    app = create_app(flight, params, arena, config.setpoint_bounds(), policy or unshed)
    server = HttpServer(app, bind("127.0.0.1", 0), tls)
    async with asyncio.TaskGroup() as group:
        tasks = [
            group.create_task(serve_requests(flight_side[0], handle)),
            group.create_task(serve_requests(flight_side[1], handle)),
            group.create_task(publish()),
            group.create_task(flight.run()),
            group.create_task(server.serve()),
        ]
        # The socket is already listening: requests queue until uvicorn accepts them.
        url = f"{server.scheme}://127.0.0.1:{server.port}"
        verify = ssl.create_default_context(cafile=tls.cert_file) if tls else True
        async with httpx.AsyncClient(base_url=url, timeout=5.0, verify=verify) as http:
            yield ApiUnderTest(url, core, flight, http)
        server.stop()
        for task in tasks[:-1]:
            task.cancel()
        for channel in flight_side:
            with contextlib.suppress(Exception):
                await channel.close()
        await flight.close()


@pytest.fixture
async def api() -> AsyncIterator[ApiUnderTest]:
    async with serve_api() as running:
        yield running


@pytest.fixture
def certificate(tmp_path: Path) -> TlsFiles:
    """A self-signed certificate for 127.0.0.1 and its key."""
    if shutil.which("openssl") is None:
        pytest.skip("needs the openssl command")
    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(
        [
            *("openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1"),
            *("-keyout", str(key), "-out", str(cert), "-subj", "/CN=127.0.0.1"),
            *("-addext", "subjectAltName=IP:127.0.0.1"),
        ],
        check=True,
        capture_output=True,
    )
    return TlsFiles(cert, key)
