"""The API process: FastAPI under uvicorn on the socket ``serve`` bound, talking to the
flight process and the simulated world over their listening sockets
(``supervisor.ipc.rendezvous``). ``serve`` restarts it when it dies: the listening socket
stays ``serve``'s, so requests made meanwhile wait in its backlog instead of failing."""

from __future__ import annotations

import asyncio
import logging
import os
import socket
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

from api.app import create_app
from api.foxglove_gateway import FoxgloveGateway
from api.guard import HttpPolicy, http_policy
from api.server import HttpServer, TlsFiles
from supervisor.app.child_process import stop_event
from supervisor.app.config import Config
from supervisor.flight.setpoints import Arena
from supervisor.flight.status import ProcessStatus
from supervisor.ipc.channel import ChannelClosedError, WorldChannel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.rendezvous import Rendezvous
from supervisor.ipc.world_client import WorldClient
from supervisor.logs.logging_setup import configure_logging
from supervisor.runtime.cpu import can_raise_priority, title_process

log = logging.getLogger(__name__)

# The flight process and the world it flies come first on a busy machine: requests and
# WebSocket clients may wait, ticks and mocap frames may not. Where they run at real-time
# priority (or a lower niceness) they come first anyway, and a niced API would only make
# an abort wait for whatever else the machine runs: then the API is not niced.
API_NICENESS = 5
GO = "go"  # serve → API process: start serving (a spare waits for it)
READY = "ready"  # API process → serve: serving


@dataclass(frozen=True)
class ApiStart:
    """What ``serve`` hands an API process: the bound HTTP socket, where the others
    listen, the token, whether a simulated world runs, and a pipe on which ``serve`` sends
    its process table at every change (after ``GO``) and hears ``READY``."""

    http_socket: socket.socket
    rendezvous: Rendezvous
    token: str
    embedded: bool
    processes: Connection


class ProcessTable:
    """What ``serve`` says on the pipe: ``GO`` (``go`` is set), then its latest process
    table."""

    def __init__(self, pipe: Connection) -> None:
        self._pipe = pipe
        self.table: dict[str, ProcessStatus] = {}
        self.go = asyncio.Event()

    def receive(self) -> None:
        try:
            while self._pipe.poll():
                message = self._pipe.recv()
                if message == GO:
                    self.go.set()
                else:
                    self.table = message
        except (EOFError, OSError):  # serve is gone: the lifeline stops this process
            asyncio.get_running_loop().remove_reader(self._pipe.fileno())

    def current(self) -> dict[str, ProcessStatus]:
        return dict(self.table)


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


async def _world_client(start: ApiStart) -> WorldClient | None:
    if not start.embedded:
        return None
    try:
        return WorldClient(await WorldChannel.connect(start.rendezvous.world))
    except ChannelClosedError as error:
        log.error("the simulated world cannot be reached: %s", error)
        return WorldClient(None)


async def serve_api(config: Config, start: ApiStart, parent: Connection) -> None:
    """Wait for ``GO``, then serve HTTP until SIGTERM or until ``serve`` closes ``parent``."""
    table = ProcessTable(start.processes)
    loop = asyncio.get_running_loop()
    loop.add_reader(start.processes.fileno(), table.receive)
    async with stop_event(parent) as stop:
        told = asyncio.create_task(table.go.wait())
        stopped = asyncio.create_task(stop.wait())
        await asyncio.wait({told, stopped}, return_when=asyncio.FIRST_COMPLETED)
        told.cancel()
        stopped.cancel()
        if not stop.is_set():
            title_process("api")
            await _serve(config, start, table, stop)


async def _serve(config: Config, start: ApiStart, table: ProcessTable, stop: asyncio.Event) -> None:
    flight = FlightClient(None, None)
    world = await _world_client(start)
    app = create_app(
        flight,
        config.system.to_params(),
        Arena.between(config.arena.min_m, config.arena.max_m),  # not assembly: no plant
        config.setpoint_bounds(),
        api_policy(config, start.token),
        world,
        processes=table.current,
    )
    http = HttpServer(app, start.http_socket, api_tls(config))
    gateway = await _foxglove_gateway(config, flight, start.token)
    async with asyncio.TaskGroup() as group:
        server = group.create_task(http.serve())
        links = [group.create_task(flight.stay_connected(start.rendezvous.flight, start.token))]
        if world is not None:
            links.append(group.create_task(world.run()))
            links.append(group.create_task(world.keep_watch()))
        start.processes.send(READY)
        await stop.wait()
        flight.end_subscriptions()  # the WebSockets close now, not cancelled after a timeout
        http.stop()
        await server
        for task in links:
            task.cancel()
    if gateway is not None:
        await gateway.close()
    await flight.close()
    if world is not None:
        await world.close()


async def _foxglove_gateway(
    config: Config, flight: FlightClient, token: str
) -> FoxgloveGateway | None:
    """The live Foxglove view's public port (``FoxgloveSection``) for clients with the API
    ``token``, unless off or taken (the API serves on without it, and says so)."""
    if not config.foxglove.enabled:
        return None
    host, port = config.foxglove.bind_host(config.api.host), config.foxglove.port

    def sdk_port() -> int | None:
        view = flight.latest.live_view if flight.latest is not None else None
        return view.sdk_port if view is not None else None

    gateway = FoxgloveGateway(sdk_port, api_policy(config, token))
    try:
        await gateway.start(host, port)
    except OSError as error:
        log.warning("Foxglove view off: cannot serve on %s:%d (%s)", host, port, error)
        return None
    log.info(
        "Foxglove view: ws://%s:%d (foxglove.websocket.v1 or foxglove.sdk.v1; the API token in "
        "the URL: /?token=TOKEN)",
        host,
        gateway.port,
    )
    return gateway


def run_api_process(config: Config, start: ApiStart, parent: Connection) -> None:
    """Child-process entry of ``serve``."""
    configure_logging()
    title_process("spare")  # until told GO (ps: uavbar-supervisor spare)
    if not can_raise_priority():
        os.nice(API_NICENESS)
    asyncio.run(serve_api(config, start, parent))
