"""Safety monitors: pure checks on every tick (time as an argument).

Each monitor reports a ``Fault`` whose ``response`` the flight core carries out; the table
with the reasoning is ``docs/safety.md``. Abort means a coordinated landing of the bar and
both UAVs; the monitors never disarm in the air (kill is the operator's decision).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import Enum

import numpy as np

from controllers.formation_params import FormationParams
from controllers.mpc import PlanStatus
from geometry.frames import rotation_from_euler_zyx
from geometry.state import payload_points, payload_position, payload_yaw
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import Mode
from supervisor.flight.setpoints import Arena


class Response(Enum):
    COAST = "coast"  # keep flying on the prediction / shifted plan, report
    CENTRALIZE = "centralize"  # the decentralized MPC hands the bar to the centralized one
    ABORT = "abort"  # coordinated landing
    LAND_OTHER = "land_other"  # one vehicle lost: the other sets the bar down alone
    PX4_LAND = "px4_land"  # blind: stop streaming, each PX4 lands on its own (AUTO.LAND)


# When monitors disagree the most severe response wins, as in PX4's failsafe framework,
# which takes the most severe of the actions its checks ask for. Blind beats abort: an
# abort flown on a frozen estimate is a blind command.
SEVERITY = {
    Response.COAST: 0,
    Response.CENTRALIZE: 1,
    Response.ABORT: 2,
    Response.LAND_OTHER: 3,
    Response.PX4_LAND: 4,
}


@dataclass(frozen=True)
class Fault:
    """A detected problem: which monitor, what it saw, and what is done about it."""

    monitor: str
    message: str
    response: Response


@dataclass(frozen=True)
class SafetyLimits:
    """Thresholds of the monitors (see docs/safety.md for the reasoning)."""

    mocap_coast_s: float = 0.1
    max_tilt_rad: float = math.radians(45.0)
    max_consecutive_fallbacks: int = 10
    slack_margin_m: float = 0.05
    slack_time_s: float = 0.5  # one slack episode this long: abort
    slack_window_s: float = 10.0  # ... or this much slack, added up, within this window
    slack_in_window_s: float = 0.5
    max_bar_yaw_error_rad: float = math.radians(20.0)  # 0: no hand-over
    max_refused_poses: int = 10  # a body's poses refused in a row: blind (10 = 0.1 s at 100 Hz)


def chosen_response(faults: list[Fault]) -> Response | None:
    """The one response to this tick's faults (None: no fault)."""
    return max((f.response for f in faults), key=SEVERITY.__getitem__, default=None)


