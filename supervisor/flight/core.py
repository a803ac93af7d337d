"""The synchronous tick core: estimation → mode logic → controller → safety → commands.

No I/O and no clock of its own: the asyncio service calls ``tick`` on the wall clock, the
fast simulator calls the very same object against the physics plant. Operator requests
(``request``, ``set_controller``, ``queue_setpoints``) are applied between ticks.

Inside the modes (``supervisor.flight.modes``) the core moves through flight phases
(``supervisor.flight.phases``). What a safety monitor forced is kept as a ``Notice``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from controllers.delay import DelayPredictor
from controllers.force_observer import ForceObserver
from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams
from controllers.integral_action import ReferenceIntegrator
from controllers.mpc import CentralizedMpc, DecentralizedMpc, PeerInputs, Plan
from controllers.params import Clock, MpcSettings
from controllers.preview import Preview, moved_like, sampled_stages
from controllers.rate_filter import RateCrossover, RateFilter
from controllers.uav_pd import UavPdGains, uav_pd_control
from geometry.arrays import FloatArray
from geometry.frames import rotation_from_euler_zyx
from geometry.state import (
    W_I,
    payload_points,
    payload_position,
    payload_velocity,
    payload_yaw,
    stacked_agent_slice,
)
from supervisor.flight.estimation import Estimate
from supervisor.flight.feasibility import FeasibilitySettings, SetpointBounds, theta_l_problem
from supervisor.flight.modes import Event, FlightModes, Mode, Transition
from supervisor.flight.path_timing import PathError, PathLimits
from supervisor.flight.paths import PathPlan, PathRunner, path_problem, plan_path
from supervisor.flight.phases import Phase, next_phase
from supervisor.flight.preflight import resting_limits, resting_pose_problems, takeoff_problem
from supervisor.flight.reference_shaping import RateLimits, ReferenceShaper
from supervisor.flight.refusals import Request, refusal
from supervisor.flight.safety import Fault, Response, SafetyLimits, SafetyMonitor, chosen_response
from supervisor.flight.set_down import SetDownProfile, SetDownView
from supervisor.flight.setpoints import (
    Arena,
    Setpoint,
    SetpointError,
    SetpointQueue,
    SetpointRefusedError,
    arena_problem,
    validate_setpoints,
)
from supervisor.flight.tick_record import TickRecord
from supervisor.flight.waypoint import Waypoint
from supervisor.vehicles.types import UavCommand

CONTROLLERS = ("centralized", "decentralized")
MOVING_SLOWER = 4.0
"""How much slower the force observer learns while the reference moves."""
# The modes in which setpoints are taken: armed (flown after the take-off) up to tracking.
# Disarmed, landing, aborting, blind or killed, a setpoint is refused rather than kept to
# fly on the next take-off; entering any of those modes empties the queue.
TAKES_SETPOINTS = frozenset({Mode.ARMED, Mode.TAKEOFF, Mode.HOVER, Mode.TRACKING})
NOTICES_KEPT = 20
GROUND_CLEARANCE_M = 0.05  # the bar this far above its resting height hangs clear of the ground


@dataclass(frozen=True)
class CoreSettings:
    """Flight-phase parameters (SI units)."""

    takeoff_height_m: float = 1.0
    reached_position_m: float = 0.05
    reached_yaw_rad: float = math.radians(3.0)
    flight_rates: RateLimits = field(default_factory=RateLimits)
    takeoff_rates: RateLimits = field(
        default_factory=lambda: RateLimits(position_mps=0.25, acceleration_mps2=0.15)
    )
    abort_rates: RateLimits = field(default_factory=lambda: RateLimits(position_mps=0.4))
    descend_speed_mps: float = 0.3
    settle_on_ground_s: float = 1.0
    landing_clearance_m: float = 0.3
    bumpless_ticks: int = 15
    rate_lookahead_steps: int = 3
    acceleration_feed_forward: bool = True
    preview: bool = True
    path_jerk_mps3: float = 2.0
    pd_gains: UavPdGains = field(default_factory=UavPdGains)
    feasibility: FeasibilitySettings = field(default_factory=FeasibilitySettings)


class NoticeKind(StrEnum):
    ABORT = "abort"  # the monitors started a coordinated landing
    LAND_OTHER = "land_other"  # a vehicle was lost: the other sets the bar down alone
    SWING = "swing"  # the decentralized MPC handed the bar to the centralized one
    VEHICLE = "vehicle"  # a vehicle refused what the supervisor asked (its own reason)
    BLIND = "blind"  # the mocap was lost: the vehicles were handed to PX4's own landing
    PROCESS = "process"  # serve restarted the flight process (it had died)
    LOG = "log"  # the flight log stopped by itself (a write error); the flight goes on
    GROUND = "ground"  # an agent lost its ground station: it holds, then lands


@dataclass(frozen=True)
class Notice:
    """A decision the safety monitors forced, in words an operator reads."""

    kind: NoticeKind
    text: str

    def __str__(self) -> str:
        return f"{self.kind.value}: {self.text}"


@dataclass(frozen=True)
class TickResult:
    """Everything one tick decided: ``events`` moved the mode, ``notices`` are what the
    safety monitors forced."""

    commands: tuple[UavCommand, ...]
    """One per UAV, UAV 1's first."""
    mode: Mode
    phase: Phase
    plan: Plan | None
    reference: FormationReference | None
    faults: list[Fault]
    record: TickRecord
    events: list[Event] = field(default_factory=list)
    notices: list[Notice] = field(default_factory=list)
    commanded: tuple[bool, ...] = (True, True)
    """Which vehicles are sent this tick's command (False: left to its PX4's failsafe)."""


