"""The ground station's process (``serve`` with ``agents.enabled``): the operators'
connections on the flight socket, the agents over Zenoh. On SIGTERM or ``serve`` going
away it lands the agents first, as the flight process would."""

from __future__ import annotations

import asyncio
import logging
import signal
import socket
from dataclasses import dataclass
from multiprocessing.connection import Connection

from supervisor.agents.fleet_security import GROUND
from supervisor.agents.ground import GroundStation
from supervisor.agents.zenoh_session import open_session
from supervisor.app.config import Config
from supervisor.flight.operator_requests import ModeRequest
from supervisor.logs.logging_setup import queued_logging
from supervisor.runtime.cpu import raise_priority, title_process
from supervisor.runtime.flight_process import LANDING_TIMEOUT_S
from supervisor.runtime.operator_front import OperatorFront

log = logging.getLogger(__name__)

LANDED_POLL_S = 0.1
GROUND_PRIORITY = 8  # SCHED_FIFO: below the agents' and a flight process's 10


@dataclass(frozen=True)
class GroundStart:
    """What ``serve`` hands the ground station: the operators' socket and token, and the
    Zenoh endpoint the agents join."""

    listener: socket.socket
    token: str
    endpoint: str


async def _land_agents(station: GroundStation) -> None:
    """Land the fleet if it is airborne and wait (at most ``LANDING_TIMEOUT_S``)."""
    status = station.telemetry()
    if status is None or not status.mode.airborne:
        return
    log.info("stopping: landing the agents first (the fleet is in %s)", status.mode.value)
    await station.handle(ModeRequest(kind="land"))
    for _ in range(round(LANDING_TIMEOUT_S / LANDED_POLL_S)):
        status = station.telemetry()
        if status is None or not status.mode.airborne:
            return
        await asyncio.sleep(LANDED_POLL_S)
    log.error("the agents are not on the ground after %.0f s", LANDING_TIMEOUT_S)


async def run_ground(config: Config, start: GroundStart, parent: Connection) -> None:
    agents = config.agents
    # Real-time below the agents, before Zenoh's threads start (they inherit it): a ground
    # station starved of the CPU for a lease (1 s) would be lost to its agents, who land.
    log.info("ground station: %s", raise_priority(GROUND_PRIORITY))
    security = agents.security(GROUND, config.system.n_vehicles)
    session = open_session([start.endpoint], [], security)
    station = GroundStation(
        session,
        agents.fleet,
        tuple(config.system.to_params().layout.vehicles),
        start.token,
        agents.peer_timeout_s,
        agents.command_timeout_s,
    )
    station.start()
    front = OperatorFront(start.token, station.handle, station.telemetry)
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    loop.add_signal_handler(signal.SIGINT, lambda: None)  # serve decides
    loop.add_reader(parent.fileno(), stop.set)  # serve is gone
    log.info("ground station: agents join at %s", start.endpoint)
    pinger = asyncio.create_task(station.keep_pinging())
    await front.start(start.listener)
    try:
        await stop.wait()
        await _land_agents(station)
    finally:
        pinger.cancel()
        await front.close()
        station.close()
        session.close()  # type: ignore[no-untyped-call]


def run_ground_process(config: Config, start: GroundStart, parent: Connection) -> None:
    """Child-process entry of ``serve``."""
    title_process("ground")
    with queued_logging():
        asyncio.run(run_ground(config, start, parent))
