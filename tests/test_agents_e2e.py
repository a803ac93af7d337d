"""End to end: ``serve --set agents.enabled=true`` on the embedded simulator — two agent
processes, each flying its own vehicle, joined to each other and to the ground station
only by Zenoh (docs/agents.md) — flown over HTTP, then one agent killed in hover."""

from __future__ import annotations

import asyncio
import contextlib
import functools
import os
import signal
import socket
import subprocess
import sys
from collections.abc import AsyncIterator, Awaitable, Callable, Sequence
from pathlib import Path

import pytest

from benchmarks.service import RunningService, in_mode, notices, running_service
from benchmarks.tick import PAPER_SETPOINTS, flight_truths
from supervisor.flight.modes import Mode
from supervisor.flight.phases import Phase
from supervisor.flight.status import Status
from supervisor.logs.flight_log import read_flight_log
from supervisor.logs.report import summarize
from tests.test_service import TOKEN, ready

pytestmark = pytest.mark.slow

AGENTS = ["agents.enabled=true"]


def _descendants(root: int) -> set[int]:
    parents: dict[int, int] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parents[int(stat.parent.name)] = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError):
            continue
    tree, frontier = {root}, [root]
    while frontier:
        parent = frontier.pop()
        children = [pid for pid, ppid in parents.items() if ppid == parent]
        tree.update(children)
        frontier.extend(children)
    return tree


def _open_files(pid: int) -> set[str]:
    """What ``pid``'s descriptors are: ``socket:[inode]``, ``pipe:[inode]``, paths."""
    targets = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            targets.add(os.readlink(fd))
        except OSError:
            continue
    return targets


def _unix_peers() -> dict[str, str]:
    """Each connected Unix socket's peer, as ``socket:[inode]`` (iproute2's ``ss``)."""
    listing = subprocess.run(["ss", "-x", "-a"], capture_output=True, text=True, check=True)
    peers = {}
    for line in listing.stdout.splitlines()[1:]:
        fields = line.split()
        if len(fields) >= 8 and fields[5].isdigit() and fields[7].isdigit():
            peers[f"socket:[{fields[5]}]"] = f"socket:[{fields[7]}]"
    return peers


TCP_ESTABLISHED, TCP_LISTEN = "01", "0A"  # /proc/net/tcp's state codes


def _tcp_sockets(pid: int, state: str) -> set[tuple[int, int]]:
    """(local port, remote port) of ``pid``'s TCP sockets in ``state``."""
    mine = _open_files(pid)
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            local, remote, inode = fields[1], fields[2], fields[9]
            if fields[3] == state and f"socket:[{inode}]" in mine:
                found.add((int(local.rsplit(":", 1)[1], 16), int(remote.rsplit(":", 1)[1], 16)))
    return found


def _listening_ports(pids: Sequence[int]) -> set[int]:
    return {local for pid in pids for local, _ in _tcp_sockets(pid, TCP_LISTEN)}


# Character devices every Python process opens on its own; no channel between processes.
UNSHARED_DEVICES = {"/dev/null", "/dev/urandom", "/dev/random"}


def assert_joined_only_by_zenoh(service: RunningService, status: Status) -> None:
    """No descriptor of an agent (started by serve, in a session of its own) is one of
    serve's other processes' (nothing inherited: no pipe, socket or file), its Unix sockets
    lead only to itself, and its TCP connections only to the Zenoh ports the agents and the
    ground station listen on or to the world's QTM server (its MAVLink link is UDP, to its
    own vehicle). Ports come from the listening sockets, not command lines: each process
    retitles itself."""
    assert status.agents is not None
    agent_pids = [a.pid for a in status.agents if a.pid is not None]
    ground_pid, world_pid = (status.processes[name].pid for name in ("ground", "world"))
    assert ground_pid is not None and world_pid is not None
    serve_files: set[str] = set()
    for pid in _descendants(service.process.pid) - set(agent_pids):
        serve_files |= _open_files(pid)
    unix_peers = _unix_peers()
    zenoh_ports = _listening_ports([ground_pid, *agent_pids])
    qtm_ports = _listening_ports([world_pid])
    assert zenoh_ports and qtm_ports
    for pid in agent_pids:
        files = _open_files(pid)
        shared = {f for f in files & serve_files if f.startswith(("socket:", "pipe:", "/"))}
        shared -= UNSHARED_DEVICES
        assert not shared, f"agent {pid} shares {shared} with serve"
        # Its own Unix sockets (the event loop's self-pipe) are connected to itself only.
        outside = {unix_peers[f] for f in files if f in unix_peers} - files
        assert not outside, f"agent {pid} has Unix sockets connected to {outside}"
        strangers = {
            (local, remote)
            for local, remote in _tcp_sockets(pid, TCP_ESTABLISHED)
            if local not in zenoh_ports and remote not in zenoh_ports | qtm_ports
        }
        assert not strangers, f"agent {pid} has connections (local, remote) {strangers}"


