"""The agents ``serve`` starts on this computer (``agents.spawn``): each a process of its
own (``uavbar-supervisor agent``), in a session of its own, sharing nothing with ``serve``
but Zenoh — no pipe, socket or file is inherited, its output goes to its own log, and the
embedded world's addresses reach it as a lab's would, in its setup (``--set``)."""

from __future__ import annotations

import json
import logging
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path
from typing import Any

from supervisor.app.child_entries import Setup
from supervisor.app.config import TOKEN_ENV, Config

log = logging.getLogger(__name__)

AGENT_STOP_TIMEOUT_S = 10.0


def _free_tcp_port(host: str) -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind((host, 0))
        return int(probe.getsockname()[1])


def _with_port(endpoint: str) -> str:
    """``endpoint`` with a free port in place of 0."""
    head, _, port = endpoint.rpartition(":")
    if port != "0":
        return endpoint
    host = head.split("/", 1)[1].strip("[]")
    return f"{head}:{_free_tcp_port(host)}"


def fleet_endpoints(config: Config) -> tuple[str, list[str]]:
    """The ground station's endpoint and each agent's, free ports chosen for port 0 (and
    for agents without endpoints, on loopback, over the ground's protocol) — only when
    ``serve`` starts them."""
    agents = config.agents
    n = config.system.n_vehicles
    scheme = agents.ground_endpoint.split("/", 1)[0]
    listed = agents.agent_endpoints or [f"{scheme}/127.0.0.1:0"] * n
    if not agents.spawn:
        return agents.ground_endpoint, listed
    return _with_port(agents.ground_endpoint), [_with_port(e) for e in listed]


def _toml(value: Any) -> str:
    return json.dumps(value)  # strings, numbers and lists of them: the same in TOML


def world_overrides(world: dict[str, Any] | None) -> list[str]:
    """The embedded world's addresses as a lab setup names them."""
    if world is None:
        return []
    qtm_host, _, qtm_port = world["qtm"].rpartition(":")
    n = len(world["vehicles"])
    overrides = [
        "sim.embedded=false",
        f"mocap.host={_toml(qtm_host)}",
        f"mocap.port={int(qtm_port)}",
        f"vehicles.addresses={_toml(list(world['vehicles']))}",
        f"vehicles.ports={_toml(world.get('link_ports') or [0] * n)}",
        f"vehicles.bind_host={_toml(qtm_host)}",
    ]
    events = world.get("px4_events")
    if events and events != "None":
        overrides.append(f"vehicles.px4_events={_toml(events)}")
    return overrides


def agent_command(
    setup: Setup, vehicle: int, listen: str, connect: list[str], world: dict[str, Any] | None
) -> list[str]:
    """The command line of agent ``vehicle``: serve's setup, the world's addresses, where
    it listens and whom it joins (Zenoh endpoints)."""
    command = [sys.executable, "-m", "supervisor.cli.main", "agent", "--vehicle", str(vehicle)]
    command += ["--config", str(setup.config_path)]
    for override in (*setup.overrides, *world_overrides(world)):
        command += ["--set", override]
    command += ["--listen", listen]
    for endpoint in connect:
        command += ["--connect", endpoint]
    return command


class SpawnedAgents:
    """The agents ``serve`` started, by vehicle."""

    def __init__(self) -> None:
        self.processes: dict[int, subprocess.Popen[bytes]] = {}

    def start(
        self,
        setup: Setup,
        config: Config,
        token: str,
        ground: str,
        endpoints: list[str],
        world: dict[str, Any] | None,
    ) -> None:
        folder = Path(config.log.folder)
        folder.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, TOKEN_ENV: token}
        for vehicle in range(1, config.system.n_vehicles + 1):
            output = folder / f"agent{vehicle}.log"
            with output.open("ab") as sink:
                peers = [e for i, e in enumerate(endpoints, start=1) if i != vehicle]
                listen = endpoints[vehicle - 1]
                process = subprocess.Popen(
                    agent_command(setup, vehicle, listen, [ground, *peers], world),
                    stdin=subprocess.DEVNULL,
                    stdout=sink,
                    stderr=subprocess.STDOUT,
                    close_fds=True,
                    start_new_session=True,  # a Ctrl-C to serve's group is serve's to decide
                    env=env,
                )
            self.processes[vehicle] = process
            log.info("agent %d: pid %d, log %s", vehicle, process.pid, output)

    def stop(self) -> None:
        """SIGTERM each agent (each lands its part first) and wait; kill what stays."""
        for process in self.processes.values():
            if process.poll() is None:
                process.send_signal(signal.SIGTERM)
        for vehicle, process in self.processes.items():
            try:
                process.wait(AGENT_STOP_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                log.error("agent %d did not stop: killed", vehicle)
                process.kill()
                process.wait()
