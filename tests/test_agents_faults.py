"""End to end, agents lost: one of three killed under the plate, and one of two cut off.

For the cut, agent 1 runs in a network namespace of its own, joined to the rest by two
veth pairs — one to its vehicle and the mocap (its companion computer's own link and
camera network, never cut), one to the Zenoh network (cut with ``ip link set DEV down``) —
and agent 2 and the ground station beside the world. No traffic leaves the machine: every
address is the test's own, inside namespaces and veths it makes."""

from __future__ import annotations

import asyncio
import contextlib
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import AsyncIterator, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from benchmarks.service import in_mode, notices, running_service
from benchmarks.tick import flight_truths
from supervisor.cli.main import main
from supervisor.flight.modes import Mode
from supervisor.flight.phases import Phase
from tests.test_agents_e2e import (
    AGENTS,
    agents_alive,
    agents_logs_noted,
    assert_joined_only_by_zenoh,
    world_apart,
)
from tests.test_service import TOKEN, reached, ready

pytestmark = pytest.mark.slow


@dataclass(frozen=True)
class Namespace:
    """A network namespace and the addresses of its two veth pairs (host side, inside)."""

    name: str
    zenoh_link: str  # the host side of the Zenoh veth (its inside end: the one cut)
    zenoh_host: str
    zenoh_inside: str
    world_host: str
    world_inside: str


def _ip(*arguments: str) -> None:
    subprocess.run(["ip", *arguments], check=True, capture_output=True)


@contextlib.contextmanager
def agent_namespace() -> Iterator[Namespace]:
    """A namespace with two veth pairs on subnets of this test's own."""
    octet = 16 + os.getpid() % 200
    ns = Namespace(
        name=f"uavbar-{os.getpid()}",
        zenoh_link=f"uz{os.getpid() % 100000}",
        zenoh_host=f"10.{octet}.1.1",
        zenoh_inside=f"10.{octet}.1.2",
        world_host=f"10.{octet}.2.1",
        world_inside=f"10.{octet}.2.2",
    )
    world_link = f"uw{os.getpid() % 100000}"
    _ip("netns", "add", ns.name)
    try:
        _ip("netns", "exec", ns.name, "ip", "link", "set", "lo", "up")
        for link, host, inside in (
            (ns.zenoh_link, ns.zenoh_host, ns.zenoh_inside),
            (world_link, ns.world_host, ns.world_inside),
        ):
            _ip("link", "add", link, "type", "veth", "peer", "name", f"{link}i")
            _ip("link", "set", f"{link}i", "netns", ns.name)
            _ip("addr", "add", f"{host}/24", "dev", link)
            _ip("link", "set", link, "up")
            _ip("netns", "exec", ns.name, "ip", "addr", "add", f"{inside}/24", "dev", f"{link}i")
            _ip("netns", "exec", ns.name, "ip", "link", "set", f"{link}i", "up")
        yield ns
    finally:
        for link in (ns.zenoh_link, world_link):
            subprocess.run(["ip", "link", "del", link], capture_output=True)
        subprocess.run(["ip", "netns", "del", ns.name], capture_output=True)


def require_namespaces() -> None:
    if os.geteuid() != 0 or shutil.which("ip") is None:
        pytest.skip("network namespaces need root and iproute2's ip")


@contextlib.asynccontextmanager
async def agent(
    vehicle: int, overrides: list[str], listen: str, connect: list[str], log: Path, ns: str = ""
) -> AsyncIterator[asyncio.subprocess.Process]:
    command = [sys.executable, "-m", "supervisor.cli.main", "agent", "--vehicle", str(vehicle)]
    command = (["ip", "netns", "exec", ns] if ns else []) + command
    for override in overrides:
        command += ["--set", override]
    command += ["--listen", listen] + [arg for c in connect for arg in ("--connect", c)]
    with log.open("ab") as sink:
        process = await asyncio.create_subprocess_exec(
            *command, stdout=sink, stderr=sink, env={**os.environ, "UAVBAR_TOKEN": TOKEN}
        )
    try:
        yield process
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGTERM)
            try:
                async with asyncio.timeout(20.0):
                    await process.wait()
            except TimeoutError:
                process.kill()
                await process.wait()


