"""The agents' ground station: what ``serve`` runs in place of the flight process when
``agents.enabled`` (docs/agents.md). It flies nothing: it hands each operator request to
every agent over Zenoh and answers with theirs, and sends the API the fleet's status made
of the agents' reports (``status_merge``), with ``status.agents``. Its liveliness token
tells the agents it is there; without it they hold, then land."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable

import zenoh
from pydantic import ValidationError

from supervisor.agents import keys
from supervisor.agents.messages import AgentAnswer, AgentCommand, AgentReport, Ping
from supervisor.agents.status_merge import merged_status
from supervisor.flight.operator_requests import Outcome, Reply, Request
from supervisor.flight.status import AgentStatus, FlightStatus

log = logging.getLogger(__name__)

PING_PERIOD_S = 1.0
PING_TIMEOUT_S = 1.0


def combined_reply(vehicles: tuple[int, ...], answers: dict[int, AgentAnswer]) -> Reply:
    """One reply for the operator from every agent's: ok when all are (the first one's
    data), else each that is not, by vehicle (an agent that did not answer: unavailable)."""
    missing = [i for i in vehicles if i not in answers]
    if missing:
        who = ", ".join(f"vehicle {i}'s agent" for i in missing)
        return Reply(outcome=Outcome.UNAVAILABLE, reason=f"{who} did not answer")
    not_ok = [(i, answers[i].reply) for i in vehicles if not answers[i].reply.ok]
    if not not_ok:
        return answers[vehicles[0]].reply
    reason = "; ".join(f"vehicle {i}: {reply.reason}" for i, reply in not_ok)
    return Reply(outcome=not_ok[0][1].outcome, reason=reason, data=not_ok[0][1].data)


class GroundStation:
    """The ground station of ``vehicles``' agents in ``fleet`` on ``session``."""

    def __init__(
        self,
        session: zenoh.Session,
        fleet: str,
        vehicles: tuple[int, ...],
        token: str,
        peer_timeout_s: float,
        command_timeout_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.session = session
        self.fleet = fleet
        self.vehicles = vehicles
        self._token = token
        self.peer_timeout_s = peer_timeout_s
        self.command_timeout_s = command_timeout_s
        self._clock = clock
        self._reports: dict[int, tuple[AgentReport, float]] = {}
        self._alive: set[int] = set()
        self._latency_ms: dict[int, float] = {}
        self._declared: list[object] = []

    def start(self) -> None:
        fleet = self.fleet
        liveliness = self.session.liveliness()
        self._declared += [
            self.session.declare_subscriber(keys.all_reports_key(fleet), self._on_report),
            liveliness.declare_subscriber(keys.all_alive_key(fleet), self._on_alive, history=True),
            liveliness.declare_token(keys.ground_alive_key(fleet)),
        ]

    def close(self) -> None:
        for entity in reversed(self._declared):
            entity.undeclare()  # type: ignore[attr-defined]
        self._declared.clear()

    def _on_report(self, sample: zenoh.Sample) -> None:
        try:
            report = AgentReport.model_validate_json(sample.payload.to_bytes())
        except ValidationError:
            log.warning("a report that does not fit the schema on %s: ignored", sample.key_expr)
            return
        if report.vehicle == keys.vehicle_of(str(sample.key_expr)):
            self._reports[report.vehicle] = (report, self._clock())

    def _on_alive(self, sample: zenoh.Sample) -> None:
        vehicle = keys.vehicle_of(str(sample.key_expr))
        if vehicle is None:
            return
        if sample.kind == zenoh.SampleKind.PUT:
            self._alive.add(vehicle)
            log.info("agent %d joined", vehicle)
        else:
            self._alive.discard(vehicle)
            log.warning("agent %d lost (its liveliness token is gone)", vehicle)

    # ---- requests ---------------------------------------------------------------------------
    def _ask(self, vehicle: int, payload: str) -> AgentAnswer | None:
        """Agent ``vehicle``'s answer to a command (blocking; None: no answer in time)."""
        replies = self.session.get(
            keys.command_key(self.fleet, vehicle), payload=payload, timeout=self.command_timeout_s
        )
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return AgentAnswer.model_validate_json(reply.ok.payload.to_bytes())
            except ValidationError:
                log.warning("agent %d answered off the schema", vehicle)
        return None

    async def handle(self, request: Request) -> Reply:
        """Hand ``request`` to every agent at once; their combined reply."""
        payload = AgentCommand(token=self._token, request=request).model_dump_json()
        results = await asyncio.gather(
            *(asyncio.to_thread(self._ask, i, payload) for i in self.vehicles)
        )
        answers = {i: a for i, a in zip(self.vehicles, results, strict=True) if a is not None}
        for i, answer in answers.items():
            if answer.status is not None:
                previous = self._reports.get(i)
                if previous is not None:
                    report = previous[0].model_copy(update={"status": answer.status})
                    self._reports[i] = (report, self._clock())
        reply = combined_reply(self.vehicles, answers)
        log.info("%s: %s %s", request.kind, reply.outcome.value, reply.reason)
        return reply

    # ---- the status -----------------------------------------------------------------------
    def _ping(self, vehicle: int) -> float:
        """One round trip to agent ``vehicle`` [ms] (nan: no answer)."""
        started = time.perf_counter()
        replies = self.session.get(
            keys.command_key(self.fleet, vehicle),
            payload=Ping().model_dump_json(),
            timeout=PING_TIMEOUT_S,
        )
        for reply in replies:
            if reply.ok is not None:
                return (time.perf_counter() - started) * 1e3
        return math.nan

    async def keep_pinging(self) -> None:
        """Each agent's round trip, every ``PING_PERIOD_S``, for ``status.agents``."""
        while True:
            for i in self.vehicles:
                self._latency_ms[i] = await asyncio.to_thread(self._ping, i)
            await asyncio.sleep(PING_PERIOD_S)

    def agents(self) -> list[AgentStatus]:
        now = self._clock()
        listed = []
        for i in self.vehicles:
            heard = self._reports.get(i)
            age = now - heard[1] if heard is not None else None
            report = heard[0] if heard is not None else None
            listed.append(
                AgentStatus(
                    vehicle=i,
                    alive=i in self._alive and age is not None and age <= self.peer_timeout_s,
                    host=report.host if report is not None else "",
                    pid=report.pid if report is not None else None,
                    mode=report.status.mode if report is not None else None,
                    link_latency_ms=self._latency_ms.get(i, math.nan),
                    last_message_age_s=age,
                )
            )
        return listed

    def telemetry(self) -> FlightStatus | None:
        """The fleet's status now (None: no agent heard lately)."""
        now = self._clock()
        fresh = {
            i: report
            for i, (report, at) in self._reports.items()
            if now - at <= self.peer_timeout_s
        }
        return merged_status(fresh, self.agents(), now)
