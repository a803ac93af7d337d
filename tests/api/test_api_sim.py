"""``/api/sim/*`` and the ``fault``/``reset`` commands over HTTP on loopback: against a
simulated world running in this process behind the real world channel, and against an API
without a world (``sim.embedded`` false)."""

from __future__ import annotations

import asyncio
import json
import re
import socket
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from typing import Any

import httpx
import numpy as np
import pytest

from api.app import create_app
from api.guard import HttpPolicy
from api.server import HttpServer, bind
from sim.plant import body_slice
from sim.px4 import BOOT_MODE, FORCE_MAGIC
from sim.px4_endpoint import Px4Endpoint
from sim.world import SimulatedWorld
from supervisor.app.assembly import arena_from_config
from supervisor.app.config import load_config
from supervisor.app.world_process import build_world, handle_world_request
from supervisor.cli.main import main
from supervisor.cli.output import format_status
from supervisor.ipc.channel import Channel, WorldChannel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.world_client import WorldClient, serve_world_requests
from tests.api.conftest import TOKEN, ApiUnderTest
from tests.conftest import CONFIGS
from tests.status_examples import a_status

AUTH = {"Authorization": f"Bearer {TOKEN}"}
MUTATING = [
    ("POST", "/api/sim/faults", {"kind": "mocap_silent"}),
    ("DELETE", "/api/sim/faults", None),
    ("POST", "/api/sim/reset", None),
]


@dataclass
class SimApi:
    url: str
    world: SimulatedWorld
    http: httpx.AsyncClient
    client: WorldClient

    async def fault(self, body: Any, token: str | None = TOKEN) -> httpx.Response:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return await self.http.post("/api/sim/faults", json=body, headers=headers)

    def px4(self, uav: int) -> Px4Endpoint:
        vehicle = self.world.vehicles[uav - 1]
        assert isinstance(vehicle, Px4Endpoint)
        return vehicle


@pytest.fixture
async def sim_api() -> AsyncIterator[SimApi]:
    """The API with a world behind the world channel (the flight channels lead nowhere:
    these routes never use them)."""
    config = load_config(CONFIGS / "sim.toml", ["sim.mocap.dropout_probability=0.0"])
    world = build_world(config, qtm_port=0, vehicle_local_ports=(0, 0))
    await world.start()
    api_end, world_end = socket.socketpair()
    world_channel = await WorldChannel.open(world_end)
    client = WorldClient(await WorldChannel.open(api_end))
    pairs = [socket.socketpair() for _ in range(2)]
    commands, urgent = [await Channel.open(a) for a, _ in pairs]
    flight = FlightClient(commands, urgent)
    app = create_app(
        flight,
        config.system.to_params(),
        arena_from_config(config),
        config.setpoint_bounds(),
        HttpPolicy(TOKEN),
        client,
    )
    server = HttpServer(app, bind("127.0.0.1", 0))
    async with asyncio.TaskGroup() as group:
        tasks = [
            group.create_task(world.run()),
            group.create_task(
                serve_world_requests(world_channel, lambda r: handle_world_request(world, r))
            ),
            group.create_task(client.run()),
            group.create_task(server.serve()),
        ]
        url = f"http://127.0.0.1:{server.port}"
        # Generous: on a busy machine the world's first steps share this event loop.
        async with httpx.AsyncClient(base_url=url, timeout=30.0) as http:
            yield SimApi(url, world, http, client)
        server.stop()
        for task in tasks[:-1]:
            task.cancel()
    await world_channel.close()
    await client.close()
    await flight.close()
    await world.close()
    for a, b in pairs:
        a.close()
        b.close()


# ---- the routes ---------------------------------------------------------------------------
@pytest.mark.parametrize("token", [None, "wrong-token"])
@pytest.mark.parametrize(("method", "path", "body"), MUTATING)
async def test_sim_routes_need_the_token(
    sim_api: SimApi, method: str, path: str, body: Any, token: str | None
) -> None:
    headers = {"Authorization": f"Bearer {token}"} if token else {}
    response = await sim_api.http.request(method, path, json=body, headers=headers)
    assert response.status_code == 401
    assert sim_api.world.fault_views() == []


