"""``uavbar-supervisor serve``: the service, composed from config.

``serve`` itself only starts and watches its processes (docs/architecture.md): the API
process serves HTTP; the flight process runs mocap, the vehicle links and the control
loop; the mocap relay forwards the mocap to each PX4; with ``sim.embedded`` the world
process runs the simulated world, which the flight process reaches over loopback exactly
as it would reach a lab. The API, flight and relay processes are started again when they
die (the flight process then flies nothing until armed again; each PX4's failsafe has the
vehicles meanwhile). SIGINT/SIGTERM stops everything in order: the flight process lands
whatever is airborne and disarms while the API still answers, then the relay and the world
stop, then the API.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing.connection
import os
import secrets
import signal
import socket
from collections.abc import Sequence
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from api.server import bind
from px4_mavlink.transport import bind_udp
from supervisor.app.agent_spawn import SpawnedAgents, fleet_endpoints
from supervisor.app.api_process import GO, READY, ApiStart, api_tls
from supervisor.app.child_entries import (
    LinkSockets,
    Setup,
    SigningKeys,
    api_main,
    flight_main,
    ground_main,
    relay_main,
    world_main,
)
from supervisor.app.children import SPAWN, Child, Lifeline, start_deaf_to_ctrl_c, stop_child
from supervisor.app.config import TOKEN_ENV, Config, ConfigError
from supervisor.app.flight_main import FlightStart
from supervisor.app.ground_main import GroundStart
from supervisor.app.relay_main import relay_addresses
from supervisor.app.signing_keys import load_signing_keys, signing_keys_path
from supervisor.flight.status import ProcessStatus
from supervisor.ipc.rendezvous import Rendezvous, listen_unix, write_discovery
from supervisor.runtime.flight_process import LANDING_TIMEOUT_S

log = logging.getLogger(__name__)

WORLD_START_TIMEOUT_S = 60.0
API_START_TIMEOUT_S = 60.0
SPARE_API_AFTER_S = 5.0  # the spare API process loads once the service is up, not during it


def resolve_token(config: Config) -> tuple[str, bool]:
    """The API token and whether it was generated (then it must be shown)."""
    if config.api.token:
        return config.api.token, False
    from_env = os.environ.get(TOKEN_ENV)
    if from_env:
        return from_env, False
    return secrets.token_urlsafe(18), True


def _bind_link_sockets(config: Config, world: dict[str, Any] | None) -> LinkSockets:
    """The vehicle links' UDP sockets, bound here so that the flight process and the mocap
    relay both send from them (``supervisor.mavlink.relay``), and a restarted flight
    process from the same address again; on the configured interface (loopback for the
    embedded world)."""
    n = config.system.n_vehicles
    ports = (world.get("link_ports") or [0] * n) if world is not None else config.vehicles.ports
    host = config.link_bind_host()
    return tuple(bind_udp(host, port) for port in ports)


def _signing_keys(config: Config) -> SigningKeys:
    """The vehicles' signing keys by system id when ``vehicles.signing`` is on (read once,
    here, so that a bad key file stops ``serve`` before anything starts)."""
    v = config.vehicles
    if not v.signing:
        return None
    return load_signing_keys(signing_keys_path(v.signing_keys), v.system_ids)


def _bind_http(config: Config) -> socket.socket:
    """The API's listening socket; a port in use (or not ours to take) is a setup error,
    said in one line."""
    host, port = config.api.host, config.api.port
    try:
        return bind(host, port)
    except OSError as error:
        raise ConfigError(
            f"cannot listen on {host}:{port}: {error.strerror} (another serve? choose a "
            "port with --set api.port=N, or PORT=N with make serve)"
        ) from None


def _certificate_path(config: Config) -> str | None:
    """The API's certificate as an absolute path, for the terminal client to trust."""
    cert_file = config.api.tls_cert_file
    return os.path.abspath(cert_file) if cert_file else None


