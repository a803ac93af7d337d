"""``uavbar-supervisor agent --vehicle I``: one vehicle's agent, for its companion computer
or a ground computer of its own (docs/agents.md).

It owns its vehicle's MAVLink link, its own QTM client, its decentralized MPC (its
vehicle's problem alone) and a whole tick core — modes, phases, safety monitors — fed the
same operator requests as its peers by the ground station over Zenoh. Its peers' vehicles
are what their agents report (``supervisor.agents.peer_vehicle``); without its ground
station it holds, then lands (``supervisor.agents.liveness``)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from controllers.mpc import agent_state
from geometry.state import P_P
from supervisor.agents.agent_node import AgentNode
from supervisor.agents.fleet_security import FleetSecurity, agent_identity
from supervisor.agents.liveness import GroundAction, behind_the_peers
from supervisor.agents.peer_vehicle import PeerPlans, PeerVehicle
from supervisor.agents.zenoh_session import open_session
from supervisor.app.assembly import (
    body_names_from_config,
    flight_core_from_config,
    fusion_from_config,
    link_configs_from_config,
    qtm_client_from_config,
)
from supervisor.app.config import AgentsSection, Config
from supervisor.app.flight_main import OFFBOARD_LOSS_LAND
from supervisor.flight.core import Notice, NoticeKind, TickResult
from supervisor.flight.modes import Event, Mode
from supervisor.logs.logging_setup import queued_logging
from supervisor.mavlink.link import MavlinkLink
from supervisor.runtime.cpu import raise_priority, single_threaded_blas, title_process
from supervisor.runtime.flight_process import FlightProcess, FlightSettings
from supervisor.runtime.operator_front import TELEMETRY_PERIOD_S
from supervisor.runtime.scheduler import DeadlineTicker
from supervisor.runtime.tick_driver import TickDriver

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AgentStart:
    """Which vehicle, where this agent listens and whom it joins (Zenoh endpoints), and the
    token the ground station's commands carry."""

    vehicle: int
    listen: tuple[str, ...]
    connect: tuple[str, ...]
    token: str


class AgentTicks:
    """What the agent does after each tick: tell its peers, and watch its ground station."""

    def __init__(self, config: Config, node: AgentNode, process: FlightProcess) -> None:
        self._params = config.system.to_params()
        self._hold_s = config.agents.ground_loss_hold_s
        self._node = node
        self._process = process
        self._held = False
        self._inputs = self._params.layout.uav_input_slice(node.vehicle)

    def after_tick(self, result: TickResult) -> dict[str, float]:
        """Tell the peers, watch the ground station; the tick's figures for the log: the
        newest one-way latency of the peers' ticks [ms]."""
        process, node = self._process, self._node
        vehicle = node.vehicle
        estimate = process.driver.estimate
        end = agent_state(estimate.x, self._params, vehicle)[P_P] if estimate is not None else None
        plan = result.plan
        plan_u = plan.u_pred[:, self._inputs] if plan is not None else np.empty((0, 4))
        queue = process.core.queue
        setpoints = (queue.queued_total, queue.finished)
        node.publish_tick(result.mode, process.links[vehicle - 1].view(), end, plan_u, setpoints)
        self._keep_to_the_peers_setpoint()
        self._watch_ground(result.mode)
        latencies = [peer.new_latency_ms() for peer in node.peers.values()]
        heard = [latency for latency in latencies if math.isfinite(latency)]
        return {"peer_latency_ms": max(heard, default=math.nan)}

    def _keep_to_the_peers_setpoint(self) -> None:
        queue = self._process.core.queue
        peers = (peer.latest() for peer in self._node.peers.values())
        if behind_the_peers(queue.queued_total, queue.finished, peers):
            queue.finish_active()

    def _watch_ground(self, mode: Mode) -> None:
        core, now = self._process.core, self._process.clock()
        action = self._node.watch_ground(now).action(now, self._hold_s)
        if action is GroundAction.FLY:
            self._held = False
            return
        if not mode.airborne or mode in (Mode.LANDING, Mode.ABORT, Mode.PX4_LANDING):
            return
        if action is GroundAction.HOLD and not self._held:
            self._held = True
            core.queue.drop_queued()
            text = (
                f"ground station lost: holding the last setpoint {self._hold_s:g} s, then landing"
            )
            self._notice(text)
        elif action is GroundAction.LAND:
            transition = core.request(Event.LAND, now)
            if transition.accepted:
                self._notice(f"ground station lost for {self._hold_s:g} s: landing the payload")

    def _notice(self, text: str) -> None:
        """Said in the status (once the ground station hears it again) and in the log."""
        log.warning("%s", text)
        self._process.core.notices.append((self._process.clock(), Notice(NoticeKind.GROUND, text)))