class FlightCore:
    """The supervisor's decision-making, one ``tick`` per control period. ``clock`` times
    the tick's compute and the MPC's solves (``controllers.params.Clock``)."""

    def __init__(
        self,
        params: FormationParams,
        mpc_settings: dict[str, MpcSettings],
        arena: Arena,
        controller: str = "centralized",
        settings: CoreSettings | None = None,
        safety: SafetyLimits | None = None,
        *,
        clock: Clock,
        agent: int | None = None,
        peer_inputs: PeerInputs | None = None,
    ) -> None:
        if controller not in CONTROLLERS:
            raise ValueError(f"controller must be one of {CONTROLLERS}")
        if agent is not None and controller != "decentralized":
            raise ValueError("an agent flies its own vehicle: the decentralized MPC only")
        self.params = params
        self._layout = params.layout
        self.settings = settings or CoreSettings()
        self.arena = arena
        self.agent = agent
        """The vehicle whose agent this core is (None: it flies every vehicle): its MPC
        solves that vehicle's problem alone, the others' plans are their agents'
        (``peer_inputs``)."""
        decentralized = DecentralizedMpc(
            params,
            mpc_settings["decentralized"],
            clock=clock,
            own=None if agent is None else (agent,),
            peer_inputs=peer_inputs,
        )
        self.controllers: dict[str, CentralizedMpc | DecentralizedMpc] = {
            "decentralized": decentralized
        }
        if agent is None:
            centralized_mpc = CentralizedMpc(params, mpc_settings["centralized"], clock=clock)
            self.controllers["centralized"] = centralized_mpc
        self._clock = clock
        self.controller = controller
        self.modes = FlightModes()
        self.queue = SetpointQueue()
        self.safety = SafetyMonitor(params, arena, safety or SafetyLimits())
        limits = mpc_settings["centralized"].limits
        self.setpoint_bounds = SetpointBounds(
            limits.thrust_min_n,
            limits.thrust_max_n,
            self.safety.limits.max_tilt_rad,
            self.settings.feasibility,
        )
        """What every queued setpoint's equilibrium must respect (``feasibility``)."""
        self.notices: deque[tuple[float, Notice]] = deque(maxlen=NOTICES_KEPT)
        """The latest decisions the safety monitors forced (time, what and why), oldest
        first: what an operator must be told even if no screen was watching."""
        self.phase = Phase.GROUND
        self._limits = mpc_settings["centralized"].limits
        self._shaper: ReferenceShaper | None = None
        self._hold_target: FormationReference | None = None
        self._paths = PathRunner(self.settings.acceleration_feed_forward)
        n = self._layout.n_vehicles
        self._ground_bar_z = 0.0
        self._ground_uav_z = (0.0,) * n
        self._yaw_hold = (0.0,) * n
        self._pd_targets: list[FloatArray] = [np.zeros(3) for _ in range(n)]
        self._last_u = np.zeros(self._layout.n_inputs)
        centralized = mpc_settings["centralized"]
        self._delay = DelayPredictor(params, centralized.delay_s)
        self._rate_filter = RateFilter(self._delay, centralized.rate_filter_weight)
        self._rate_crossover = RateCrossover(self._layout, centralized.rate_crossover_s)
        self._mpc_state: FloatArray | None = None  # the state the last MPC step started from
        self._integral = ReferenceIntegrator(self._layout, centralized.integral_gain_per_s)
        self.force_observer = ForceObserver(
            params, self._delay, centralized.force_observer_s, centralized.force_observer_max_n
        )
        """The external loads both MPCs' equilibria carry (``controllers.force_observer``)."""
        self._blend_from: FloatArray | None = None
        self._blend_tick = 0
        self._last_estimate: Estimate | None = None
        self._mpc_reference: FormationReference | None = None
        self.mpc_was_prepared: bool | None = None
        """Whether this tick's MPC used the model prepared after the last (None: no MPC)."""
        self._last_tick_s: float | None = None
        self._dt_s = 0.0
        self._low_since_s: float | None = None
        self.left_to_px4: int | None = None
        """The vehicle (1 … N) whose link was lost in this flight: it is left to its PX4's
        failsafe for the rest of the flight, even if its link comes back."""
        self._set_down_end = np.zeros(3)  # the connected UAV's bar-end target (set_down)
        self._set_down_yaw = 0.0
        self._set_down_profile: SetDownProfile | None = None

    # ---- operator interface -------------------------------------------------------------
    def request(self, event: Event, now_s: float) -> Transition:
        """An operator request (arm, disarm, takeoff, land, abort, kill)."""
        if event is Event.TAKEOFF and self.modes.mode is Mode.ARMED and not self._mocap_fresh():
            return Transition(
                False,
                self.modes.mode,
                "cannot take off without fresh motion capture of all bodies",
            )
        if event is Event.ARM and self.modes.mode is Mode.DISARMED:
            problems = self.not_ready_to_arm()
            if problems:
                return Transition(False, self.modes.mode, "cannot arm: " + "; ".join(problems))
        before = self.modes.mode
        result = self.modes.handle(event, now_s)
        if not result.accepted:
            return Transition(False, before, refusal(before, Request(event.value)))
        if result.mode is not before:
            self._entered(result.mode, now_s)
        return result

    def not_ready_to_arm(self) -> list[str]:
        """Why the system must not arm (empty: it may): every body measured and fresh, the
        resting pose the take-off starts from, and the hover it goes to
        (``supervisor.flight.preflight``), each with what to do."""
        if not self._mocap_fresh():
            return ["no fresh motion capture of all bodies: check that QTM tracks each body"]
        assert self._last_estimate is not None
        x = self._last_estimate.x
        limits = resting_limits(self.settings.landing_clearance_m)
        problems = resting_pose_problems(x, self.params, limits)
        if not problems:
            height_m = self.settings.takeoff_height_m
            hover = takeoff_problem(x, self.params, height_m, self.arena, self.setpoint_bounds)
            problems += [hover] if hover is not None else []
        return problems

    def _mocap_fresh(self) -> bool:
        """Every body measured, none older than the safety monitor's coasting limit: one
        dropped frame (10 ms) must not refuse a take-off, a lost body must."""
        estimate = self._last_estimate
        return (
            estimate is not None
            and bool(np.all(np.isfinite(estimate.x)))
            and estimate.age_s <= self.safety.limits.mocap_coast_s
        )

    @property
    def bodies_in_motion(self) -> bool:
        """Airborne, and not settling on the ground at the end of a landing: the bodies
        move, so a pose repeated bit for bit is no measurement (a frozen mocap pipeline).
        On the ground a resting system may repeat itself exactly (a noise-free simulator)."""
        mode = self.modes.mode
        return mode.airborne and not (self.phase is Phase.DESCEND and self._low_since_s is not None)

    def set_controller(self, name: str, now_s: float) -> Transition:
        """Switch between the centralized and decentralized MPC, bumplessly in flight."""
        if name not in CONTROLLERS:
            return Transition(
                False, self.modes.mode, f"controller must be one of {', '.join(CONTROLLERS)}"
            )
        if name not in self.controllers:
            return Transition(
                False,
                self.modes.mode,
                "the agents fly one vehicle each: only the decentralized MPC (the centralized "
                "one needs one computer flying all: agents.enabled = false)",
            )
        if name != self.controller:
            self.controllers[name].reset()
            self.controller = name
            if self.modes.mode.airborne:
                self._blend_from = self._last_u.copy()
                self._blend_tick = 0
        return Transition(True, self.modes.mode)

    def start_in_hover(
        self, estimate: Estimate, now_s: float, ground_z_m: tuple[float, ...]
    ) -> None:
        """Begin airborne, hovering where the system is (simulations that start in the air,
        as the paper's Section VII does); ``ground_z_m`` are the heights of the payload's
        and then each UAV's centre when they rest on the ground, which a landing returns to.
        Not an operator request: the mode table has no way from the ground to hover but
        take-off."""
        self.modes = FlightModes(Mode.HOVER)
        self._ground_bar_z = ground_z_m[0]
        self._ground_uav_z = tuple(ground_z_m[1:])
        self._last_estimate = estimate
        self._yaw_hold = self._layout.uav_yaws(estimate.x)
        self._entered(Mode.HOVER, now_s)

    def queue_setpoints(self, setpoints: list[Setpoint]) -> None:
        """Queue setpoints, all or none: only in a mode that flies them (``TAKES_SETPOINTS``,
        else raises ``SetpointRefusedError``), they must fit the queue (raises
        ``SetpointQueueFullError``) and each is validated against the arena and equilibrium
        feasibility, ``setpoint_bounds`` (raises ``SetpointError`` naming which one)."""
        mode = self.modes.mode
        if mode not in TAKES_SETPOINTS:
            raise SetpointRefusedError(refusal(mode, Request.SETPOINT))
        self.queue.check_room(len(setpoints))
        validate_setpoints(setpoints, self.params, self.arena, self.setpoint_bounds)
        self.queue.extend(setpoints)

    def queue_path(
        self,
        waypoints: Sequence[Waypoint],
        speed_mps: float,
        accel_mps2: float,
        jerk_mps3: float | None = None,
        hold_s: float = 0.0,
    ) -> Setpoint:
        """Queue a path through ``waypoints`` after what is queued, timed within the speed,
        acceleration and jerk (default ``settings.path_jerk_mps3``) and the flight rates'
        yaw and θ_l rates: as a setpoint at its end, held ``hold_s`` once reached.
        Refused like a setpoint (raises ``SetpointError``) in a mode that takes none, with a
        full queue, or when any point along its timing cannot be flown; returns what was
        queued."""
        mode = self.modes.mode
        if mode not in TAKES_SETPOINTS:
            raise SetpointRefusedError(refusal(mode, Request.SETPOINT))
        self.queue.check_room(1)
        rates = self.settings.flight_rates
        try:
            limits = PathLimits(
                speed_mps,
                accel_mps2,
                self.settings.path_jerk_mps3 if jerk_mps3 is None else jerk_mps3,
                rates.yaw_radps,
                rates.theta_l_radps,
            )
            plan = plan_path(
                self._queue_end(waypoints[0] if waypoints else None), waypoints, limits
            )
        except PathError as error:
            raise SetpointError(str(error)) from None
        for index, point in enumerate(waypoints):
            steep = theta_l_problem(point.theta_l_rad or 0.0, self.setpoint_bounds)
            if steep is not None:
                raise SetpointError(f"waypoint {index}: {steep}")
        problem = path_problem(plan, self.params, self.setpoint_bounds, self.arena)
        if problem is not None:
            raise SetpointError(problem)
        end = plan.end()
        setpoint = Setpoint(
            end.payload_position_m,
            end.payload_yaw_rad,
            end.uav_yaw_rad,
            end.cone_angle_rad,
            hold_s,
            path=plan,
        )
        self.queue.extend([setpoint])
        return setpoint

    def path_progress(self, now_s: float) -> tuple[PathPlan, float] | None:
        """The path flown now (or last, until the next setpoint starts) and how long since
        it began [s]; None without one."""
        return self._paths.progress(now_s)

    def _queue_end(self, first: Waypoint | None) -> FormationReference:
        """Where the bar will be when a setpoint queued now starts: the last queued one's
        end, else the active one's, else the reference held; on the ground, where the
        take-off will lift it; ``first`` (a path's first waypoint) with nothing measured."""
        n = self._layout.n_vehicles
        last = self.queue.queued[-1] if self.queue.queued else self.queue.active
        if last is not None:
            return last.reference(n)
        if self._hold_target is not None:
            return self._hold_target.at_rest()
        if self._shaper is not None:
            return self._shaper.current.at_rest()
        if self._last_estimate is None:
            position = first.bar_position_m if first is not None else (0.0, 0.0, 0.0)
            return FormationReference(position, 0.0, (0.0,) * n)
        here = self._current_reference(self._last_estimate.x)
        if self.modes.mode not in (Mode.ARMED, Mode.TAKEOFF):
            return here
        x, y, z = here.payload_position_m
        ground_z = z if self.modes.mode is Mode.ARMED else self._ground_bar_z
        return replace(here, payload_position_m=(x, y, ground_z + self.settings.takeoff_height_m))

    def clear_setpoints(self) -> None:
        """Drop the queue and the active setpoint; in flight the bar stops where braking
        from its reference's motion at the flight rates' acceleration (a path's, if it
        flew one) brings it, sooner if that would leave the arena, and holds there."""
        active = self.queue.active
        self.queue.clear()
        if self._shaper is not None and self.modes.mode in (Mode.HOVER, Mode.TRACKING):
            accel = self._shaper.limits.acceleration_mps2
            if active is not None and active.path is not None:
                accel = max(accel, active.path.limits.accel_mps2)
            self._hold_target = self._stop_inside_arena(self._shaper, accel)

    def _stop_inside_arena(self, shaper: ReferenceShaper, accel_mps2: float) -> FormationReference:
        """The shaper's stop braking at ``accel_mps2``, or, where that stop's equilibrium
        leaves the arena, the furthest stop short of it that does not (braking harder);
        the shaper is set to brake so."""
        here = shaper.current.at_rest()
        stop = shaper.stopping_point(accel_mps2)
        offset = np.subtract(stop.payload_position_m, here.payload_position_m)
        fraction = 1.0
        for _ in range(12):
            if fraction < 1e-3:
                fraction = 0.0
                break
            p = np.add(here.payload_position_m, fraction * offset)
            candidate = replace(here, payload_position_m=(float(p[0]), float(p[1]), float(p[2])))
            try:
                eq = formation_equilibrium(self.params, candidate, remember=False)
            except ValueError:
                fraction *= 0.5
                continue
            if arena_problem(eq, self.arena) is None:
                break
            fraction *= 0.5
        p = np.add(here.payload_position_m, fraction * offset)
        stop = replace(here, payload_position_m=(float(p[0]), float(p[1]), float(p[2])))
        if fraction > 0.0:  # else not even here is inside: the reference stops at once
            shaper.brake(accel_mps2 / fraction, stop)
        return stop

    def hand_over_to_px4(self, why: str, now_s: float) -> Notice | None:
        """Airborne, stop commanding: each PX4 lands on its own (the flight process stops
        the stream and sets AUTO.LAND). The notice, or None when already handed over or on
        the ground."""
        mode = self.modes.mode
        if not mode.airborne or mode is Mode.PX4_LANDING:
            return None
        self.modes.handle(Event.BLIND, now_s)
        self._entered(Mode.PX4_LANDING, now_s)
        return Notice(
            NoticeKind.BLIND, f"{why}: no longer streaming, each PX4 lands on its own (AUTO.LAND)"
        )

    def await_vehicles(self, now_s: float) -> None:
        """Begin with the vehicles in PX4's hands (``px4_landing``) until both are heard
        disarmed (``vehicles_landed``): a flight process may start while they fly in their
        failsafe landing (the one before it died), and until a heartbeat says otherwise the
        status must not say they are disarmed on the ground. Only on the ground."""
        if self.modes.mode is Mode.DISARMED:
            self.modes = FlightModes(Mode.PX4_LANDING)
            self.modes.changed_at_s = now_s
            self._entered(Mode.PX4_LANDING, now_s)

    def vehicles_landed(self, now_s: float) -> None:
        """Both PX4s have landed and disarmed on their own: a PX4 landing is over."""
        if self.modes.mode is Mode.PX4_LANDING:
            self.modes.handle(Event.LANDED, now_s)
            self._entered(Mode.DISARMED, now_s)

    def vehicles_disarmed(self, now_s: float) -> None:
        """Every vehicle is heard disarmed after the landing: the system is disarmed."""
        if self.modes.mode is Mode.DISARMING:
            self.modes.handle(Event.DISARMED, now_s)
            self._entered(Mode.DISARMED, now_s)

    # ---- the tick -----------------------------------------------------------------------
    def tick(
        self,
        now_s: float,
        estimate: Estimate,
        links_connected: tuple[bool, ...] | None = None,
        lateness_s: float = 0.0,
    ) -> TickResult:
        """Decide this tick's commands from the estimate at ``now_s`` (``links_connected``:
        each vehicle's link, None: all up)."""
        started = self._clock()
        if links_connected is None:
            links_connected = (True,) * self._layout.n_vehicles
        self._dt_s = 0.0 if self._last_tick_s is None else max(0.0, now_s - self._last_tick_s)
        self._last_tick_s = now_s
        self._last_estimate = estimate
        self._mpc_reference = None
        self.mpc_was_prepared = None
        events: list[Event] = []
        mode = self.modes.mode
        plan: Plan | None = None
        reference: FormationReference | None = None
        if mode in (Mode.DISARMED, Mode.KILLED, Mode.ARMED):
            commands = self._off()
            self._remember_ground(estimate)
        elif mode in (Mode.PX4_LANDING, Mode.DISARMING):  # nothing flies: stop the motors
            commands = self._off()
        elif mode is Mode.TAKEOFF:
            commands, plan, reference = self._takeoff(now_s, estimate, events)
        elif mode in (Mode.HOVER, Mode.TRACKING):
            commands, plan, reference = self._fly(now_s, estimate, events)
        else:
            commands, plan, reference = self._land(now_s, estimate, events)

        faults = self.safety.check(
            now_s,
            estimate,
            self.modes.mode,
            plan.status if plan else None,
            links_connected,
            reference.payload_yaw_rad if reference is not None else None,
        )
        notices = self._respond(faults, links_connected, now_s)
        self.notices.extend((now_s, notice) for notice in notices)
        # A vehicle whose link is lost is left to its own failsafe: it gets no commands.
        commanded = tuple(
            connected and self.left_to_px4 != i
            for i, connected in enumerate(links_connected, start=1)
        )
        commands = tuple(
            command if sent else UavCommand.off()
            for command, sent in zip(commands, commanded, strict=True)
        )
        for event in events:
            before = self.modes.mode
            if self.modes.handle(event, now_s).accepted and self.modes.mode is not before:
                self._entered(self.modes.mode, now_s)
        u = np.array([v for c in commands for v in (c.thrust_n, *c.torque_nm)])
        self._last_u = u
        self._delay.sent(now_s, u)
        state_ref = (
            formation_equilibrium(self.params, reference).x
            if reference is not None
            else np.full(self._layout.n_states, np.nan)
        )
        record = TickRecord(
            t_s=now_s,
            mode=self.modes.mode.value,
            controller=self.controller,
            state=estimate.x.tolist(),
            state_ref=state_ref.tolist(),
            inputs=u.tolist(),
            plan_status=plan.status.value if plan else self.phase,
            solve_ms=plan.solve_time_s * 1e3 if plan else math.nan,
            compute_ms=(self._clock() - started) * 1e3,
            lateness_ms=lateness_s * 1e3,
            mocap_age_ms=estimate.age_s * 1e3,
        )
        return TickResult(
            commands,
            self.modes.mode,
            self.phase,
            plan,
            reference,
            faults,
            record,
            events,
            notices,
            commanded,
        )

    def _respond(
        self, faults: list[Fault], links_connected: tuple[bool, ...], now_s: float
    ) -> list[Notice]:
        """Carry out the one response the faults call for (``chosen_response``)."""
        response = chosen_response(faults)
        centralizable = "centralized" in self.controllers
        if response is Response.CENTRALIZE and self.controller == "decentralized" and centralizable:
            self.set_controller("centralized", now_s)
            swing = next(f for f in faults if f.response is Response.CENTRALIZE)
            return [Notice(NoticeKind.SWING, f"{swing.message}; switched to the centralized MPC")]
        mode = self.modes.mode
        if response is Response.PX4_LAND:
            blind = "; ".join(f.message for f in faults if f.response is Response.PX4_LAND)
            notice = self.hand_over_to_px4(blind, now_s)
            return [notice] if notice is not None else []
        if response is Response.LAND_OTHER and self.left_to_px4 is None:
            lost = links_connected.index(False) + 1
            return self._land_other(lost, now_s)
        airborne = mode.airborne and mode not in (Mode.ABORT, Mode.PX4_LANDING)
        if response is Response.ABORT and airborne:
            self.modes.handle(Event.FAULT, now_s)
            self._entered(Mode.ABORT, now_s)
            return [Notice(NoticeKind.ABORT, "; ".join(f.message for f in faults))]
        return []

    def _land_other(self, lost: int, now_s: float) -> list[Notice]:
        """Vehicle ``lost`` is gone: leave it to its PX4's failsafe landing for the rest of
        the flight and let the others set the payload down (``set_down``: with two UAVs,
        the other lowers its bar end alone), or, when the UAVs fly alone anyway, descend
        with the abort."""
        mode = self.modes.mode
        if not mode.airborne or mode is Mode.PX4_LANDING:
            return []
        self.left_to_px4 = lost
        if mode is not Mode.ABORT:
            self.modes.handle(Event.FAULT, now_s)
            self._entered(Mode.ABORT, now_s)
        others = self._connected_vehicles()
        x = self._last_estimate.x if self._last_estimate is not None else None
        hanging = self.phase in (Phase.LIFT, Phase.HOVER, Phase.TRACKING, Phase.LOWER)
        if len(others) == 1:
            who, what = f"UAV {others[0]}", "sets its bar end down alone"
        else:
            who, what = "UAVs " + ", ".join(map(str, others)), "set the payload down"
        if hanging and x is not None and np.all(np.isfinite(x)):
            self._enter_phase(Phase.SET_DOWN)
            self._set_down_end = self._set_down_point(x)
            self._set_down_yaw = payload_yaw(x)
            self._set_down_profile = SetDownProfile(
                float(self._set_down_end[2]),
                self.settings.abort_rates.position_mps,
                self.settings.abort_rates.acceleration_mps2,
                always_slower=self.agent is not None,
            )
            self._yaw_hold = self._layout.uav_yaws(x)
            self.set_controller("decentralized", now_s)  # each agent models its UAV alone
            action = f"{who} {what}"
        else:
            action = f"{who} descend" if len(others) > 1 else f"{who} descends"
        text = f"vehicle {lost} link lost: {action}; UAV {lost} is left to its PX4 failsafe"
        return [Notice(NoticeKind.LAND_OTHER, text)]

    def _connected_vehicles(self) -> list[int]:
        """The UAVs still flown by the supervisor (all but the one left to its PX4)."""
        return [i for i in self._layout.vehicles if i != self.left_to_px4]

    def _set_down_point(self, x: FloatArray) -> FloatArray:
        """Where the connected UAVs' attachments are, on average [m]: the point the set-down
        lowers (with two UAVs, the other's bar end)."""
        ends = self._attachments(x)
        mean: FloatArray = np.mean([ends[i - 1] for i in self._connected_vehicles()], axis=0)
        return mean

    # ---- phases ---------------------------------------------------------------------------
    def _entered(self, mode: Mode, now_s: float) -> None:
        x = self._last_estimate.x if self._last_estimate is not None else None
        if mode is Mode.TAKEOFF and x is not None and self._last_estimate is not None:
            self._remember_ground(self._last_estimate)
            self._enter_phase(Phase.CLIMB)
            self._set_climb_targets(x)
        elif mode in (Mode.LANDING, Mode.ABORT):
            flying_alone = self.phase in (Phase.CLIMB, Phase.DESCEND)
            self._enter_phase(Phase.DESCEND if flying_alone else Phase.LOWER)
            if self.phase is Phase.DESCEND and x is not None:
                self._set_descend_targets(x)
            self.queue.clear()
            if x is not None:
                self._shaper = self._new_shaper(x, self._rates(mode))
        elif mode is Mode.HOVER:
            self._enter_phase(Phase.HOVER)
            # A hold already chosen (the take-off's height, the queue's end, a cleared
            # queue's stop) stands; else the reference where it is.
            if self._shaper is not None and self._hold_target is None:
                self._hold_target = self._shaper.current
        elif mode is Mode.TRACKING:
            self._enter_phase(Phase.TRACKING)
        elif mode is Mode.PX4_LANDING:
            self._enter_phase(Phase.PX4)
            self.queue.clear()
            self._shaper = None
            self._hold_target = None
        elif mode in (Mode.DISARMED, Mode.DISARMING, Mode.KILLED, Mode.ARMED):
            self._enter_phase(Phase.GROUND)
            if mode is not Mode.ARMED:
                self.queue.clear()
            self._shaper = None
            self._hold_target = None
            self.left_to_px4 = None
            for c in self.controllers.values():
                c.reset()
            self._delay.reset()
            self._rate_filter.reset()
            self._rate_crossover.reset()
            self._integral.reset()
            self.force_observer.reset()

    def _enter_phase(self, phase: Phase) -> None:
        self.phase = next_phase(self.phase, phase)

    def _new_shaper(self, x: FloatArray, limits: RateLimits) -> ReferenceShaper:
        """A reference shaper starting from the formation at ``x``."""
        feed = self.settings.acceleration_feed_forward
        return ReferenceShaper(self._current_reference(x), limits, feed_acceleration=feed)

    def _rates(self, mode: Mode) -> RateLimits:
        if mode is Mode.ABORT:
            return self.settings.abort_rates
        if mode is Mode.TAKEOFF:
            return self.settings.takeoff_rates
        return self.settings.flight_rates

    def _off(self) -> tuple[UavCommand, ...]:
        return tuple(UavCommand.off() for _ in self._layout.vehicles)

    def _attachments(self, x: FloatArray) -> list[FloatArray]:
        """Where the cables are fixed to the payload, e_i [m], cable 1's first."""
        return payload_points(x, self.params.payload.attachments_m)

    def _remember_ground(self, estimate: Estimate) -> None:
        x = estimate.x
        if np.all(np.isfinite(x)):
            self._ground_bar_z = float(payload_position(x)[2])
            self._ground_uav_z = tuple(
                float(self._layout.uav_position(x, i)[2]) for i in self._layout.vehicles
            )
            self._yaw_hold = self._layout.uav_yaws(x)

    def _set_climb_targets(self, x: FloatArray) -> None:
        self._pd_targets = [
            end + np.array([0.0, 0.0, length + 0.02])
            for end, length in zip(self._attachments(x), self.params.cable_lengths_m, strict=True)
        ]

    def _set_descend_targets(self, x: FloatArray) -> None:
        """Each UAV above its cable's attachment moved ``landing_clearance_m`` outward, away
        from the payload's CoM (for the bar: along the bar, beyond its ends)."""
        self._low_since_s = None  # a new descent: not settled yet
        out = self.settings.landing_clearance_m
        centre = payload_position(x)
        self._pd_targets = []
        for i, end in zip(self._layout.vehicles, self._attachments(x), strict=True):
            offset = end - centre
            distance = float(np.linalg.norm(offset))
            outward = offset / distance if distance > 0.0 else np.zeros(3)
            self._pd_targets.append(
                np.array([*(end + out * outward)[0:2], self._layout.uav_position(x, i)[2]])
            )

    def _current_reference(self, x: FloatArray) -> FormationReference:
        p_b = payload_position(x)
        return FormationReference(
            (float(p_b[0]), float(p_b[1]), float(p_b[2])),
            payload_yaw(x),
            self._layout.uav_yaws(x),
            0.0,
        )

    def _pd_commands(self, x: FloatArray, extra_load: tuple[float, ...]) -> tuple[UavCommand, ...]:
        commands = []
        for k, uav in enumerate(self.params.uavs):
            position, velocity, euler, rates_now = self._layout.uav_slices(k + 1)
            thrust, torque, rates = uav_pd_control(
                x[position],
                x[velocity],
                rotation_from_euler_zyx(*x[euler]),
                x[rates_now],
                self._pd_targets[k],
                self._yaw_hold[k],
                uav.mass_kg,
                uav.inertia_kgm2,
                (self._limits.thrust_min_n, self._limits.thrust_max_n, self._limits.torque_max_nm),
                extra_load[k],
                self.settings.pd_gains,
                self.params.gravity_mps2,
            )
            commands.append(UavCommand(thrust, torque, rates, True))
        return tuple(commands)

    def _mpc_commands(self, plan: Plan) -> tuple[UavCommand, ...]:
        u = plan.u.copy()
        if self._blend_from is not None:  # bumpless transfer after a controller switch
            self._blend_tick += 1
            alpha = self._blend_tick / self.settings.bumpless_ticks
            u = (1.0 - alpha) * self._blend_from + alpha * u
            if self._blend_tick >= self.settings.bumpless_ticks:
                self._blend_from = None
        # A rate-controlled PX4 turns a rate error into torque through its rate loop, whose
        # time constant is ~1/K_P (50–70 ms): the MPC's predicted rate that far ahead asks
        # it for about the MPC's own torque; the next step's rate would ask for a third.
        ahead = min(self.settings.rate_lookahead_steps, len(plan.x_pred) - 1)
        next_x = plan.x_pred[ahead]

        layout = self._layout

        def predicted_rates(i: int) -> FloatArray:
            rates: FloatArray = (
                next_x[layout.uav_slices(i)[3]]
                if self.controller == "centralized"
                else next_x[stacked_agent_slice(i)][W_I]
            )
            return rates.copy()

        return tuple(
            UavCommand(
                float(u[layout.thrust_index(i)]),
                u[layout.torque_slice(i)].copy(),
                predicted_rates(i),
                True,
            )
            for i in layout.vehicles
        )

    def _mpc(
        self,
        now_s: float,
        x: FloatArray,
        reference: FormationReference,
        preview: Preview | None = None,
    ) -> tuple[tuple[UavCommand, ...], Plan]:
        controller = self.controllers[self.controller]
        # The estimate is the state the mocap latency ago; the MPC plans from now on.
        if self._model_predicts(x):
            measured_s = now_s - self._delay.delay_s
            corrected = self._rate_crossover.corrected(x, measured_s)
            filtered = self._rate_filter.filtered(corrected, measured_s)
            # In a move it learns four times slower: what the model misses of the
            # transients is no constant load, yet the loads learnt holding change with the
            # geometry (docs/results.md, the force observer's "Slower in moves").
            held = reference == reference.at_rest() and not preview
            forces = self.force_observer.update(
                filtered, measured_s, MOVING_SLOWER if not held else 1.0
            )
            self._mpc_state = self._delay.predict(filtered, now_s)
        else:
            self._rate_filter.reset()
            self._rate_crossover.reset()
            self.force_observer.pause()
            forces = self.force_observer.forces
            self._mpc_state = x
        # Setting the payload down with a UAV lost, the payload's pose is beyond the
        # connected UAVs' reach (the lost end falls): its error is no offset to take out.
        setting_down = self.phase is Phase.SET_DOWN
        shifted = self._integral.shifted(reference, x, now_s, integrating=not setting_down)
        ahead = moved_like(preview, reference, shifted) if preview else None
        plan = controller.step(self._mpc_state, shifted, now_s, ahead, forces)
        self._mpc_reference = shifted
        self.mpc_was_prepared = controller.last_step_was_prepared
        return self._mpc_commands(plan), plan

    def _model_predicts(self, x: FloatArray) -> bool:
        """Whether the model describes what the inputs sent did: the bar hanging clear of
        the ground (the model has no ground contact: a bar still resting on it would be
        predicted falling) and every UAV flown by this core (not one left to its PX4)."""
        hanging = self.phase in (Phase.LIFT, Phase.HOVER, Phase.TRACKING, Phase.LOWER)
        clear = float(payload_position(x)[2]) > self._ground_bar_z + GROUND_CLEARANCE_M
        return hanging and clear and self.left_to_px4 is None

    def prepare_next(self) -> None:
        """Between ticks, once the commands are out: let the MPC that flew this tick
        linearize for the next one (controllers/mpc.py, ``prepare``)."""
        if self._mpc_reference is not None and self._mpc_state is not None:
            controller = self.controllers[self.controller]
            controller.prepare(self._mpc_state, self._mpc_reference)

    def _takeoff(
        self, now_s: float, estimate: Estimate, events: list[Event]
    ) -> tuple[tuple[UavCommand, ...], Plan | None, FormationReference | None]:
        x = estimate.x
        layout = self._layout
        if self.phase is Phase.CLIMB:
            commands = self._pd_commands(x, (0.0,) * layout.n_vehicles)
            ends = self._attachments(x)
            taut = all(
                np.linalg.norm(layout.uav_position(x, i) - ends[i - 1])
                >= self.params.cable_lengths_m[i - 1] - 0.03
                for i in layout.vehicles
            )
            speeds = [np.linalg.norm(layout.uav_velocity(x, i)) for i in layout.vehicles]
            if taut and max(speeds) < 0.3:
                self._enter_phase(Phase.LIFT)
                self._shaper = self._new_shaper(x, self.settings.takeoff_rates)
            return commands, None, None
        assert self._shaper is not None
        p_b = payload_position(x)
        target = FormationReference(
            (float(p_b[0]), float(p_b[1]), self._ground_bar_z + self.settings.takeoff_height_m),
            payload_yaw(x),
            self._yaw_hold,
            0.0,
        )
        if self._hold_target is None:
            self._hold_target = target
        reference = self._shaper.update(self._hold_target, now_s)
        commands, plan = self._mpc(now_s, x, reference)
        if reference == self._hold_target and self._reached(x, reference):
            events.append(Event.AIRBORNE)
        return commands, plan, reference

    def _reached(self, x: FloatArray, reference: FormationReference) -> bool:
        position_error = np.linalg.norm(
            payload_position(x) - np.asarray(reference.payload_position_m)
        )
        yaw_error = abs(math.remainder(payload_yaw(x) - reference.payload_yaw_rad, 2 * math.pi))
        return bool(
            position_error < self.settings.reached_position_m
            and yaw_error < self.settings.reached_yaw_rad
        )

    def _fly(
        self, now_s: float, estimate: Estimate, events: list[Event]
    ) -> tuple[tuple[UavCommand, ...], Plan | None, FormationReference | None]:
        x = estimate.x
        if self._shaper is None:
            self._shaper = self._new_shaper(x, self.settings.flight_rates)
        if self._hold_target is None:
            self._hold_target = self._shaper.current
        target = self._hold_target
        active = self.queue.active
        n = self._layout.n_vehicles
        if active is not None:
            target = active.reference(n)
        reached = (
            self._shaper.current == target
            and self._reached(x, target)
            and not self._paths.flying(active, now_s)
        )
        setpoint = self.queue.update(reached, now_s)
        if setpoint is not None:
            target = setpoint.reference(n)
            if self.modes.mode is Mode.HOVER:
                events.append(Event.TRACK)
        elif self.modes.mode is Mode.TRACKING:
            self._hold_target = target
            events.append(Event.HOLD)
        stages, dt_s = self._horizon()
        along = self._paths.step(setpoint, self._shaper, now_s, stages, dt_s)
        if along is not None:
            reference, preview = along
        else:
            reference = self._shaper.update(target, now_s)
            preview = self._shaper.preview(target, now_s, stages, dt_s)
        commands, plan = self._mpc(now_s, x, reference, preview)
        return commands, plan, reference

    def _horizon(self) -> tuple[tuple[int, ...], float]:
        """The stages ahead at which the MPC is given the reference (none: the preview is
        off), and its step [s]."""
        settings = self.controllers[self.controller].settings
        stages = sampled_stages(settings.horizon) if self.settings.preview else ()
        return stages, settings.dt_s

    def _land(
        self, now_s: float, estimate: Estimate, events: list[Event]
    ) -> tuple[tuple[UavCommand, ...], Plan | None, FormationReference | None]:
        x = estimate.x
        if self.phase is Phase.SET_DOWN:
            return self._set_down(now_s, x)
        if self.phase is Phase.LOWER:
            if self._shaper is None:
                self._shaper = self._new_shaper(x, self._rates(self.modes.mode))
            current = self._shaper.current
            target = FormationReference(
                (current.payload_position_m[0], current.payload_position_m[1], self._ground_bar_z),
                current.payload_yaw_rad,
                current.uav_yaw_rad,
                0.0,
            )
            reference = self._shaper.update(target, now_s)
            commands, plan = self._mpc(now_s, x, reference)
            bar_z, bar_vz = payload_position(x)[2], payload_velocity(x)[2]
            if bar_z < self._ground_bar_z + 0.03 or (reference == target and abs(bar_vz) < 0.05):
                self._enter_phase(Phase.DESCEND)
                self._yaw_hold = self._layout.uav_yaws(x)
                self._set_descend_targets(x)
            return commands, plan, reference
        dt_descend = self.settings.descend_speed_mps * self._dt_s
        for k, ground_z in enumerate(self._ground_uav_z):
            self._pd_targets[k][2] = max(ground_z - 0.05, self._pd_targets[k][2] - dt_descend)
        commands = self._pd_commands(x, (0.0,) * self._layout.n_vehicles)
        # Down once all have stayed at their ground height for a while: velocity
        # estimates are too noisy near zero to decide on one tick. A vehicle left to its
        # PX4 lands on its own.
        low = all(
            self._layout.uav_position(x, i)[2] < self._ground_uav_z[i - 1] + 0.05
            for i in self._layout.vehicles
            if i != self.left_to_px4
        )
        if not low:
            self._low_since_s = None
        elif self._low_since_s is None:
            self._low_since_s = now_s
        settled_since = self._low_since_s
        if settled_since is not None and now_s - settled_since >= self.settings.settle_on_ground_s:
            events.append(Event.LANDED)
            return self._off(), None, None
        return commands, None, None

    def _set_down(
        self, now_s: float, x: FloatArray
    ) -> tuple[tuple[UavCommand, ...], Plan | None, FormationReference | None]:
        """The connected UAVs lower their attachments (with two UAVs, the other's bar end)
        to the ground as ``SetDownProfile`` paces them; their decentralized agents track the
        payload lowered so (with the descent as the reference's velocity, so they do not
        lag), level at the held yaw."""
        assert self.left_to_px4 is not None and self._set_down_profile is not None
        connected = self._connected_vehicles()
        mine = self._set_down_point(x)
        view = SetDownView(
            own_z_m=float(mine[2]),
            lost_z_m=float(self._attachments(x)[self.left_to_px4 - 1][2]),
            lost_uav_descent_mps=-float(self._layout.uav_velocity(x, self.left_to_px4)[2]),
            rest_z_m=self._ground_bar_z,
        )
        self._set_down_end[2], speed = self._set_down_profile.step(view, self._dt_s)
        # The payload level at the held yaw, the connected attachments' mean at the target.
        level = rotation_from_euler_zyx(0.0, 0.0, self._set_down_yaw)
        attachments = self.params.payload.attachments_m
        held = np.mean([attachments[i - 1] for i in connected], axis=0)
        centre = self._set_down_end - level @ held
        reference = FormationReference(
            (float(centre[0]), float(centre[1]), float(centre[2])),
            self._set_down_yaw,
            self._yaw_hold,
            0.0,
            (0.0, 0.0, -speed),
        )
        commands, plan = self._mpc(now_s, x, reference)
        if mine[2] < self._ground_bar_z + 0.03:
            self._enter_phase(Phase.DESCEND)
            self._yaw_hold = self._layout.uav_yaws(x)
            self._set_descend_targets(x)
        return commands, plan, reference
