"""The entry points of ``serve``'s child processes, in a module that imports nothing heavy.

A spawned child imports the module of its target before it runs it: were the targets in
``serve.py``, every child would first import what ``serve`` imports for all of them (the
flight process's MPCs and the API: 2.4 s here), the world too. Here each child imports what
it runs, when it runs it (``serve`` starts 0.3 s sooner: each child needs much of it anyway).
"""

from __future__ import annotations

import socket
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

from supervisor.app.children import ignore_ctrl_c

if TYPE_CHECKING:
    from supervisor.app.api_process import ApiStart
    from supervisor.app.config import Config
    from supervisor.app.flight_main import FlightStart
    from supervisor.app.ground_main import GroundStart

LinkSockets = tuple[socket.socket, ...]
SigningKeys = dict[int, bytes] | None


@dataclass(frozen=True)
class Setup:
    """How to rebuild the configuration in a child process."""

    config_path: Path
    overrides: tuple[str, ...]

    def load(self) -> Config:
        from supervisor.app.config import load_config

        return load_config(self.config_path, self.overrides)


def world_main(setup: Setup, ready: Connection, listener: socket.socket) -> None:
    ignore_ctrl_c()
    from supervisor.app.world_process import run_world_process

    run_world_process(setup.load(), ready, listener)


def flight_main(
    setup: Setup, start: FlightStart, world: dict[str, Any] | None, parent: Connection
) -> None:
    ignore_ctrl_c()
    from supervisor.app.flight_main import run_flight_process

    run_flight_process(setup.load(), start, world, parent)


def ground_main(setup: Setup, start: GroundStart, parent: Connection) -> None:
    ignore_ctrl_c()
    from supervisor.app.ground_main import run_ground_process

    run_ground_process(setup.load(), start, parent)


def relay_main(
    setup: Setup,
    world: dict[str, Any] | None,
    link_sockets: LinkSockets,
    signing_keys: SigningKeys,
    parent: Connection,
) -> None:
    ignore_ctrl_c()
    from supervisor.app.relay_main import run_relay_process

    run_relay_process(setup.load(), world, link_sockets, parent, signing_keys)


def api_main(setup: Setup, start: ApiStart, parent: Connection) -> None:
    ignore_ctrl_c()
    from supervisor.app.api_process import run_api_process

    run_api_process(setup.load(), start, parent)
