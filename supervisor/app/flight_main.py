"""The flight process's entry point: connect mocap and both vehicles as configured (or to
the embedded world's addresses), then run ``FlightProcess`` until SIGTERM, a shutdown
request, or the API process going away (each of which lands first)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import socket
import time
from pathlib import Path
from typing import Any

from mocap.client import QtmClient
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
    link_configs_from_config,
)
from supervisor.app.config import Config, host_port
from supervisor.ipc.channel import Channel
from supervisor.logs.logging_setup import queued_logging
from supervisor.mavlink.link import MavlinkLink
from supervisor.runtime.cpu import name_process, raise_priority, single_threaded_blas
from supervisor.runtime.flight_process import FlightProcess, FlightSettings
from supervisor.runtime.tick_driver import TickDriver

log = logging.getLogger(__name__)

OFFBOARD_LOSS_LAND = 4  # COM_OBL_RC_ACT: land when the offboard stream stops


async def fly(
    config: Config,
    commands: Channel,
    urgent: Channel,
    world: dict[str, Any] | None,
    link_sockets: tuple[socket.socket, socket.socket] | None = None,
    relayed: bool = False,
    signing_keys: dict[int, bytes] | None = None,
) -> None:
    """Run the flight process on already opened channels (and the links' sockets, bound by
    ``serve``; ``signing_keys`` by system id, read by ``serve``)."""
    if world is not None:
        qtm_host, qtm_port = host_port(world["qtm"])
        vehicles = [host_port(address) for address in world["vehicles"]]
        ports = world.get("link_ports") or (0, 0)
        link_configs = link_configs_from_config(
            config,
            (vehicles[0], vehicles[1]),
            (ports[0], ports[1]),
            world.get("px4_events"),
            signing_keys,
        )
    else:
        qtm_host, qtm_port = config.mocap.host, config.mocap.port
        link_configs = link_configs_from_config(config, signing_keys=signing_keys)
    sockets = link_sockets or (None, None)
    links = (
        MavlinkLink(link_configs[0], sock=sockets[0]),
        MavlinkLink(link_configs[1], sock=sockets[1]),
    )
    for link in links:
        await link.start()
    try:
        async with QtmClient(qtm_host, qtm_port) as mocap:
            process = FlightProcess(
                FlightSettings(
                    config.mpc.dt_s,
                    config.mocap.phase_lock,
                    config.name,
                    forward_mocap=not relayed,
                    failsafe_parameters={
                        "COM_OF_LOSS_T": config.vehicles.offboard_loss_timeout_s,
                        "COM_OBL_RC_ACT": OFFBOARD_LOSS_LAND,
                    },
                ),
                TickDriver(
                    flight_core_from_config(config, clock=time.perf_counter),
                    fusion_from_config(config),
                    body_names_from_config(config),
                ),
                mocap,
                links,
                Path(config.log.folder),
            )
            loop = asyncio.get_running_loop()
            loop.add_signal_handler(signal.SIGTERM, process.stop)
            loop.add_signal_handler(signal.SIGINT, lambda: None)  # the API process decides
            await process.run(commands, urgent)
    finally:
        for link in links:
            await link.close()


def run_flight_process(
    config: Config,
    commands: socket.socket,
    urgent: socket.socket,
    world: dict[str, Any] | None,
    link_sockets: tuple[socket.socket, socket.socket],
    relayed: bool,
    signing_keys: dict[int, bytes] | None = None,
) -> None:
    """Child-process entry of ``serve`` (``relayed``: the relay process forwards the mocap
    to the vehicles)."""
    single_threaded_blas()
    name_process("uavbar-flight")

    async def main() -> None:
        command_channel = await Channel.open(commands)
        urgent_channel = await Channel.open(urgent)
        try:
            await fly(
                config, command_channel, urgent_channel, world, link_sockets, relayed, signing_keys
            )
        finally:
            for channel in (command_channel, urgent_channel):
                with contextlib.suppress(Exception):
                    await channel.close()

    with queued_logging():
        log.info("flight process: %s", raise_priority())
        asyncio.run(main())