async def test_a_fault_is_applied_listed_and_ends_on_the_worlds_clock(sim_api: SimApi) -> None:
    response = await sim_api.fault(
        {"kind": "mocap_jump", "body": "bar", "offset_m": [0, 0, 0.2], "duration_s": 0.6}
    )
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["accepted"] and answer["embedded"]
    assert answer["fault"]["kind"] == "mocap_jump"
    assert answer["fault"]["params"] == {"body": "bar", "offset_m": [0.0, 0.0, 0.2]}
    assert 0.0 < answer["fault"]["remaining_s"] <= 0.6
    [listed] = answer["faults"]
    assert set(listed) == {"kind", "params", "duration_s", "started_s", "remaining_s"}
    assert listed["started_s"] == pytest.approx(answer["world_time_s"], abs=0.05)
    open_list = (await sim_api.http.get("/api/sim/faults")).json()  # no token needed
    assert open_list["embedded"] and [f["kind"] for f in open_list["faults"]] == ["mocap_jump"]
    await asyncio.sleep(1.0)
    assert (await sim_api.http.get("/api/sim/faults")).json()["faults"] == []


async def test_a_push_through_the_api_lifts_the_bar_on_the_worlds_plant(
    sim_api: SimApi, capsys: pytest.CaptureFixture[str]
) -> None:
    """The bar resting on the ground, its weight and 2 m/s² more pushed up at its centre for
    0.5 s (the cables stay slack): it rises ½ a T² = 0.25 m, coasts up v²/2g = 0.05 m more
    and falls back; once the push has expired the plant carries no load."""
    world = sim_api.world
    mass = world.plant.params.bar.mass_kg
    lift = mass * (world.plant.params.gravity_mps2 + 2.0)
    rest_z = float(world.plant.body("bar").position_m[2])
    push = {"kind": "push", "body": "bar", "force_n": [0, 0, lift], "duration_s": 0.5}
    response = await sim_api.fault(push)
    assert response.status_code == 200, response.text
    assert response.json()["fault"]["params"] == {"body": "bar", "force_n": [0.0, 0.0, lift]}
    [load] = world.plant.loads
    assert (load.body, load.force_n, load.duration_s) == ("bar", (0.0, 0.0, lift), 0.5)
    apex = rest_z
    for _ in range(200):  # 1 s
        await asyncio.sleep(0.005)
        apex = max(apex, float(world.plant.body("bar").position_m[2]))
    assert apex - rest_z == pytest.approx(0.30, abs=0.03)
    assert world.plant.loads == () and world.fault_views() == []
    assert float(world.plant.body("bar").position_m[2]) < rest_z + 0.05  # back down
    # The command line takes the same kind; the API refuses more than 50 N along an axis.
    force = ["--force-n", "0", "1", "0"]
    assert await cli(sim_api.url, "fault", "push", "--body", "uav2", *force) == 0
    assert "in effect: push body uav2 force_n [0.0, 1.0, 0.0]" in capsys.readouterr().out
    [load] = list(world.plant.loads)
    assert (load.body, load.force_n, load.duration_s) == ("uav2", (0, 1, 0), None)
    assert await cli(sim_api.url, "fault", "--clear") == 0
    assert world.plant.loads == ()
    too_hard = {"kind": "push", "body": "bar", "force_n": [0, 0, 60]}
    response = await sim_api.fault(too_hard)
    assert response.status_code == 422 and "force_n" in response.text
    assert world.plant.loads == ()


async def test_delete_ends_every_fault(sim_api: SimApi) -> None:
    for body in ({"kind": "mocap_freeze"}, {"kind": "link_lost", "vehicle": 2}):
        assert (await sim_api.fault(body)).status_code == 200
    link = sim_api.px4(2).datagram_filter
    assert link is not None and not link(True)
    response = await sim_api.http.delete("/api/sim/faults", headers=AUTH)
    assert response.status_code == 200
    assert [f["kind"] for f in response.json()["cleared"]] == ["mocap_freeze", "link_lost"]
    assert response.json()["faults"] == [] and sim_api.world.fault_views() == []


@pytest.mark.parametrize(
    ("body", "reason"),
    [
        ({"kind": "meteor"}, "kind"),
        ({"duration_s": 1}, "kind"),
        ({"kind": "mocap_silent", "vehicle": 1}, "vehicle"),
        ({"kind": "mocap_body_lost"}, "body"),
        ({"kind": "mocap_jump", "body": "bar", "offset_m": [1, 2]}, "offset_m"),
        ({"kind": "link_lost", "vehicle": 9}, "vehicle"),
        ({"kind": "px4_reboot", "vehicle": "1"}, "vehicle"),
        ({"kind": "udp_loss", "fraction": 1.5}, "fraction"),
        ({"kind": "udp_loss", "fraction": 0.1, "duration_s": -1}, "duration_s"),
        ({"kind": "udp_loss", "fraction": 0.1, "duration_s": 0}, "duration_s"),
    ],
)
async def test_an_invalid_fault_is_422_naming_the_field_and_nothing_is_applied(
    sim_api: SimApi, body: Any, reason: str
) -> None:
    response = await sim_api.fault(body)
    assert response.status_code == 422
    assert reason in json.dumps(response.json())
    assert sim_api.world.fault_views() == []


