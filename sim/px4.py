"""The simulated PX4's behaviour, without I/O: modes, arming, offboard rules, failsafes,
and the setpoint paths (docs/reference/px4-offboard.md §2 and §5). Time is an argument.

* Modes are PX4's (main, sub) custom modes; it starts disarmed in POSCTL.
* Offboard: any setpoint counts as proof of life; offboard can be entered when armed only
  while setpoints have arrived at > 2 Hz for > 1 s (else ``TEMPORARILY_REJECTED``, mode
  unchanged); when disarmed it may be selected, but arming in it then needs the stream too.
  Setpoints act only while in OFFBOARD. No setpoint for ``offboard_loss_timeout_s``
  (COM_OF_LOSS_T) in OFFBOARD: failsafe to AUTO.LAND (COM_OBL_RC_ACT = Land, the lab
  setting), with a status text.
* Arming: refused when not on the ground, or (``require_vision``) without fresh external
  vision. Normal disarm only on the ground; force-disarm (param2 21196) at once, anywhere.
  Auto-disarm ``auto_disarm_land_s`` after landing, and after ``auto_disarm_preflight_s``
  armed on the ground without taking off (COM_DISARM_LAND, COM_DISARM_PRFLT).
* Command modes: ``SET_ATTITUDE_TARGET`` type_mask 128 (body rates FRD + normalized
  thrust) through the rate PID; ``SET_ACTUATOR_CONTROL_TARGET`` group 0 (torques in
  [-1, 1] FRD, thrust in [0, 1]). Normalized values scale by this vehicle's calibration
  (``thrust_max_n``, ``torque_max_nm``, ``thrust_scale``), which may differ from the
  supervisor's.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import euler_zyx_from_quaternion, rotation_from_quaternion
from sim.ports import AirframeState
from sim.px4_control import HoldController, RateController

FORCE_MAGIC = 21196


class MainMode(IntEnum):
    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoMode(IntEnum):
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6


class Result(IntEnum):
    """MAV_RESULT."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4


@dataclass(frozen=True)
class Px4Params:
    """Parameters of one simulated vehicle (PX4 parameter names in the comments)."""

    inertia_kgm2: tuple[float, float, float] = (0.0348, 0.0459, 0.0977)
    thrust_max_n: float = 26.0  # thrust at normalized 1.0 (the vehicle's true calibration)
    torque_max_nm: float = 1.0  # torque at normalized ±1.0
    thrust_scale: float = 1.0  # calibration mismatch: true thrust = scale × commanded
    hover_thrust_n: float = 13.2  # MPC_THR_HOVER × max: UAV plus half the bar
    offboard_loss_timeout_s: float = 1.0  # COM_OF_LOSS_T
    proof_of_life_s: float = 1.0
    proof_of_life_rate_hz: float = 2.0
    land_speed_mps: float = 0.5  # MPC_LAND_SPEED
    auto_disarm_land_s: float = 2.0  # COM_DISARM_LAND
    auto_disarm_preflight_s: float = 10.0  # COM_DISARM_PRFLT
    require_vision: bool = False
    vision_timeout_s: float = 0.5


@dataclass(frozen=True)
class Setpoint:
    """The last offboard setpoint: body rates FLU [rad/s] or torque FLU [N m], thrust [N]."""

    kind: str  # "rates" or "actuator"
    thrust_n: float
    vector: FloatArray
    time_s: float