def _dashboard_address(host: str, port: int, token: str) -> str:
    """The address to open: the dashboard reads its token from the fragment, which the
    browser never sends to the server."""
    shown = "127.0.0.1" if host in ("0.0.0.0", "::", "") else host
    shown = f"[{shown}]" if ":" in shown else shown
    return f"http://{shown}:{port}/#token={token}"


def _spawn(name: str, target: Any, *args: Any) -> tuple[BaseProcess, Lifeline]:
    """Start ``target(*args, lifeline)`` as process ``name``; serve keeps the other end."""
    parent, child = SPAWN.Pipe()
    process = SPAWN.Process(target=target, args=(*args, child), name=name)
    start_deaf_to_ctrl_c(process)
    child.close()
    return process, parent


def _start_world(
    setup: Setup, listener: socket.socket
) -> tuple[BaseProcess, Lifeline, dict[str, Any]]:
    """The world process, its lifeline (which also brings its addresses)."""
    parent, child = SPAWN.Pipe()
    process = SPAWN.Process(target=world_main, args=(setup, child, listener), name="uavbar-world")
    start_deaf_to_ctrl_c(process)
    child.close()
    if not parent.poll(WORLD_START_TIMEOUT_S):
        process.kill()
        raise RuntimeError("the simulated world did not start")
    addresses: dict[str, Any] = parent.recv()
    if "error" in addresses:
        process.join(5.0)
        raise RuntimeError(f"the simulated world failed: {addresses['error']}")
    return process, parent, addresses


def _process_status(child: Child) -> ProcessStatus:
    """One child as the status shows it."""
    pid = child.process.pid if child.process is not None else None
    return ProcessStatus(
        pid=pid, alive=child.alive, restarts=child.restarts, last_exit=child.last_exit
    )