async def test_a_body_the_world_does_not_have_is_409_and_nothing_is_applied(
    sim_api: SimApi,
) -> None:
    response = await sim_api.fault({"kind": "mocap_body_lost", "body": "ghost"})
    assert response.status_code == 409
    assert "body: 'ghost' is not a configured" in response.json()["detail"]
    assert sim_api.world.fault_views() == []


async def test_a_vehicle_the_world_does_not_have_is_409_and_nothing_is_applied(
    sim_api: SimApi,
) -> None:
    """Vehicle 3 fits the schema (1 to 8); this world has two."""
    response = await sim_api.fault({"kind": "link_lost", "vehicle": 3})
    assert response.status_code == 409
    assert "vehicle: 3 is not a vehicle of this world" in response.json()["detail"]
    assert sim_api.world.fault_views() == []


async def test_nan_is_refused(sim_api: SimApi) -> None:
    for content in (
        '{"kind": "udp_loss", "fraction": NaN}',
        '{"kind": "mocap_silent", "duration_s": NaN}',
        '{"kind": "mocap_jump", "body": "bar", "offset_m": [0, NaN, 0]}',
    ):
        response = await sim_api.http.post(
            "/api/sim/faults",
            content=content,
            headers={**AUTH, "Content-Type": "application/json"},
        )
        assert response.status_code == 422, content
    assert sim_api.world.fault_views() == []


async def test_reset_is_refused_while_armed_then_puts_the_world_back(sim_api: SimApi) -> None:
    world = sim_api.world
    resting = world.plant.get_state()
    px4 = sim_api.px4(1)
    px4.model.command(400, (1.0, FORCE_MAGIC, 0, 0, 0, 0, 0), px4.clock_s(), px4.airframe.state())
    assert (await sim_api.fault({"kind": "mocap_freeze"})).status_code == 200
    refused = await sim_api.http.post("/api/sim/reset", headers=AUTH)
    assert refused.status_code == 409
    assert refused.json() == {"accepted": False, "detail": refused.json()["detail"]}
    assert "vehicle 1 is armed" in refused.json()["detail"]
    assert len(world.fault_views()) == 1  # nothing happened
    px4.model.command(400, (0.0, FORCE_MAGIC, 0, 0, 0, 0, 0), px4.clock_s(), px4.airframe.state())
    world.plant.set_body("uav2", position_m=np.array([1.5, 1.0, 0.2]))
    response = await sim_api.http.post("/api/sim/reset", headers=AUTH)
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["reset"] and answer["faults"] == [] and len(answer["cleared"]) == 1
    # No flight process behind this API: the reply came after the wait, not tracked.
    assert answer["tracked"] is False and answer["arm_blocked_by"] == "no telemetry"
    assert "resting_positions" not in answer
    position = world.plant.body("uav2").position_m
    np.testing.assert_allclose(position, resting[body_slice("uav2")][:3], atol=0.02)
    assert px4.model.intended == BOOT_MODE and not px4.armed


async def test_the_worlds_stalls_and_faults_are_watched_for_the_status(sim_api: SimApi) -> None:
    """What ``GET /api/status`` shows as ``world`` and ``status`` prints: a stall of the
    world's own process (here, this event loop blocked) and the faults in effect."""
    watch = asyncio.create_task(sim_api.client.keep_watch(period_s=0.05))
    assert (await sim_api.fault({"kind": "mocap_freeze", "duration_s": 60.0})).status_code == 200
    time.sleep(0.15)  # noqa: ASYNC251 -- on purpose: the world, in this event loop, stalls
    for _ in range(200):  # until a view from after the stall (a busy machine has others)
        await asyncio.sleep(0.05)
        view = sim_api.client.view()
        if view.stalls is not None and view.stalls.worst_ms >= 100.0 and view.faults:
            break
    watch.cancel()
    assert view.embedded and view.reachable and view.stalls is not None
    assert view.stalls.count >= 1 and view.stalls.worst_ms >= 100.0, view
    assert [fault.kind for fault in view.faults] == ["mocap_freeze"]
    shown = format_status(a_status(mode="hover", world=view.model_dump()))
    assert "simulated world: mocap_freeze (" in shown
    assert re.search(r"stalled \d+ times by this computer \(worst \d+ ms", shown), shown