@dataclass
class Px4Model:
    """One vehicle's flight stack state machine."""

    system_id: int
    params: Px4Params = field(default_factory=Px4Params)
    armed: bool = False
    main_mode: MainMode = MainMode.POSCTL
    sub_mode: int = 0
    setpoint: Setpoint | None = None
    last_vision_s: float = -math.inf
    vision_messages: int = 0
    status_texts: deque[tuple[int, str]] = field(default_factory=lambda: deque(maxlen=32))
    _setpoint_times: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    _armed_at_s: float = 0.0
    _took_off: bool = False
    _landed_since_s: float | None = None
    _hold_target: FloatArray | None = None
    _hold_yaw: float = 0.0
    _last_step_s: float | None = None
    rates: RateController = field(init=False)
    hold: HoldController = field(init=False)

    def __post_init__(self) -> None:
        p = self.params
        self.rates = RateController(p.inertia_kgm2, p.torque_max_nm)
        self.hold = HoldController(p.hover_thrust_n)

    # ---- what the heartbeat shows --------------------------------------------------------
    @property
    def custom_mode(self) -> int:
        """PX4's custom_mode: main mode in bits 16–23, sub mode in bits 24–31."""
        return (int(self.main_mode) << 16) | (int(self.sub_mode) << 24)

    @property
    def mode_name(self) -> str:
        if self.main_mode is MainMode.AUTO:
            return f"AUTO.{AutoMode(self.sub_mode).name}" if self.sub_mode else "AUTO"
        return self.main_mode.name

    def _say(self, severity: int, text: str) -> None:
        self.status_texts.append((severity, text))

    # ---- inputs ---------------------------------------------------------------------------
    def _stream_alive(self, now_s: float) -> bool:
        """Setpoints at > rate for > the proof-of-life time, the last one recent."""
        p = self.params
        times = [t for t in self._setpoint_times if now_s - t <= p.proof_of_life_s + 0.5]
        if not times or now_s - times[-1] > 1.0 / p.proof_of_life_rate_hz:
            return False
        if times[-1] - times[0] < p.proof_of_life_s:
            return False
        gaps = np.diff(times)
        return bool(gaps.size and gaps.max() < 1.0 / p.proof_of_life_rate_hz)

    def rate_setpoint(self, rates_frd: FloatArray, thrust: float, now_s: float) -> None:
        """SET_ATTITUDE_TARGET, type_mask 128: body rates (FRD) and thrust in [0, 1]."""
        if not (np.all(np.isfinite(rates_frd)) and math.isfinite(thrust)):
            return  # PX4 ignores non-finite setpoints
        p = self.params
        rates_flu = np.array([rates_frd[0], -rates_frd[1], -rates_frd[2]])
        thrust_n = float(np.clip(thrust, 0.0, 1.0)) * p.thrust_max_n * p.thrust_scale
        self.setpoint = Setpoint("rates", thrust_n, rates_flu, now_s)
        self._setpoint_times.append(now_s)

    def actuator_setpoint(self, controls: FloatArray, now_s: float) -> None:
        """SET_ACTUATOR_CONTROL_TARGET group 0: roll, pitch, yaw torque (FRD) and thrust."""
        if not np.all(np.isfinite(controls[:4])):
            return
        p = self.params
        torque_frd = np.clip(controls[:3], -1.0, 1.0) * p.torque_max_nm
        torque_flu = np.array([torque_frd[0], -torque_frd[1], -torque_frd[2]])
        thrust_n = float(np.clip(controls[3], 0.0, 1.0)) * p.thrust_max_n * p.thrust_scale
        self.setpoint = Setpoint("actuator", thrust_n, torque_flu, now_s)
        self._setpoint_times.append(now_s)

    def vision(self, now_s: float) -> None:
        """An external vision pose (VISION_POSITION_ESTIMATE or ODOMETRY) arrived."""
        self.last_vision_s = now_s
        self.vision_messages += 1

    def command(
        self, command: int, params: tuple[float, ...], now_s: float, state: AirframeState
    ) -> Result:
        """A COMMAND_LONG: the MAV_RESULT it is acknowledged with."""
        if command == 400:  # MAV_CMD_COMPONENT_ARM_DISARM
            force = round(params[1]) == FORCE_MAGIC
            return self._arm(now_s, state, force) if params[0] > 0.5 else self._disarm(state, force)
        if command == 176:  # MAV_CMD_DO_SET_MODE
            return self.set_mode(int(params[0]), int(params[1]), int(params[2]), now_s, state)
        if command in (21, 185):  # NAV_LAND, DO_FLIGHTTERMINATION → land / stop
            if command == 185 and params[0] > 0.5:
                self.armed = False
                self._say(2, "Flight termination active")
                return Result.ACCEPTED
            return self.set_mode(1, int(MainMode.AUTO), int(AutoMode.LAND), now_s, state)
        if command in (511, 512, 520):  # SET_MESSAGE_INTERVAL, REQUEST_MESSAGE, capabilities
            return Result.ACCEPTED
        return Result.UNSUPPORTED

    def set_mode(
        self, base_mode: int, main: int, sub: int, now_s: float, state: AirframeState
    ) -> Result:
        """DO_SET_MODE (or SET_MODE) with custom main/sub mode."""
        if not base_mode & 1:
            return Result.UNSUPPORTED
        try:
            target = MainMode(main)
        except ValueError:
            return Result.UNSUPPORTED
        if target is MainMode.OFFBOARD and self.armed and not self._stream_alive(now_s):
            self._say(4, "Switching to Offboard is currently not available")
            return Result.TEMPORARILY_REJECTED
        self.main_mode = target
        self.sub_mode = sub if target is MainMode.AUTO else 0
        self._enter_mode(state)
        return Result.ACCEPTED

    def _enter_mode(self, state: AirframeState) -> None:
        self._hold_target = np.array(state.position_m, dtype=float)
        self._hold_yaw = float(euler_zyx_from_quaternion(state.quaternion)[2])
        self.hold.reset()

    def _arm(self, now_s: float, state: AirframeState, force: bool) -> Result:
        if self.armed:
            return Result.ACCEPTED
        if not force:
            if not state.on_ground:
                self._say(3, "Arming denied: not landed")
                return Result.DENIED
            vision_fresh = now_s - self.last_vision_s <= self.params.vision_timeout_s
            if self.params.require_vision and not vision_fresh:
                self._say(3, "Arming denied: no position estimate (external vision)")
                return Result.DENIED
            if self.main_mode is MainMode.OFFBOARD and not self._stream_alive(now_s):
                self._say(3, "Arming denied: offboard setpoints not streaming")
                return Result.TEMPORARILY_REJECTED
        self.armed = True
        self._armed_at_s = now_s
        self._took_off = False
        self._landed_since_s = None
        self.rates.reset()
        self._say(6, "Armed by external command")
        return Result.ACCEPTED

    def _disarm(self, state: AirframeState, force: bool) -> Result:
        if not self.armed:
            return Result.ACCEPTED
        if not force and not state.on_ground:
            self._say(3, "Disarming denied: not landed")
            return Result.DENIED
        self.armed = False
        self._say(6, "Disarmed by external command" + (" (forced)" if force else ""))
        return Result.ACCEPTED

    # ---- the flight-control step ------------------------------------------------------------
    def step(self, now_s: float, state: AirframeState) -> tuple[float, FloatArray]:
        """Failsafes and the active mode's control at ``now_s``: (thrust [N], torque FLU
        [N m]) for the airframe; zeros when disarmed."""
        dt = 0.0 if self._last_step_s is None else max(0.0, now_s - self._last_step_s)
        self._last_step_s = now_s
        self._failsafes(now_s, state)
        if not self.armed:
            return 0.0, np.zeros(3)
        rates_now = np.asarray(state.body_rates_radps, dtype=float)
        if self.main_mode is MainMode.OFFBOARD:
            sp = self.setpoint
            if sp is None:
                return 0.0, np.zeros(3)
            if sp.kind == "actuator":
                return sp.thrust_n, sp.vector.copy()
            return sp.thrust_n, self.rates.torque(sp.vector, rates_now, dt)
        if self.main_mode is MainMode.AUTO and self.sub_mode in (AutoMode.LAND, AutoMode.LOITER):
            return self._hold_or_land(state, rates_now, dt)
        return 0.0, np.zeros(3)  # manual modes without a pilot: motors idle

    def _hold_or_land(
        self, state: AirframeState, rates_now: FloatArray, dt: float
    ) -> tuple[float, FloatArray]:
        if self._hold_target is None:
            self._enter_mode(state)
        assert self._hold_target is not None
        landing = self.sub_mode == AutoMode.LAND
        if landing and state.on_ground:
            return 0.0, np.zeros(3)  # touched down: spool down, auto-disarm follows
        rotation = rotation_from_quaternion(state.quaternion)
        thrust, rates_sp = self.hold.command(
            self._hold_target,
            -self.params.land_speed_mps if landing else None,
            self._hold_yaw,
            np.asarray(state.position_m, dtype=float),
            np.asarray(state.velocity_mps, dtype=float),
            rotation,
            dt,
        )
        return min(thrust, self.params.thrust_max_n), self.rates.torque(rates_sp, rates_now, dt)

    def _failsafes(self, now_s: float, state: AirframeState) -> None:
        p = self.params
        if not self.armed:
            return
        if not state.on_ground:
            self._took_off = True
            self._landed_since_s = None
        elif self._landed_since_s is None:
            self._landed_since_s = now_s
        if self.main_mode is MainMode.OFFBOARD:
            last = self.setpoint.time_s if self.setpoint is not None else self._armed_at_s
            if now_s - last > p.offboard_loss_timeout_s:
                self._say(4, "Failsafe: offboard lost, landing")
                self.main_mode, self.sub_mode = MainMode.AUTO, int(AutoMode.LAND)
                self._enter_mode(state)
        landed_for = now_s - self._landed_since_s if self._landed_since_s is not None else 0.0
        if self._took_off and self.sub_mode == AutoMode.LAND and landed_for > p.auto_disarm_land_s:
            self.armed = False
            self._say(6, "Disarmed: landed")
        elif not self._took_off and now_s - self._armed_at_s > p.auto_disarm_preflight_s:
            self.armed = False
            self._say(6, "Disarmed: no takeoff after arming")
