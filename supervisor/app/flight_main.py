"""The flight process's entry point: connect mocap and every vehicle as configured (or to
the embedded world's addresses), then run ``FlightProcess`` until SIGTERM or ``serve``
going away (each of which lands first). A restarted flight process says why it was
restarted (a notice) and flies nothing until the operator arms it again."""

from __future__ import annotations

import asyncio
import logging
import signal
import socket
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
    link_configs_from_config,
    qtm_client_from_config,
)
from supervisor.app.config import Config, host_port
from supervisor.flight.core import Notice, NoticeKind
from supervisor.logs.foxglove_live import FoxgloveLiveView
from supervisor.logs.logging_setup import queued_logging
from supervisor.logs.view_seal import view_keys
from supervisor.mavlink.link import MavlinkLink
from supervisor.runtime.cpu import raise_priority, single_threaded_blas, title_process
from supervisor.runtime.flight_process import FlightProcess, FlightSettings
from supervisor.runtime.tick_driver import TickDriver

log = logging.getLogger(__name__)

OFFBOARD_LOSS_LAND = 4  # COM_OBL_RC_ACT: land when the offboard stream stops


@dataclass(frozen=True)
class FlightStart:
    """What ``serve`` hands a flight process: the socket it accepts operators on and the
    token they present, the links' sockets, whether the relay forwards the mocap, and why
    this process was started again (None: the first start)."""

    listener: socket.socket
    token: str
    link_sockets: tuple[socket.socket, ...]
    relayed: bool
    restarted_because: str | None = None
    signing_keys: dict[int, bytes] | None = None  # by system id, read by serve


async def fly(
    config: Config, start: FlightStart, world: dict[str, Any] | None, parent: Connection
) -> None:
    """Run the flight process until SIGTERM or until ``parent`` closes its end."""
    if world is not None:
        vehicles = [host_port(address) for address in world["vehicles"]]
        ports = world.get("link_ports") or [0] * len(vehicles)
        link_configs = link_configs_from_config(
            config, vehicles, ports, world.get("px4_events"), start.signing_keys
        )
    else:
        link_configs = link_configs_from_config(config, signing_keys=start.signing_keys)
    sockets = start.link_sockets
    links = tuple(
        MavlinkLink(link_config, sock=sock)
        for link_config, sock in zip(link_configs, sockets, strict=True)
    )
    for link in links:
        await link.start()
    try:
        async with qtm_client_from_config(config, world) as mocap:
            process = FlightProcess(
                FlightSettings(
                    config.mpc.dt_s,
                    config.mocap.phase_lock,
                    config.name,
                    forward_mocap=not start.relayed,
                    log_format=config.log.format,
                    failsafe_parameters={
                        "COM_OF_LOSS_T": config.vehicles.offboard_loss_timeout_s,
                        "COM_OBL_RC_ACT": OFFBOARD_LOSS_LAND,
                    },
                    min_free_log_mb=config.log.min_free_mb,
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
            if start.restarted_because is not None:
                text = f"{start.restarted_because}; started again, flying nothing until armed"
                process.core.notices.append((process.clock(), Notice(NoticeKind.PROCESS, text)))
            loop = asyncio.get_running_loop()
            loop.add_signal_handler(signal.SIGTERM, process.stop)
            loop.add_signal_handler(signal.SIGINT, lambda: None)  # serve decides
            loop.add_reader(parent.fileno(), process.stop)  # serve is gone
            process.driver.live = _live_view(config, start.token)
            # Real-time only now that the MPC is built: seconds of set-up at SCHED_FIFO
            # would hold a core from everything below it, another serve's world included.
            log.info("flight process: %s", raise_priority())
            try:
                await process.run(start.listener, start.token)
            finally:
                if process.driver.live is not None:
                    process.driver.live.close()
    finally:
        for link in links:
            await link.close()


def _live_view(config: Config, token: str) -> FoxgloveLiveView | None:
    """The Foxglove view's server, on a free loopback port, its messages sealed with the API
    ``token``'s keys (clients come through the API process's gateway on ``foxglove.port``,
    which opens them: api/foxglove_gateway.py), unless off or no port is free (a view is
    never worth a flight: the flight process goes on without it)."""
    if not config.foxglove.enabled:
        return None
    try:
        attachments_m = config.system.to_params().payload.attachments_m
        view = FoxgloveLiveView("127.0.0.1", 0, attachments_m, view_keys(token))
    except RuntimeError as error:
        log.warning("Foxglove view off: cannot serve on loopback (%s)", error)
        return None
    log.info("Foxglove view's server: ws://127.0.0.1:%d (foxglove.sdk.v1, sealed)", view.port)
    return view


def run_flight_process(
    config: Config, start: FlightStart, world: dict[str, Any] | None, parent: Connection
) -> None:
    """Child-process entry of ``serve``."""
    single_threaded_blas()
    title_process("flight")
    with queued_logging():
        asyncio.run(fly(config, start, world, parent))
