"""End to end: ``serve --set agents.enabled=true`` on the embedded simulator — two agent
processes, each flying its own vehicle, joined to each other and to the ground station
only by Zenoh (docs/agents.md) — flown over HTTP, then one agent killed in hover."""

from __future__ import annotations

import asyncio
import os
import signal
import subprocess
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


def _tcp_connections(pid: int) -> set[tuple[int, int]]:
    """(local port, remote port) of ``pid``'s established TCP connections."""
    mine = _open_files(pid)
    connections = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            local, remote, state, inode = fields[1], fields[2], fields[3], fields[9]
            if state == "01" and f"socket:[{inode}]" in mine:  # ESTABLISHED
                ports = (int(local.rsplit(":", 1)[1], 16), int(remote.rsplit(":", 1)[1], 16))
                connections.add(ports)
    return connections


def _zenoh_ports(agent_pid: int) -> set[int]:
    """The Zenoh ports an agent's command line names (its own, the ground's, its peers')."""
    words = Path(f"/proc/{agent_pid}/cmdline").read_bytes().split(b"\0")
    return {
        int(words[k + 1].rsplit(b":", 1)[1])
        for k, word in enumerate(words[:-1])
        if word in (b"--listen", b"--connect")
    }


def assert_joined_only_by_zenoh(service: RunningService, agent_pids: list[int]) -> None:
    """No descriptor of an agent (started by serve, in a session of its own) is one of
    serve's other processes' (nothing inherited: no pipe, socket or file), its Unix sockets
    lead only to itself, and its TCP connections only to Zenoh ports or the world's QTM
    server (its MAVLink link is UDP, to its own vehicle)."""
    serve_files: set[str] = set()
    for pid in _descendants(service.process.pid) - set(agent_pids):
        serve_files |= _open_files(pid)
    unix_peers = _unix_peers()
    for pid in agent_pids:
        files = _open_files(pid)
        shared = {f for f in files & serve_files if f.startswith(("socket:", "pipe:", "/"))}
        shared -= {"/dev/null"}
        assert not shared, f"agent {pid} shares {shared} with serve"
        # Its own Unix sockets (the event loop's self-pipe) are connected to itself only.
        outside = {unix_peers[f] for f in files if f in unix_peers} - files
        assert not outside, f"agent {pid} has Unix sockets connected to {outside}"
        qtm_port = next(
            int(w.split(b"=")[1])
            for w in Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
            if w.startswith(b"mocap.port=")
        )
        zenoh = _zenoh_ports(pid)
        strangers = {
            (local, remote)
            for local, remote in _tcp_connections(pid)
            if local not in zenoh and remote not in zenoh | {qtm_port}
        }
        assert not strangers, f"agent {pid} has connections (local, remote) {strangers}"


def agents_alive(status: Status) -> bool:
    return status.agents is not None and all(a.alive for a in status.agents)


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
        assert_joined_only_by_zenoh(service, agent_pids)
        for setpoint in PAPER_SETPOINTS:
            response = await http.post("/api/setpoints", json={**setpoint, "hold_s": 2.0})
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