def _agents_said(folder: Path) -> list[str]:
    return [
        f"--- {log.name} ---\n{log.read_text()[-6000:]}"
        for log in sorted(folder.glob("agent*.log"))
    ]


def agents_logs_noted(
    test: Callable[[Path], Awaitable[None]],
) -> Callable[[Path], Awaitable[None]]:
    """The test's failure carries what the agents said (their output is their own, in the
    test's ``tmp_path``)."""

    @functools.wraps(test)
    async def noted(tmp_path: Path) -> None:
        try:
            await test(tmp_path)
        except BaseException as error:
            for note in _agents_said(tmp_path):
                error.add_note(note)
            raise

    return noted


def agents_alive(status: Status) -> bool:
    return status.agents is not None and all(a.alive for a in status.agents)


@agents_logs_noted
async def test_two_agents_fly_the_papers_sequence_land_then_one_killed_the_other_sets_down(
    tmp_path: Path,
) -> None:
    """The paper's sequence flown by two agent processes over HTTP (the bar's x error
    close to the single process's), a landing; then a second flight from a stable hover in
    which agent 2 is killed: agent 1 lowers its bar end alone, as one flight process does
    for a lost vehicle, no faster than 0.5 m/s and tilting less than 30° (the world's
    truth of that flight)."""
    async with running_service(TOKEN, tmp_path, AGENTS) as service, service.client() as http:
        status = await service.wait_for(http, agents_alive, 60.0, "both agents heard")
        await ready(service, http)
        assert status.agents is not None and [a.vehicle for a in status.agents] == [1, 2]
        agent_pids = [a.pid for a in status.agents if a.pid is not None]
        assert len(agent_pids) == 2 and set(status.processes) == {"api", "ground", "world"}
        refused = await http.post("/api/mode", json={"controller": "centralized"})
        assert refused.status_code == 409 and "decentralized" in refused.text
        await service.take_off(http)
        assert_joined_only_by_zenoh(service, status)
        for setpoint in PAPER_SETPOINTS:
            response = await http.post("/api/setpoints", json={**setpoint, "hold_s": 1.0})
            assert response.status_code == 200, response.text
        await service.wait_for(
            http,
            lambda s: s.setpoints.active is None and not s.setpoints.queued,
            120.0,
            "the paper's setpoints",
        )
        status = await service.status(http)
        assert status.mode is Mode.HOVER and status.controller == "decentralized"
        assert status.agents is not None and status.log is not None
        assert all(a.link_latency_ms is not None and a.link_latency_ms < 50 for a in status.agents)
        paper_log = Path(status.log)
        landed = await http.post("/api/land?wait_s=90", timeout=100.0)
        assert landed.status_code == 200, landed.text
        assert landed.json()["outcome"]["message"].startswith("landed and disarmed")

        await service.take_off(http)
        await asyncio.sleep(2.0)
        os.kill(agent_pids[1], signal.SIGKILL)
        status = await service.wait_for(
            http, lambda s: s.phase is Phase.SET_DOWN, 5.0, "UAV 1 setting its end down"
        )
        said = " ".join(notices(status))
        assert "vehicle 2 link lost: UAV 1 sets its bar end down alone" in said, said
        assert status.agents is not None and not status.agents[1].alive
        await service.wait_for(http, in_mode(Mode.DISARMING, Mode.DISARMED), 60.0, "UAV 1 landed")
        await asyncio.sleep(1.0)  # the world's truth of the flight, said as it ends
    paper = summarize(read_flight_log(paper_log))
    assert paper["bar_x_error_std_m"] < 0.05, paper
    killed = flight_truths(service.output)[1]
    assert killed["max_uav_tilt_deg"] < 30.0, killed
    assert killed["max_descent_uav1_mps"] <= 0.5, killed  # what agent 1 flies