async def _report(node: AgentNode, process: FlightProcess) -> None:
    """The agent's status to its ground station, every ``TELEMETRY_PERIOD_S``."""
    ticker = DeadlineTicker(TELEMETRY_PERIOD_S, clock=process.clock)
    try:
        async for _ in ticker:
            node.publish_report(process.telemetry())
    finally:
        ticker.close()


async def run_agent(config: Config, start: AgentStart) -> None:
    """Fly vehicle ``start.vehicle``'s part until SIGTERM or SIGINT (each lands first)."""
    vehicle = start.vehicle
    agents = config.agents
    vehicles = config.system.to_params().layout.vehicles
    security = agents.security(agent_identity(vehicle), len(vehicles))  # its files, first
    link = MavlinkLink(link_configs_from_config(config)[vehicle - 1])
    await link.start()
    peers = {
        j: PeerVehicle(j, agents.peer_timeout_s, agents.command_timeout_s / 2)
        for j in vehicles
        if j != vehicle
    }
    plans = PeerPlans(peers, agents.share_plans)
    core = flight_core_from_config(
        config, clock=time.perf_counter, agent=vehicle, peer_inputs=plans
    )
    try:
        async with qtm_client_from_config(config, None) as mocap:
            links = tuple(link if j == vehicle else peers[j] for j in vehicles)
            settings = FlightSettings(
                config.mpc.dt_s,
                config.mocap.phase_lock,
                f"{config.name} (agent {vehicle})",
                forward_mocap=True,
                log_format=config.log.format,
                failsafe_parameters={
                    "COM_OF_LOSS_T": config.vehicles.offboard_loss_timeout_s,
                    "COM_OBL_RC_ACT": OFFBOARD_LOSS_LAND,
                },
                min_free_log_mb=config.log.min_free_mb,
                own_vehicles=(vehicle,),
            )
            driver = TickDriver(core, fusion_from_config(config), body_names_from_config(config))
            folder = Path(config.log.folder) / f"agent{vehicle}"
            process = FlightProcess(settings, driver, mocap, links, folder)
            # Real-time from here, set-up done; Zenoh's threads, started next, inherit it:
            # a peer's ticks and the ground's keep-alives are as punctual as the ticks.
            log.info("agent %d: %s", vehicle, raise_priority())
            with _zenoh_node(start, security, agents, peers) as node:
                process.on_tick = AgentTicks(config, node, process).after_tick
                loop = asyncio.get_running_loop()
                node.start(loop, process.handle, process.telemetry)
                for sig in (signal.SIGTERM, signal.SIGINT):
                    loop.add_signal_handler(sig, process.stop)
                reporter = asyncio.create_task(_report(node, process))
                try:
                    await process.run(None, start.token)
                finally:
                    reporter.cancel()
    finally:
        await link.close()


@contextlib.contextmanager
def _zenoh_node(
    start: AgentStart,
    security: FleetSecurity | None,
    agents: AgentsSection,
    peers: dict[int, PeerVehicle],
) -> Iterator[AgentNode]:
    """The agent's Zenoh session and side, closed on the way out."""
    session = open_session(start.listen, start.connect, security)
    node = AgentNode(session, agents.fleet, start.vehicle, peers, start.token, agents.share_plans)
    try:
        yield node
    finally:
        node.close()
        try:
            session.close()  # type: ignore[no-untyped-call]
        except zenoh.ZError as error:  # a link cut off: its close waits on nobody
            log.warning("Zenoh session not closed cleanly: %s", error)


def run_agent_process(config: Config, start: AgentStart) -> int:
    """Entry point of ``uavbar-supervisor agent``."""
    single_threaded_blas()
    title_process(f"agent{start.vehicle}")
    with queued_logging():
        asyncio.run(run_agent(config, start))
    return 0