async def test_the_routes_are_in_the_openapi_schema(sim_api: SimApi) -> None:
    schema = (await sim_api.http.get("/openapi.json")).json()
    assert {"/api/sim/faults", "/api/sim/reset"} <= set(schema["paths"])


# ---- not embedded: no world behind the API ------------------------------------------------------
async def test_without_an_embedded_world_get_says_so(api: ApiUnderTest) -> None:
    response = await api.http.get("/api/sim/faults")
    assert response.status_code == 200
    assert response.json() == {"embedded": False, "faults": []}


@pytest.mark.parametrize(
    ("method", "path", "body"),
    [*MUTATING, ("POST", "/api/sim/faults", {"kind": "meteor"})],
)
async def test_without_an_embedded_world_mutations_are_409_after_the_token(
    api: ApiUnderTest, method: str, path: str, body: Any
) -> None:
    assert (await api.http.request(method, path, json=body)).status_code == 401
    response = await api.http.request(method, path, json=body, headers=AUTH)
    assert response.status_code == 409
    assert "not embedded" in response.json()["detail"]


# ---- the terminal client ---------------------------------------------------------------------
async def cli(url: str, *args: str) -> int:
    return await asyncio.to_thread(main, [*args, "--url", url, "--token", TOKEN])


async def test_fault_and_reset_commands(
    sim_api: SimApi, capsys: pytest.CaptureFixture[str]
) -> None:
    url = sim_api.url
    assert await cli(url, "fault", "mocap_body_lost", "--body", "uav1", "--duration", "30") == 0
    assert "in effect: mocap_body_lost body uav1 (" in capsys.readouterr().out
    offset = ["--offset-m", "0", "0", "0.1"]
    assert await cli(url, "fault", "mocap_jump", "--body", "bar", *offset) == 0
    assert await cli(url, "fault", "--json") == 0
    listed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert [f["kind"] for f in listed["faults"]] == ["mocap_body_lost", "mocap_jump"]
    assert listed["faults"][1]["remaining_s"] is None
    assert await cli(url, "fault", "--clear") == 0
    out = capsys.readouterr().out
    assert "ended: mocap_jump body bar offset_m [0.0, 0.0, 0.1] (until cleared)" in out
    assert "no fault in effect" in out
    assert await cli(url, "reset") == 0
    assert "world reset" in capsys.readouterr().out


async def test_fault_refusals_exit_1_with_the_reason(
    sim_api: SimApi, capsys: pytest.CaptureFixture[str]
) -> None:
    url = sim_api.url
    assert await cli(url, "fault", "link_lost", "--vehicle", "9") == 1
    assert "link_lost.vehicle: Input should be less than or equal to 8" in capsys.readouterr().err
    assert await cli(url, "fault", "link_lost", "--vehicle", "3") == 1  # this world has two
    assert "(409): vehicle: 3 is not a vehicle of this world" in capsys.readouterr().err
    assert await cli(url, "fault", "mocap_silent", "--fraction", "0.2") == 1
    assert "mocap_silent.fraction: Extra inputs are not permitted" in capsys.readouterr().err
    assert await cli(url, "fault", "udp_loss", "--fraction", "nan") == 2  # a usage error
    assert "--fraction: 'nan' is not a finite number" in capsys.readouterr().err
    assert await cli(url, "fault", "mocap_body_lost", "--body", "ghost") == 1
    assert "not a configured rigid body" in capsys.readouterr().err
    assert await cli(url, "fault", "--clear", "--vehicle", "1") == 2  # a usage error
    assert sim_api.world.fault_views() == []


async def test_fault_commands_without_a_world(
    api: ApiUnderTest, capsys: pytest.CaptureFixture[str]
) -> None:
    assert await cli(api.url, "fault") == 0
    assert "no simulated world here" in capsys.readouterr().out
    assert await cli(api.url, "fault", "mocap_silent") == 1
    assert "refused (409)" in capsys.readouterr().err
    assert await cli(api.url, "reset") == 1
    assert "not embedded" in capsys.readouterr().err
