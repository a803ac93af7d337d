"""What only the simulator can see about a flight: cable tension and slack while the
payload hangs, and the UAVs' worst tilt. The closed-loop simulator and the real-time world
keep the same figures, so that a flight on real PX4 is judged like a ``simulate`` run."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sim.plant import Plant

HANGING_CLEARANCE_M = 0.05
DESCENT_FLOOR_M = 0.2  # descents count above this height (bodies' centres)
BODIES = ("bar", "uav1", "uav2")


@dataclass
class TruthStats:
    """Slack and tension count while the payload hangs: in an airborne mode with the
    payload more than ``HANGING_CLEARANCE_M`` above its resting height ``bar_rest_z_m`` (so
    touch-down and the first centimetres of lift-off, where the ground carries it, are not
    counted as slack). The descent rate counts in an airborne mode, for every body above
    ``DESCENT_FLOOR_M``. ``bodies`` are the plant's, the payload first, then the UAVs (the
    bar's two by default)."""

    bar_rest_z_m: float
    bodies: tuple[str, ...] = BODIES
    slack_events: int = 0
    max_tilt_deg: float = 0.0
    min_tension_n: float = math.inf
    min_tension_airborne_n: float = math.inf
    hanging_s: float = 0.0
    max_descent_mps: float = 0.0
    descent_by_body_mps: dict[str, float] = field(init=False)
    """The fastest descent of each body (``max_descent_mps`` is the fastest of them): after
    a lost link, the lost UAV comes down with its PX4's failsafe, the others with the MPC."""
    _slack: tuple[bool, ...] = field(init=False)
    _last_hanging_s: float | None = None

    def __post_init__(self) -> None:
        self.descent_by_body_mps = dict.fromkeys(self.bodies, 0.0)
        self._slack = (False,) * (len(self.bodies) - 1)

    def update(self, plant: Plant, airborne: bool) -> None:
        """Account for the plant's state now; ``airborne`` is the flight mode's view."""
        cables = plant.cables()
        self.min_tension_n = min(self.min_tension_n, *cables.tension_n)
        bodies = {name: plant.body(name) for name in self.bodies}
        if airborne:
            for name, body in bodies.items():
                if body.position_m[2] > DESCENT_FLOOR_M:
                    descent = max(self.descent_by_body_mps[name], -float(body.velocity_mps[2]))
                    self.descent_by_body_mps[name] = descent
                    self.max_descent_mps = max(self.max_descent_mps, descent)
        payload = self.bodies[0]
        hanging = bodies[payload].position_m[2] > self.bar_rest_z_m + HANGING_CLEARANCE_M
        if not airborne or not hanging:
            self._slack = cables.slack
            self._last_hanging_s = None
            return
        if self._last_hanging_s is not None:
            self.hanging_s += plant.time_s - self._last_hanging_s
        self._last_hanging_s = plant.time_s
        self.min_tension_airborne_n = min(self.min_tension_airborne_n, *cables.tension_n)
        self.slack_events += sum(
            1 for now, before in zip(cables.slack, self._slack, strict=True) if now and not before
        )
        self._slack = cables.slack
        for name in self.bodies[1:]:
            z_axis_z = float(bodies[name].rotation[2, 2])
            tilt = math.degrees(math.acos(max(-1.0, min(1.0, z_axis_z))))
            self.max_tilt_deg = max(self.max_tilt_deg, tilt)

    def describe(self, title: str = "truth") -> str:
        """One line for the world's log (``benchmarks.tick`` reads it back), after
        ``title``: the whole run's figures are the ``truth``, one flight's the ``truth of
        flight K``."""
        payload = self.bodies[0]
        if self.hanging_s == 0.0:
            return f"{title}: the {payload} has not hung yet"
        return (
            f"{title}: {payload} hanging {self.hanging_s:.1f} s, min cable tension "
            f"{self.min_tension_airborne_n:.2f} N, slack events {self.slack_events}, "
            f"max UAV tilt {self.max_tilt_deg:.1f} deg, "
            f"max descent {self.max_descent_mps:.2f} m/s above {DESCENT_FLOOR_M} m ("
            + ", ".join(f"{name} {v:.2f}" for name, v in self.descent_by_body_mps.items())
            + ")"
        )


class FlightTruths:
    """The truth of each flight on its own (a run's ``TruthStats`` keeps the worst of
    all its flights): a flight starts when any UAV rises above ``DESCENT_FLOOR_M`` and
    ends once every UAV is below it again. A test of one flight's fault response reads
    that flight's figures, untouched by the flights before it."""

    def __init__(self, payload_rest_z_m: float, bodies: tuple[str, ...] = BODIES) -> None:
        self._payload_rest_z_m = payload_rest_z_m
        self._bodies = bodies
        self.flights_ended = 0
        self.current: TruthStats | None = None

    def update(self, plant: Plant) -> str | None:
        """Account for the plant's state now; the line of the flight that just ended."""
        up = any(plant.body(name).position_m[2] > DESCENT_FLOOR_M for name in self._bodies[1:])
        if self.current is None and up:
            self.current = TruthStats(self._payload_rest_z_m, self._bodies)
        if self.current is None:
            return None
        self.current.update(plant, airborne=True)
        if up:
            return None
        ended, self.current = self.current, None
        self.flights_ended += 1
        return ended.describe(f"truth of flight {self.flights_ended}")