@contextlib.asynccontextmanager
async def world_apart(
    log_folder: Path, overrides: Sequence[str] = ()
) -> AsyncIterator[tuple[list[str], int]]:
    """``uavbar-supervisor sitl``: the simulated world as a process of its own, as the
    arena's vehicles and QTM are (docs/agents.md); its output lines and QTM port."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        qtm_port = probe.getsockname()[1]
    arguments = ["sitl", "--set", f"mocap.port={qtm_port}", "--set", f'log.folder="{log_folder}"']
    for override in overrides:
        arguments += ["--set", override]
    process = await asyncio.create_subprocess_exec(
        sys.executable,
        "-m",
        "supervisor.cli.main",
        *arguments,
        stdout=asyncio.subprocess.PIPE,
        stderr=asyncio.subprocess.STDOUT,
        start_new_session=True,
    )
    assert process.stdout is not None
    output: list[str] = []

    async def read() -> None:
        assert process.stdout is not None
        while line := await process.stdout.readline():
            output.append(line.decode(errors="replace").rstrip())

    reader = asyncio.create_task(read())
    try:
        async with asyncio.timeout(60.0):
            while not any("running in real time" in line for line in output):
                assert process.returncode is None, "sitl exited:\n" + "\n".join(output)
                await asyncio.sleep(0.1)
        yield output, qtm_port
    finally:
        if process.returncode is None:
            process.send_signal(signal.SIGINT)
            try:
                async with asyncio.timeout(20.0):
                    await process.wait()
            except TimeoutError:
                process.kill()
                await process.wait()
        await reader


@agents_logs_noted
async def test_the_ground_station_killed_in_hover_the_agents_hold_then_land(
    tmp_path: Path,
) -> None:
    """Every process of ``serve`` killed in hover (the world runs apart, as a lab's does):
    the agents hold the bar for agents.ground_loss_hold_s, then land it together, on their
    own mocap throughout (no vehicle handed to PX4's blind landing)."""
    async with world_apart(tmp_path) as (world, qtm_port):
        lab = [
            "sim.embedded=false",
            'mocap.host="127.0.0.1"',
            f"mocap.port={qtm_port}",
            'vehicles.addresses=["127.0.0.1:14580", "127.0.0.1:14581"]',
            'vehicles.bind_host="127.0.0.1"',
            "agents.ground_loss_hold_s=2.0",
        ]
        agent_pids: list[int] = []
        try:
            async with (
                running_service(TOKEN, tmp_path, [*AGENTS, *lab]) as service,
                service.client() as http,
            ):
                status = await service.wait_for(http, agents_alive, 60.0, "both agents heard")
                assert status.agents is not None
                agent_pids = [a.pid for a in status.agents if a.pid is not None]
                await ready(service, http)
                await service.take_off(http)
                await asyncio.sleep(2.0)
                for pid in _descendants(service.process.pid) - set(agent_pids):
                    os.kill(pid, signal.SIGKILL)
                await service.process.wait()
            logs = [tmp_path / f"agent{i}.log" for i in (1, 2)]
            deadline = asyncio.get_running_loop().time() + 40.0
            while not all("mode disarming → disarmed" in log.read_text() for log in logs):
                assert asyncio.get_running_loop().time() < deadline, logs[0].read_text()
                await asyncio.sleep(0.2)
        finally:
            for pid in agent_pids:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGTERM)
        for log in logs:
            text = log.read_text()
            lost = text.index("ground station lost: holding the last setpoint 2 s")
            landing = text.index("ground station lost for 2 s: landing the payload")
            assert lost < landing < text.index("mode landing → disarming"), text
        await asyncio.sleep(1.0)  # the world's truth of the flight, said as it ends
    assert not [line for line in world if "AUTO.LAND" in line], world  # nobody flew blind
    truth = flight_truths(world)[0]
    assert truth["max_uav_tilt_deg"] < 30.0, truth
    assert truth["max_descent_mps"] <= 0.5, truth