class Service:
    """``serve``'s processes and what they share."""

    def __init__(self, setup: Setup, config: Config, token: str) -> None:
        self.setup = setup
        self.config = config
        self.token = token
        config.link_bind_host()  # a lab without its interface: refused before anything starts
        self.signing_keys = _signing_keys(config)
        self.http_socket = _bind_http(config)
        self.rendezvous = Rendezvous.create()
        self.world_addresses: dict[str, Any] | None = None
        self.link_sockets: LinkSockets | None = None
        self.children: dict[str, Child] = {}
        self._flight_listener: socket.socket | None = None
        self._table_pipe: multiprocessing.connection.Connection | None = None
        # A started API process waiting for GO (its process, lifeline, serve's pipe end).
        self._spare: tuple[BaseProcess, Lifeline, multiprocessing.connection.Connection] | None
        self._spare = None
        self._api_ready = asyncio.Event()
        self.agents = SpawnedAgents()
        self._ground_endpoint = ""

    @property
    def port(self) -> int:
        return int(self.http_socket.getsockname()[1])

    def process_table(self) -> dict[str, ProcessStatus]:
        """Name → PID, alive and restarts, for the status (a child never started is left
        out)."""
        return {name: _process_status(child) for name, child in self.children.items()}

    def publish_table(self, *_: Any) -> None:
        if self._table_pipe is not None:
            with contextlib.suppress(OSError):
                self._table_pipe.send(self.process_table())

    async def start(self) -> None:
        config = self.config
        if config.sim.embedded:
            listener = listen_unix(self.rendezvous.world)
            process, lifeline, started = await asyncio.to_thread(_start_world, self.setup, listener)
            listener.close()
            log.info(
                "simulated world: QTM %s, PX4s %s", started["qtm"], ", ".join(started["vehicles"])
            )
            self.world_addresses = started
            world = Child("world", lambda _: (process, lifeline), restartable=False)
            self._watch(world)
        self._flight_listener = listen_unix(self.rendezvous.flight)
        if config.agents.enabled:
            self._start_fleet()
        else:
            self._start_flight_and_relay()
        self._watch(Child("api", self._start_api, restartable=True))
        try:
            async with asyncio.timeout(API_START_TIMEOUT_S):
                await self._api_ready.wait()
        except TimeoutError:
            raise RuntimeError("the API process did not start") from None

    def _start_flight_and_relay(self) -> None:
        config = self.config
        self.link_sockets = _bind_link_sockets(config, self.world_addresses)
        if relay_addresses(config, self.world_addresses) is not None:
            self._watch(Child("relay", self._start_relay, restartable=True))
        else:
            log.info("mocap relay: vehicle addresses unknown, the flight process forwards mocap")
        self._watch(Child("flight", self._start_flight, restartable=True))

    def _start_fleet(self) -> None:
        """The agents' ground station in the flight process's place (and the agents
        themselves with ``agents.spawn``): each agent owns its vehicle's link and forwards
        its mocap, so neither links nor relay are serve's."""
        ground, endpoints = fleet_endpoints(self.config)
        self._ground_endpoint = ground
        self._watch(Child("ground", self._start_ground, restartable=True))
        if self.config.agents.spawn:
            self.agents.start(
                self.setup, self.config, self.token, ground, endpoints, self.world_addresses
            )

    def _start_ground(self, _: str | None) -> tuple[BaseProcess, Lifeline]:
        assert self._flight_listener is not None
        start = GroundStart(self._flight_listener, self.token, self._ground_endpoint)
        return _spawn("uavbar-ground", ground_main, self.setup, start)

    def _watch(self, child: Child) -> None:
        child.on_exit = self._ended
        self.children[child.name] = child
        child.start()
        self.publish_table()

    def _ended(self, child: Child, how: str) -> None:
        if child.name == "ground":
            log.error(
                "the ground station died (%s): the agents hold, then land; starting it again",
                how,
            )
        elif child.name == "flight":
            log.error(
                "the flight process died (%s): nothing commands the vehicles now, each PX4's "
                "offboard-loss failsafe takes over; starting it again (it flies nothing until "
                "armed)",
                how,
            )
        elif child.name == "world":
            log.error("the simulated world died (%s): no mocap, no vehicles", how)
        else:
            log.error("the %s process died (%s)", child.name, how)
        asyncio.get_running_loop().call_soon(self.publish_table)

    def _start_relay(self, _: str | None) -> tuple[BaseProcess, Lifeline]:
        return _spawn(
            "uavbar-relay",
            relay_main,
            self.setup,
            self.world_addresses,
            self.link_sockets,
            self.signing_keys,
        )

    def _start_flight(self, because: str | None) -> tuple[BaseProcess, Lifeline]:
        assert self.link_sockets is not None and self._flight_listener is not None
        start = FlightStart(
            self._flight_listener,
            self.token,
            self.link_sockets,
            "relay" in self.children,
            because,
            self.signing_keys,
        )
        return _spawn("uavbar-flight", flight_main, self.setup, start, self.world_addresses)

    def _spawn_api(self) -> tuple[BaseProcess, Lifeline, multiprocessing.connection.Connection]:
        """An API process, loaded and waiting for ``GO``."""
        ours, theirs = SPAWN.Pipe()
        start = ApiStart(
            self.http_socket, self.rendezvous, self.token, self.config.sim.embedded, theirs
        )
        process, lifeline = _spawn("uavbar-api", api_main, self.setup, start)
        theirs.close()
        return process, lifeline, ours

    def _start_api(self, _: str | None) -> tuple[BaseProcess, Lifeline]:
        """The spare, told to serve (else a new one), and a new spare a little later."""
        loop = asyncio.get_running_loop()
        if self._table_pipe is not None:
            loop.remove_reader(self._table_pipe.fileno())
            self._table_pipe.close()
        spare, self._spare = self._spare, None
        if spare is None or not spare[0].is_alive():
            if spare is not None:
                spare[1].close()
                spare[2].close()
            spare = self._spawn_api()
        process, lifeline, ours = spare
        ours.send(GO)
        self._table_pipe = ours
        loop.add_reader(ours.fileno(), self._api_says)
        loop.call_soon(self.publish_table)
        loop.call_later(SPARE_API_AFTER_S, self._prepare_spare)
        return process, lifeline

    def _prepare_spare(self) -> None:
        api = self.children.get("api")
        if self._spare is None and api is not None and not api.stopped:
            self._spare = self._spawn_api()

    def _stop_spare(self) -> None:
        """Blocking: the spare ends when its lifeline closes."""
        spare, self._spare = self._spare, None
        if spare is not None:
            process, lifeline, pipe = spare
            lifeline.close()
            pipe.close()
            process.join(5.0)
            if process.is_alive():
                process.kill()
                process.join(5.0)

    def _api_says(self) -> None:
        assert self._table_pipe is not None
        try:
            while self._table_pipe.poll():
                if self._table_pipe.recv() == READY:
                    self._api_ready.set()
                    self.publish_table()
        except (EOFError, OSError):
            asyncio.get_running_loop().remove_reader(self._table_pipe.fileno())

    async def stop(self) -> None:
        """Land and stop the flight process (the API answering meanwhile), then the rest;
        a child that ends meanwhile (Ctrl-C reaches them all) is not started again."""
        for child in self.children.values():
            child.stopped = True
        order = [
            ("flight", LANDING_TIMEOUT_S + 10.0),
            ("ground", LANDING_TIMEOUT_S + 10.0),
            ("relay", 5.0),
            ("world", 10.0),
            ("api", 5.0),
        ]
        for name, timeout_s in order:
            if name in self.children:
                await stop_child(self.children[name], timeout_s)
            if name == "ground":  # landed by it: then the agents stop
                await asyncio.to_thread(self.agents.stop)
        await asyncio.to_thread(self._stop_spare)
        if self._table_pipe is not None:
            asyncio.get_running_loop().remove_reader(self._table_pipe.fileno())
            self._table_pipe.close()
        for sock in (*(self.link_sockets or ()), self.http_socket):
            sock.close()
        if self._flight_listener is not None:
            self._flight_listener.close()
        self.rendezvous.remove()