class SafetyMonitor:
    """Runs every monitor on a tick; keeps the little state some of them need."""

    def __init__(
        self, params: FormationParams, arena: Arena, limits: SafetyLimits = SafetyLimits()
    ) -> None:
        self.params = params
        self._layout = params.layout
        self.arena = arena
        self.limits = limits
        self._fallbacks = 0
        self._slack_since_s: float | None = None
        self._slack_ticks: deque[tuple[float, float]] = deque()  # (time, slack time) in window
        self._slack_in_window_s = 0.0
        self._last_slack_check_s: float | None = None

    def check(
        self,
        now_s: float,
        estimate: Estimate,
        mode: Mode,
        plan_status: PlanStatus | None,
        links_connected: tuple[bool, ...],
        bar_yaw_reference_rad: float | None = None,
    ) -> list[Fault]:
        """All faults seen on this tick (empty when everything is fine); the bar's yaw is
        checked against ``bar_yaw_reference_rad`` when the tick had a reference."""
        if not mode.airborne:
            self._fallbacks = 0
            self._forget_slack()
            return []
        faults: list[Fault] = []
        lim = self.limits
        if estimate.unhealthy:
            response = Response.PX4_LAND if estimate.age_s > lim.mocap_coast_s else Response.COAST
            faults.append(
                Fault(
                    "mocap",
                    f"{', '.join(estimate.unhealthy)} stale or untracked"
                    f" ({estimate.age_s * 1e3:.0f} ms)",
                    response,
                )
            )
        for refused in estimate.refused:
            if refused.in_a_row >= lim.max_refused_poses:
                # The mocap says what no rigid body can do (or repeats itself): what the
                # supervisor would fly is the coasting estimate of a source it cannot trust.
                faults.append(
                    Fault(
                        "mocap",
                        f"{refused.body}: {refused.in_a_row} poses in a row refused"
                        f" ({refused.why})",
                        Response.PX4_LAND,
                    )
                )
        if not np.all(np.isfinite(estimate.x)) and estimate.age_s <= lim.mocap_coast_s:
            faults.append(Fault("numeric", "NaN or inf in the estimated state", Response.ABORT))
        lost = [i for i, connected in enumerate(links_connected, start=1) if not connected]
        if len(lost) == 1:
            faults.append(Fault("link", f"vehicle {lost[0]} link lost", Response.LAND_OTHER))
        elif lost:  # too few left to hold the payload: every PX4 lands on its own
            which = (
                "both vehicle links"
                if len(lost) == len(links_connected) == 2
                else "vehicle links " + ", ".join(map(str, lost))
            )
            faults.append(Fault("link", f"{which} lost", Response.PX4_LAND))
        x = estimate.x
        if np.all(np.isfinite(x)):
            self._geofence(x, faults)
            self._tilt(x, faults)
            self._slack(now_s, x, mode, faults)
            if bar_yaw_reference_rad is not None:
                self._swing(x, mode, bar_yaw_reference_rad, faults)
        if plan_status is not None:
            self._fallbacks = self._fallbacks + 1 if plan_status.is_fallback else 0
            if self._fallbacks >= lim.max_consecutive_fallbacks:
                faults.append(
                    Fault("solver", f"{self._fallbacks} consecutive fallback plans", Response.ABORT)
                )
        return faults

    def _geofence(self, x: np.ndarray, faults: list[Fault]) -> None:
        bodies = [("bar", payload_position(x))]
        bodies += [(f"UAV {i}", self._layout.uav_position(x, i)) for i in self._layout.vehicles]
        for name, position in bodies:
            if not self.arena.contains(position, margin_m=0.0):
                faults.append(Fault("geofence", f"{name} left the arena", Response.ABORT))

    def _tilt(self, x: np.ndarray, faults: list[Fault]) -> None:
        for i in self._layout.vehicles:
            z_axis_z = float(rotation_from_euler_zyx(*self._layout.uav_euler(x, i))[2, 2])
            tilt = math.acos(max(-1.0, min(1.0, z_axis_z)))
            if tilt > self.limits.max_tilt_rad:
                faults.append(
                    Fault("tilt", f"UAV {i} tilted {math.degrees(tilt):.0f}°", Response.ABORT)
                )

    def _forget_slack(self) -> None:
        self._slack_since_s = None
        self._slack_ticks.clear()
        self._slack_in_window_s = 0.0
        self._last_slack_check_s = None

    def _slack(self, now_s: float, x: np.ndarray, mode: Mode, faults: list[Fault]) -> None:
        """A cable much shorter than its length means the bar is not hanging: abort after
        one episode of ``slack_time_s``, or when episodes add up to ``slack_in_window_s``
        within the last ``slack_window_s`` (short ones, repeated, never reach the first)."""
        if mode not in (Mode.HOVER, Mode.TRACKING):
            self._forget_slack()
            return
        lim = self.limits
        # A slack tick adds the time since the previous check (a slack seen on n ticks
        # lasted n ticks, give or take one), capped so that a stalled loop does not count
        # its stall as slack.
        since = 0.0 if self._last_slack_check_s is None else now_s - self._last_slack_check_s
        self._last_slack_check_s = now_s
        ends = payload_points(x, self.params.payload.attachments_m)
        slack = [
            i
            for i in self._layout.vehicles
            if np.linalg.norm(self._layout.uav_position(x, i) - ends[i - 1])
            < self.params.cable_lengths_m[i - 1] - lim.slack_margin_m
        ]
        while self._slack_ticks and self._slack_ticks[0][0] <= now_s - lim.slack_window_s:
            self._slack_in_window_s -= self._slack_ticks.popleft()[1]
        if not self._slack_ticks:
            self._slack_in_window_s = 0.0  # no rounding left over from the running sum
        if not slack:
            self._slack_since_s = None
            return
        added = min(max(since, 0.0), 2.0 * lim.mocap_coast_s)
        self._slack_ticks.append((now_s, added))
        self._slack_in_window_s += added
        cables = " and ".join(f"cable {i}" for i in slack)
        self._slack_since_s = now_s if self._slack_since_s is None else self._slack_since_s
        if now_s - self._slack_since_s >= lim.slack_time_s:
            faults.append(
                Fault(
                    "slack",
                    f"{cables} slack for {now_s - self._slack_since_s:.2f} s",
                    Response.ABORT,
                )
            )
        elif self._slack_in_window_s >= lim.slack_in_window_s - 1e-9:
            faults.append(
                Fault(
                    "slack",
                    f"cables slack {self._slack_in_window_s:.2f} s in all within the last "
                    f"{lim.slack_window_s:.0f} s ({cables} now)",
                    Response.ABORT,
                )
            )

    def _swing(self, x: np.ndarray, mode: Mode, reference_rad: float, faults: list[Fault]) -> None:
        """The bar turned far from its reference while the MPC holds or tracks it: the
        decentralized MPC lets the bar's yaw swing grow (docs/safety.md)."""
        limit = self.limits.max_bar_yaw_error_rad
        if limit <= 0.0 or mode not in (Mode.HOVER, Mode.TRACKING):
            return
        error = math.remainder(payload_yaw(x) - reference_rad, math.tau)
        if abs(error) > limit:
            faults.append(
                Fault(
                    "swing",
                    f"bar yaw {math.degrees(error):+.1f}° off its reference",
                    Response.CENTRALIZE,
                )
            )
