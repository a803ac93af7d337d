"""The fleet's one status from its agents' reports (pure): what the ground station sends
the API in place of a flight process's.

Every agent runs the whole tick core, so each report holds the whole formation; the status
is the report of the agent whose mode is the least safe (airborne before armed before on
the ground, then the lowest vehicle), so that it never says a safer state than a vehicle
is in. Each vehicle's own entry (link, arming) is its own agent's, which owns that link."""

from __future__ import annotations

from supervisor.agents.messages import AgentReport
from supervisor.flight.modes import Mode
from supervisor.flight.status import AgentStatus, FlightStatus, RecentNotice


def _risk(mode: Mode) -> int:
    """How far from safe on the ground a mode is: airborne 2, armed on the ground 1."""
    if mode.airborne:
        return 2
    return 0 if mode is Mode.DISARMED else 1


def merged_status(
    fresh: dict[int, AgentReport], agents: list[AgentStatus], now_s: float
) -> FlightStatus | None:
    """The status from the ``fresh`` reports by vehicle (None: no agent heard lately, so
    nothing is said rather than something old); ``agents`` as the ground station sees
    them; ``now_s`` the ground station's clock."""
    if not fresh:
        return None
    base_vehicle = max(fresh, key=lambda i: (_risk(fresh[i].status.mode), -i))
    base = fresh[base_vehicle].status
    uavs = list(base.uavs)
    armed = list(base.armed)
    for i, report in fresh.items():
        uavs[i - 1] = report.status.uavs[i - 1]
        armed[i - 1] = report.status.armed[i - 1]
    newest: dict[str, RecentNotice] = {}
    for report in fresh.values():
        for notice in report.status.notices:
            kept = newest.get(notice.message)
            if kept is None or notice.age_s < kept.age_s:
                newest[notice.message] = notice
    notices = sorted(newest.values(), key=lambda n: -n.age_s)
    return base.model_copy(
        update={
            "time_s": now_s,
            "uavs": uavs,
            "armed": armed,
            "notices": notices,
            "agents": agents,
        }
    )
