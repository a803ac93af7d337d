"""An agent's Zenoh side: its liveliness token, its tick and report publishers, its peers'
ticks and tokens and the ground station's token as they arrive, and the queryable the
ground station's commands come through (docs/agents.md).

Zenoh calls back on its own threads: what arrives is stored by one assignment, or handed
to the agent's event loop (a command), never acted on there."""

from __future__ import annotations

import asyncio
import hmac
import logging
import math
import os
import socket
import time
from collections.abc import Awaitable, Callable

import numpy as np
import zenoh
from pydantic import ValidationError

from geometry.arrays import FloatArray
from supervisor.agents import keys
from supervisor.agents.liveness import GroundWatch
from supervisor.agents.messages import (
    AgentAnswer,
    AgentCommand,
    AgentReport,
    AgentTick,
    Ping,
    Pong,
    VehicleReport,
)
from supervisor.agents.peer_vehicle import PeerVehicle
from supervisor.flight.modes import Mode
from supervisor.flight.operator_requests import Outcome, Reply, Request
from supervisor.flight.status import FlightStatus
from supervisor.vehicles.types import VehicleView

log = logging.getLogger(__name__)

CommandHandler = Callable[[Request], Awaitable[Reply]]


def vehicle_report(view: VehicleView) -> VehicleReport:
    """A link's view as the agent's ticks carry it."""
    battery = view.battery_v if math.isfinite(view.battery_v) else None
    return VehicleReport(
        connected=view.connected,
        armed=view.armed,
        px4_mode=view.px4_mode,
        battery_v=battery,
        status_text=view.status_text,
    )


