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
from typing import Any

from api.app import create_app
from api.server import HttpServer
from supervisor.app.assembly import arena_from_config
from supervisor.app.child_process import stop_event
from supervisor.app.config import Config
from supervisor.ipc.channel import ChannelClosedError, WorldChannel
from supervisor.ipc.client import FlightClient
from supervisor.ipc.rendezvous import Rendezvous
from supervisor.ipc.world_client import WorldClient
from supervisor.logs.logging_setup import configure_logging
from supervisor.runtime.cpu import title_process

log = logging.getLogger(__name__)

# The flight process and the world it flies come first on a busy machine: requests and
# WebSocket clients may wait, ticks and mocap frames may not.
API_NICENESS = 5
READY = "ready"


@dataclass(frozen=True)
class ApiStart:
    """What ``serve`` hands an API process: the bound HTTP socket, where the others
    listen, the token, whether a simulated world runs, and a pipe on which ``serve`` sends
    its process table at every change (and hears ``READY``)."""

    http_socket: socket.socket
    rendezvous: Rendezvous
    token: str
    embedded: bool
    processes: Connection


class ProcessTable:
    """``serve``'s latest process table, as received on its pipe."""

    def __init__(self, pipe: Connection) -> None:
        self._pipe = pipe
        self.table: dict[str, dict[str, Any]] = {}

    def receive(self) -> None:
        try:
            while self._pipe.poll():
                self.table = self._pipe.recv()
        except (EOFError, OSError):  # serve is gone: the lifeline stops this process
            asyncio.get_running_loop().remove_reader(self._pipe.fileno())

    def current(self) -> dict[str, dict[str, Any]]:
        return dict(self.table)


async def _world_client(start: ApiStart) -> WorldClient | None:
    if not start.embedded:
        return None
    try:
        return WorldClient(await WorldChannel.connect(start.rendezvous.world))
    except ChannelClosedError as error:
        log.error("the simulated world cannot be reached: %s", error)
        return WorldClient(None)


async def serve_api(config: Config, start: ApiStart, parent: Connection) -> None:
    """Serve HTTP until SIGTERM or until ``serve`` closes ``parent``."""
    flight = FlightClient(None, None)
    world = await _world_client(start)
    table = ProcessTable(start.processes)
    loop = asyncio.get_running_loop()
    loop.add_reader(start.processes.fileno(), table.receive)
    app = create_app(
        flight,
        config.system.to_params(),
        arena_from_config(config),
        start.token,
        world,
        processes=table.current,
    )
    http = HttpServer(app, start.http_socket)
    async with stop_event(parent) as stop, asyncio.TaskGroup() as group:
        server = group.create_task(http.serve())
        links = [group.create_task(flight.stay_connected(start.rendezvous.flight, start.token))]
        if world is not None:
            links.append(group.create_task(world.run()))
        start.processes.send(READY)
        await stop.wait()
        flight.end_subscriptions()  # the WebSockets close now, not cancelled after a timeout
        http.stop()
        await server
        for task in links:
            task.cancel()
    await flight.close()
    if world is not None:
        await world.close()


def run_api_process(config: Config, start: ApiStart, parent: Connection) -> None:
    """Child-process entry of ``serve``."""
    configure_logging()
    title_process("api")
    os.nice(API_NICENESS)
    asyncio.run(serve_api(config, start, parent))
