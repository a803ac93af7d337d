"""One tick as data, the same in the service and in the fast simulator.

``decide``: the fused rigid bodies at ``now_s`` → ``estimate_state`` → ``FlightCore.tick``;
the caller then sends the commands (MAVLink) or applies them (the plant); ``finish``: the
tick's record goes to the flight log and the live Foxglove view, and the MPC prepares the
next tick's model while no frame waits. Which clock ``now_s`` comes from is the caller's:
the wall clock in the flight process, simulated time in ``supervisor.simulate``.
"""

from __future__ import annotations

from typing import Any

from mocap.fusion import MocapFusion
from supervisor.flight.core import FlightCore, TickResult
from supervisor.flight.estimation import BodyNames, Estimate, estimate_state
from supervisor.logs.flight_log import FlightLogSink
from supervisor.logs.foxglove_live import FoxgloveLiveView


class TickDriver:
    """Estimation, the tick core and the flight log of one flight, tick by tick."""

    def __init__(self, core: FlightCore, fusion: MocapFusion, names: BodyNames) -> None:
        self.core = core
        self.fusion = fusion
        self.names = names
        self.log: FlightLogSink | None = None
        self.live: FoxgloveLiveView | None = None
        self.estimate: Estimate | None = None

    def estimate_at(self, now_s: float) -> Estimate:
        """The state from what the fusion knows at ``now_s`` (kept as ``estimate``)."""
        self.estimate = estimate_state(self.fusion.states(now_s), self.names)
        return self.estimate

    def decide(
        self,
        now_s: float,
        links_connected: tuple[bool, ...] | None = None,
        lateness_s: float = 0.0,
    ) -> TickResult:
        """This tick's commands, from the estimate at ``now_s`` (``links_connected``: each
        vehicle's link, None: all up). Frames fused after it are
        refused when they repeat themselves while the bodies fly
        (``FlightCore.bodies_in_motion``)."""
        result = self.core.tick(now_s, self.estimate_at(now_s), links_connected, lateness_s)
        self.fusion.refuse_repeats = self.core.bodies_in_motion
        return result

    def finish(self, result: TickResult, **extra: Any) -> None:
        """Log the tick (with the caller's ``extra`` figures), stream it to the live view,
        and prepare the next one."""
        notices = tuple(str(notice) for notice in result.notices)
        if self.log is not None or self.live is not None:
            result.record.extra.update(extra)
        if self.log is not None:
            self.log.append(result.record, notices)
        if self.live is not None:
            self.live.append(result.record, notices)
        self.core.prepare_next()