class AgentNode:
    """Agent ``vehicle`` of ``fleet`` on ``session``; ``peers`` are the others' vehicles as
    this agent sees them. Commands need ``token``; ``share_plans`` says whether its ticks
    carry its plan."""

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        vehicle: int,
        peers: dict[int, PeerVehicle],
        token: str,
        share_plans: bool,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.session = session
        self.fleet = fleet
        self.vehicle = vehicle
        self.peers = peers
        self._token = token.encode()
        self.share_plans = share_plans
        self._clock = clock
        self._ground_alive = False
        self.ground = GroundWatch()
        self._handle: CommandHandler | None = None
        self._status: Callable[[], FlightStatus] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._declared: list[object] = []
        self._tick_publisher = session.declare_publisher(
            keys.tick_key(fleet, vehicle), congestion_control=zenoh.CongestionControl.DROP
        )
        self._report_publisher = session.declare_publisher(
            keys.report_key(fleet, vehicle), congestion_control=zenoh.CongestionControl.DROP
        )
        self._ticks_sent = 0
        self.host = socket.gethostname()

    def start(
        self,
        loop: asyncio.AbstractEventLoop,
        handle: CommandHandler,
        status: Callable[[], FlightStatus],
    ) -> None:
        """Take commands (each handled on ``loop`` by ``handle``, answered with
        ``status()`` after it), hear peers and the ground station, and show itself alive."""
        self._loop, self._handle, self._status = loop, handle, status
        fleet = self.fleet
        liveliness = self.session.liveliness()
        self._declared += [
            self.session.declare_subscriber(keys.all_ticks_key(fleet), self._on_tick),
            liveliness.declare_subscriber(keys.all_alive_key(fleet), self._on_alive, history=True),
            self.session.declare_queryable(keys.command_key(fleet, self.vehicle), self._on_query),
            liveliness.declare_token(keys.agent_alive_key(fleet, self.vehicle)),
        ]

    def close(self) -> None:
        for entity in reversed(self._declared):
            entity.undeclare()  # type: ignore[attr-defined]
        self._declared.clear()
        self._tick_publisher.undeclare()  # type: ignore[no-untyped-call]
        self._report_publisher.undeclare()  # type: ignore[no-untyped-call]

    # ---- what arrives ---------------------------------------------------------------------
    def _on_tick(self, sample: zenoh.Sample) -> None:
        vehicle = keys.vehicle_of(str(sample.key_expr))
        peer = self.peers.get(vehicle) if vehicle is not None else None
        if peer is None:
            return  # its own, or no vehicle of this fleet
        try:
            tick = AgentTick.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            log.warning("agent %s sent a tick that does not fit the schema: ignored", vehicle)
            return
        if tick.vehicle == vehicle:
            peer.observe(tick)

    def _on_alive(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        alive = sample.kind == zenoh.SampleKind.PUT
        if key == keys.ground_alive_key(self.fleet):
            self._ground_alive = alive
            log.log(
                logging.INFO if alive else logging.WARNING,
                "ground station %s",
                "heard" if alive else "lost",
            )
            return
        vehicle = keys.vehicle_of(key)
        peer = self.peers.get(vehicle) if vehicle is not None else None
        if peer is not None and not alive:
            peer.token_lost()
            log.warning("agent %d lost (its liveliness token is gone)", vehicle)

    def _on_query(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        try:
            Ping.model_validate_json(payload)
        except ValidationError:
            pass
        else:
            query.reply(query.key_expr, Pong(vehicle=self.vehicle).model_dump_json())
            return
        try:
            command = AgentCommand.model_validate_json(payload)
        except ValidationError as error:
            reply = Reply(outcome=Outcome.INVALID, reason=f"not a command: {error}")
            self._answer(query, reply, None)
            return
        if not hmac.compare_digest(command.token.encode(), self._token):
            log.warning("a command without the ground station's token: refused")
            self._answer(query, Reply(outcome=Outcome.REFUSED, reason="wrong token"), None)
            return
        assert self._loop is not None
        asyncio.run_coroutine_threadsafe(self._run(query, command.request), self._loop)

    async def _run(self, query: zenoh.Query, request: Request) -> None:
        assert self._handle is not None and self._status is not None
        try:
            reply = await self._handle(request)
        except Exception as error:  # a bad request must not take the agent down
            reply = Reply(outcome=Outcome.INVALID, reason=f"request failed: {error!r}")
        self._answer(query, reply, self._status())

    def _answer(self, query: zenoh.Query, reply: Reply, status: FlightStatus | None) -> None:
        answer = AgentAnswer(vehicle=self.vehicle, reply=reply, status=status)
        try:
            query.reply(query.key_expr, answer.model_dump_json())
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    # ---- what it says ---------------------------------------------------------------------
    def watch_ground(self, now_s: float) -> GroundWatch:
        """The ground watch brought to ``now_s``."""
        self.ground = self.ground.heard(self._ground_alive, now_s)
        return self.ground

    def publish_tick(
        self,
        mode: Mode,
        own: VehicleView,
        bar_end_m: FloatArray | None,
        plan_u: FloatArray,
        setpoints: tuple[int, int],
    ) -> None:
        """This tick's message to peers and the ground station; ``setpoints``: how many it
        was given and how many it has ended."""
        end = [float(v) for v in bar_end_m] if bar_end_m is not None else None
        if end is not None and not all(math.isfinite(v) for v in end):
            end = None
        rows = plan_u.tolist() if self.share_plans and np.all(np.isfinite(plan_u)) else []
        tick = AgentTick(
            vehicle=self.vehicle,
            sent_s=time.time(),
            tick=self._ticks_sent,
            mode=mode,
            own=vehicle_report(own),
            bar_end_m=end,
            plan_u=rows,
            setpoints_queued=setpoints[0],
            setpoints_finished=setpoints[1],
        )
        self._ticks_sent += 1
        self._tick_publisher.put(tick.model_dump_json())

    def publish_report(self, status: FlightStatus) -> None:
        report = AgentReport(
            vehicle=self.vehicle, host=self.host, pid=os.getpid(), sent_s=time.time(), status=status
        )
        self._report_publisher.put(report.model_dump_json())