async def serve(setup: Setup) -> int:
    """Run the service until SIGINT or SIGTERM; returns the exit status."""
    config = setup.load()
    token, generated = resolve_token(config)
    service = Service(setup, config, token)
    stop = asyncio.Event()

    def on_signal() -> None:
        # Kept until every process has stopped: a second Ctrl-C (or a signal to the whole
        # process group) must not interrupt the landing half-way and leave children behind.
        if stop.is_set():
            log.warning(
                "already stopping: landing first, then every process stops "
                "(uavbar-supervisor kill stops the motors now)"
            )
        stop.set()

    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, on_signal)
    discovery: Path | None = None
    try:
        await service.start()
        host = config.api.host
        scheme = "https" if api_tls(config) is not None else "http"
        url = f"{scheme}://{host}:{service.port}"
        discovery = write_discovery(
            service.port,
            {
                "url": url,
                "pid": os.getpid(),
                "operator_socket": str(service.rendezvous.flight),
                "cert_file": _certificate_path(config),
            },
        )
        log.info(
            "uavbar-supervisor serving %s/ (setup %s; API docs %s/docs; Ctrl-C stops)",
            url,
            config.name,
            url,
        )
        if generated:
            log.info(
                "API token (generated; set %s or api.token to choose one): %s", TOKEN_ENV, token
            )
        log.info("dashboard: %s", _dashboard_address(host, service.port, token))
        await stop.wait()
        log.info("stopping: landing whatever is airborne, then stopping every process")
    finally:
        await service.stop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        if discovery is not None:
            discovery.unlink(missing_ok=True)
    log.info("stopped")
    return 0


def run_serve(config_path: Path, overrides: Sequence[str]) -> int:
    """Entry point of ``serve`` (the configuration was already validated)."""
    return asyncio.run(serve(Setup(config_path, tuple(overrides))))
