"""``uavbar-supervisor serve``: the service, composed from config.

Three processes (docs/architecture.md): this one serves the API; a flight process runs
mocap, the vehicle links and the control loop; with ``sim.embedded`` a third runs the
simulated world, which the flight process then reaches over loopback exactly as it would
reach a lab. SIGINT/SIGTERM (or the flight process ending) stops everything in order: the
flight process lands whatever is airborne and disarms, then the world stops, then HTTP.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import secrets
import signal
import socket
from collections.abc import Sequence
from dataclasses import dataclass
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any

from api.app import create_app
from api.guard import HttpPolicy, http_policy
from api.server import HttpServer, TlsFiles, bind
from supervisor.app.assembly import arena_from_config
from supervisor.app.config import TOKEN_ENV, Config, load_config
from supervisor.app.relay_main import relay_addresses
from supervisor.flight.operator_requests import ShutdownRequest
from supervisor.ipc.channel import Channel, WorldChannel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.world_client import WorldClient
from supervisor.mavlink.transport import bind_udp
from supervisor.runtime.flight_process import LANDING_TIMEOUT_S

log = logging.getLogger(__name__)

SPAWN = multiprocessing.get_context("spawn")
WORLD_START_TIMEOUT_S = 60.0
API_NICENESS = 5


@dataclass(frozen=True)
class Setup:
    """How to rebuild the configuration in a child process."""

    config_path: Path
    overrides: tuple[str, ...]

    def load(self) -> Config:
        return load_config(self.config_path, self.overrides)


def resolve_token(config: Config) -> tuple[str, bool]:
    """The API token and whether it was generated (then it must be shown)."""
    if config.api.token:
        return config.api.token, False
    from_env = os.environ.get(TOKEN_ENV)
    if from_env:
        return from_env, False
    return secrets.token_urlsafe(18), True


def _world_main(
    setup: Setup, ready: multiprocessing.connection.Connection, requests: socket.socket
) -> None:
    from supervisor.app.world_process import run_world_process

    run_world_process(setup.load(), ready, requests)


LinkSockets = tuple[socket.socket, socket.socket]


def _flight_main(
    setup: Setup,
    commands: socket.socket,
    urgent: socket.socket,
    world: Any,
    link_sockets: LinkSockets,
    relayed: bool,
) -> None:
    from supervisor.app.flight_main import run_flight_process

    run_flight_process(setup.load(), commands, urgent, world, link_sockets, relayed)


def _relay_main(
    setup: Setup,
    world: Any,
    link_sockets: LinkSockets,
    parent: multiprocessing.connection.Connection,
) -> None:
    from supervisor.app.relay_main import run_relay_process

    run_relay_process(setup.load(), world, link_sockets, parent)


def _bind_link_sockets(config: Config, world: dict[str, Any] | None) -> LinkSockets:
    """The vehicle links' UDP sockets, bound here so that the flight process and the mocap
    relay both send from them (``supervisor.mavlink.relay``)."""
    ports = (world.get("link_ports") or [0, 0]) if world is not None else config.vehicles.ports
    host = config.vehicles.bind_host
    return bind_udp(host, ports[0]), bind_udp(host, ports[1])


def _start_relay(
    setup: Setup, config: Config, world: dict[str, Any] | None, link_sockets: LinkSockets
) -> tuple[BaseProcess, multiprocessing.connection.Connection] | None:
    """The mocap relay process and the pipe whose closing stops it, when the vehicles'
    addresses are known (else the flight process forwards the mocap itself)."""
    if relay_addresses(config, world) is None:
        log.info("mocap relay: vehicle addresses unknown, the flight process forwards mocap")
        return None
    parent, child = SPAWN.Pipe()
    process = SPAWN.Process(
        target=_relay_main, args=(setup, world, link_sockets, child), name="uavbar-relay"
    )
    process.start()
    child.close()
    return process, parent


def _start_world(
    setup: Setup,
) -> tuple[BaseProcess, multiprocessing.connection.Connection, dict[str, Any], socket.socket]:
    """The world process, the pipe whose closing stops it, its addresses, and the API's end
    of the world channel (fault injection and reset)."""
    parent, child = SPAWN.Pipe()
    requests, world_end = socket.socketpair()
    process = SPAWN.Process(target=_world_main, args=(setup, child, world_end), name="uavbar-world")
    process.start()
    child.close()
    world_end.close()  # the world holds its own copy
    if not parent.poll(WORLD_START_TIMEOUT_S):
        process.kill()
        requests.close()
        raise RuntimeError("the simulated world did not start")
    addresses: dict[str, Any] = parent.recv()
    if "error" in addresses:
        process.join(5.0)
        requests.close()
        raise RuntimeError(f"the simulated world failed: {addresses['error']}")
    return process, parent, addresses, requests


async def _world_client(sock: socket.socket | None) -> WorldClient | None:
    """The API's handle on the world process, when there is one."""
    return None if sock is None else WorldClient(await WorldChannel.open(sock))


def api_policy(config: Config, token: str) -> HttpPolicy:
    """What the API's gate enforces (api.guard), from ``config.api``."""
    api = config.api
    return http_policy(token, api.host, api.allowed_hosts, api.max_body_bytes)