@agents_logs_noted
async def test_one_agent_cut_off_in_hover_every_vehicle_lands_slowly(tmp_path: Path) -> None:
    """Agent 1's Zenoh link cut in hover: cut off from everyone, it lowers its bar end; agent
    2, its peer lost, lowers its own; both vehicles on the ground within 10 s, none
    descending faster than 0.5 m/s and none handed to PX4's blind landing (the world's
    truth). Beyond loopback, so the fleet flies over TLS with its own certificates."""
    require_namespaces()
    fleet = tmp_path / "fleet"
    assert main(["fleet-certs", "--folder", str(fleet)]) == 0
    with agent_namespace() as ns:
        world_setup = [f'sim.host="{ns.world_host}"']
        async with world_apart(tmp_path, world_setup) as (world, qtm_port):
            ground, agent_1, agent_2 = (
                f"tls/{ns.zenoh_host}:7447",
                f"tls/{ns.zenoh_inside}:7448",
                f"tls/{ns.zenoh_host}:7449",
            )
            lab = [
                "sim.embedded=false",
                f'mocap.host="{ns.world_host}"',
                f"mocap.port={qtm_port}",
                f'vehicles.addresses=["{ns.world_host}:14580", "{ns.world_host}:14581"]',
                f'log.folder="{tmp_path}"',
                f'agents.tls_folder="{fleet}"',
                f'agents.ground_endpoint="{ground}"',
            ]
            on_host = [*lab, f'vehicles.bind_host="{ns.world_host}"']
            inside = [*lab, f'vehicles.bind_host="{ns.world_inside}"']
            serve = ["agents.enabled=true", "agents.spawn=false"]
            async with (
                running_service(TOKEN, tmp_path, [*serve, *on_host]) as service,
                agent(1, inside, agent_1, [ground, agent_2], tmp_path / "agent1.log", ns.name),
                agent(2, on_host, agent_2, [ground, agent_1], tmp_path / "agent2.log"),
                service.client() as http,
            ):
                await service.wait_for(http, agents_alive, 60.0, "both agents heard")
                await ready(service, http)
                await service.take_off(http)
                await asyncio.sleep(2.0)
                # Cut inside: the host side's address stays, for the host's own peers.
                _ip("netns", "exec", ns.name, "ip", "link", "set", f"{ns.zenoh_link}i", "down")
                cut_s = asyncio.get_running_loop().time()
                logs = [tmp_path / f"agent{i}.log" for i in (1, 2)]
                while not all("→ disarming" in log.read_text() for log in logs):
                    assert asyncio.get_running_loop().time() - cut_s < 10.0, [
                        log.read_text()[-2000:] for log in logs
                    ]
                    await asyncio.sleep(0.1)
                await service.wait_for(
                    http, in_mode(Mode.DISARMING, Mode.DISARMED), 5.0, "agent 2 on the ground"
                )
            await asyncio.sleep(1.0)  # the world's truth of the flight, said as it ends
    assert not [line for line in world if "AUTO.LAND" in line], world
    truth = flight_truths(world)[0]
    assert truth["max_descent_mps"] <= 0.5, truth
    assert truth["max_uav_tilt_deg"] < 30.0, truth


@agents_logs_noted
async def test_three_agents_carry_the_plate_and_two_set_it_down_when_one_is_killed(
    tmp_path: Path,
) -> None:
    """``sim_tri``'s plate on three agent processes, joined only by Zenoh: a setpoint flown
    over HTTP; agent 3 killed in hover, agents 1 and 2 set the plate down, no faster than
    0.5 m/s and tilting less than 30° (the world's truth)."""
    async with (
        running_service(TOKEN, tmp_path, AGENTS, setup="sim_tri") as service,
        service.client() as http,
    ):
        status = await service.wait_for(http, agents_alive, 60.0, "three agents heard")
        assert status.agents is not None and [a.vehicle for a in status.agents] == [1, 2, 3]
        await ready(service, http)
        await service.take_off(http)
        assert_joined_only_by_zenoh(service, status)
        setpoint = {"bar_position": [0.3, 0.2, 1.1], "hold_s": 1.0}
        assert (await http.post("/api/setpoints", json=setpoint)).status_code == 200
        await service.wait_for(http, reached(setpoint), 30.0, "the setpoint")
        await service.wait_for(http, in_mode(Mode.HOVER), 30.0, "the setpoint held")
        await asyncio.sleep(1.0)
        os.kill(status.agents[2].pid or 0, signal.SIGKILL)
        status = await service.wait_for(
            http, lambda s: s.phase is Phase.SET_DOWN, 5.0, "UAVs 1 and 2 setting it down"
        )
        said = " ".join(notices(status))
        assert "vehicle 3 link lost: UAVs 1, 2 set the payload down" in said, said
        await service.wait_for(
            http, in_mode(Mode.DISARMING, Mode.DISARMED), 60.0, "UAVs 1 and 2 landed"
        )
        await asyncio.sleep(1.0)
    truth = flight_truths(service.output)[0]
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert max(truth["max_descent_uav1_mps"], truth["max_descent_uav2_mps"]) <= 0.5, truth