def api_tls(config: Config) -> TlsFiles | None:
    """The API's certificate and key, when configured."""
    api = config.api
    if api.tls_cert_file is None or api.tls_key_file is None:
        return None
    return TlsFiles(Path(api.tls_cert_file), Path(api.tls_key_file))


def process_table(children: dict[str, BaseProcess | None]) -> dict[str, dict[str, Any]]:
    """``serve``'s processes for the status: name → PID and whether it is alive (this one,
    the API, always is; a child that was never started is left out)."""
    table: dict[str, dict[str, Any]] = {"api": {"pid": os.getpid(), "alive": True}}
    for name, process in children.items():
        if process is not None:
            table[name] = {"pid": process.pid, "alive": process.is_alive()}
    return table


def _stop(process: BaseProcess | None, timeout_s: float) -> None:
    if process is None or not process.is_alive():
        return
    if process.pid is not None:
        os.kill(process.pid, signal.SIGTERM)
    process.join(timeout_s)
    if process.is_alive():
        process.kill()
        process.join(5.0)


async def serve(setup: Setup) -> int:
    """Run the service until a signal or the flight process ends; returns the exit status."""
    config = setup.load()
    token, generated = resolve_token(config)
    http_socket = bind(config.api.host, config.api.port)
    world: BaseProcess | None = None
    world_addresses: dict[str, Any] | None = None
    world_pipe: multiprocessing.connection.Connection | None = None
    world_channel: socket.socket | None = None
    if config.sim.embedded:
        world, world_pipe, started, world_channel = await asyncio.to_thread(_start_world, setup)
        log.info("simulated world: QTM %s, PX4s %s", started["qtm"], ", ".join(started["vehicles"]))
        world_addresses = started
    link_sockets = _bind_link_sockets(config, world_addresses)
    relay = _start_relay(setup, config, world_addresses, link_sockets)
    pairs = [socket.socketpair() for _ in range(2)]
    flight = SPAWN.Process(
        target=_flight_main,
        args=(setup, pairs[0][1], pairs[1][1], world_addresses, link_sockets, relay is not None),
        name="uavbar-flight",
    )
    flight.start()
    for _, child_end in pairs:
        child_end.close()
    for sock in link_sockets:
        sock.close()  # the children hold their own copies
    # The flight process and the world it flies come first on a busy machine: requests
    # and WebSocket clients may wait, ticks and mocap frames may not.
    os.nice(API_NICENESS)
    commands, urgent = [await Channel.open(parent_end) for parent_end, _ in pairs]
    client = FlightClient(commands, urgent)
    sim_world = await _world_client(world_channel)
    children = {"flight": flight, "world": world, "relay": relay[0] if relay else None}
    app = create_app(
        client,
        config.system.to_params(),
        arena_from_config(config),
        api_policy(config, token),
        sim_world,
        processes=lambda: process_table(children),
    )
    http = HttpServer(app, http_socket, api_tls(config))
    host = config.api.host
    log.info(
        "uavbar-supervisor serving %s://%s:%d/ (setup %s)",
        http.scheme,
        host,
        http.port,
        config.name,
    )
    if generated:
        log.info("API token (generated; set %s or api.token to choose one): %s", TOKEN_ENV, token)

    stop = asyncio.Event()
    flight_died = False
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    try:
        async with asyncio.TaskGroup() as group:
            group.create_task(http.serve())
            flight_link = group.create_task(client.run())
            world_link = group.create_task(sim_world.run()) if sim_world else None
            stopper = group.create_task(stop.wait())
            await asyncio.wait({flight_link, stopper}, return_when=asyncio.FIRST_COMPLETED)
            if flight_link.done() and not stop.is_set():
                await asyncio.to_thread(flight.join, 5.0)
                if flight.exitcode != 0:
                    flight_died = True
                    log.error(
                        "the flight process died (exit status %s): nothing commands the "
                        "vehicles now, each PX4's offboard-loss failsafe takes over; the API "
                        "stays up (its status is marked stale); Ctrl-C stops",
                        flight.exitcode,
                    )
                    await stopper
            if not flight_link.done():
                await client.request(ShutdownRequest())
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(LANDING_TIMEOUT_S + 10.0):
                        await flight_link
            stopper.cancel()
            if world_link is not None:
                world_link.cancel()
            http.stop()
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(sig)
        await asyncio.to_thread(_stop, flight, 10.0)
        if relay is not None:
            await asyncio.to_thread(_stop, relay[0], 5.0)
            relay[1].close()
        await asyncio.to_thread(_stop, world, 10.0)
        if world_pipe is not None:
            world_pipe.close()
        await client.close()
        if sim_world is not None:
            await sim_world.close()
    if flight_died:
        return 1
    return 0 if flight.exitcode in (0, None) or stop.is_set() else 1


def run_serve(config_path: Path, overrides: Sequence[str]) -> int:
    """Entry point of ``serve`` (the configuration was already validated)."""
    return asyncio.run(serve(Setup(config_path, tuple(overrides))))
