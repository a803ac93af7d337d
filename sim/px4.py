"""The simulated PX4's behaviour, without I/O: modes, arming, offboard rules, failsafes,
parameters, events and the setpoint paths (docs/reference/px4-offboard.md §2 and §5, and
../shared/reference/px4-observed.md). Time is an argument.

As PX4 v1.15.4 does, measured on its SITL build:

* **Modes** are PX4's (main, sub) custom modes. It boots disarmed in AUTO.LOITER. What the
  heartbeat shows (PX4's nav_state) is the user's *intended* mode unless a failsafe holds
  another one; disarming ends any failsafe, so after a force-disarm in the air the heartbeat
  reads OFFBOARD (disarmed) again when offboard was what the user asked for.
* **Offboard**: any setpoint counts as proof of life; offboard can be entered when armed
  only while setpoints have arrived at > 2 Hz for > 1 s (else ``TEMPORARILY_REJECTED``,
  mode unchanged); when disarmed it may be selected, but arming in it then needs the stream
  too. Setpoints act only while in OFFBOARD.
* **Offboard loss**: no setpoint for COM_OF_LOSS_T while the intended mode is OFFBOARD and
  armed. Commander checks at 10 Hz, so the failsafe starts 0–0.1 s after the timeout
  (measured 1.02–1.10 s with 1.0, 0.55 s with 0.5), without a COM_FAIL_ACT_T hold first.
  COM_OBL_RC_ACT chooses it: 0 POSCTL (no RC: holds position), 1 ALTCTL (holds height,
  level, drifts), 2 STABILIZED (level, hover thrust), 3 AUTO.RTL, 4 AUTO.LAND, 5 AUTO.LOITER,
  6 flight termination, 7 disarm (each measured on v1.15.4 but 6 and 7). When setpoints come
  back the failsafe ends and OFFBOARD is shown again (measured for 0–5).
* **Parameters**: PX4's names, types and defaults (``PARAMETERS``); the ones marked in
  ``DRIVING`` steer the behaviour, the rest are stored and echoed (as on a vehicle whose
  hardware we do not simulate). ``Px4Params`` fields give the initial values.
* **Arming**: refused (``TEMPORARILY_REJECTED``, as PX4 answers a failed arming check) when
  not on the ground, after a flight termination, without fresh external vision
  (``require_vision``; the sample's capture time counts once TIMESYNC converged, else its
  arrival, minus EKF2_EV_DELAY), or in OFFBOARD without a stream. Normal disarm only on the
  ground (else ``TEMPORARILY_REJECTED``); force-disarm (param2 21196) at once, anywhere.
  Auto-disarm COM_DISARM_LAND after landing in AUTO.LAND / RTL, and COM_DISARM_PRFLT after
  arming without a take-off.
* **Reasons** are EVENTs (``Px4Event``, names of ``sim/px4_events.json``, the firmware's ids
  and argument layouts), plus the arming-check report whenever the set of failing checks
  changes; ``status_texts`` keeps a line of words per event for tests.
* **Command modes**: ``SET_ATTITUDE_TARGET`` type_mask 128 (body rates FRD + normalized
  thrust) through the rate PID; ``SET_ACTUATOR_CONTROL_TARGET`` group 0 (torques in
  [-1, 1] FRD, thrust in [0, 1]). Normalized values scale by this vehicle's calibration
  (``thrust_max_n``, ``torque_max_nm``, ``thrust_scale``), which may differ from the
  supervisor's.
"""

from __future__ import annotations

import logging
import math
import struct
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import euler_zyx_from_quaternion, rotation_from_quaternion
from sim.ports import AirframeState
from sim.px4_control import HoldController, RateController

log = logging.getLogger(__name__)

FORCE_MAGIC = 21196
COMMANDER_PERIOD_S = 0.1
"""PX4's commander evaluates failsafes and auto-disarm at this period (what the measured
spread of the offboard-loss delay shows)."""
RTL_ARRIVED_M = 0.3  # horizontal distance to home at which RTL starts its landing


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


class FailsafeAction(IntEnum):
    """PX4's ``failsafe_action_t`` (the values its failsafe events carry)."""

    FALLBACK_POSCTRL = 2
    FALLBACK_ALTCTRL = 3
    FALLBACK_STABILIZED = 4
    HOLD = 5
    RTL = 6
    LAND = 7
    DISARM = 9
    TERMINATE = 10


class ArmDisarmReason(IntEnum):
    """PX4's ``arm_disarm_reason_t`` (what its armed/disarmed events carry)."""

    COMMAND_EXTERNAL = 4
    AUTO_DISARM_LAND = 6
    AUTO_DISARM_PREFLIGHT = 7
    FAILSAFE = 14


Mode = tuple[MainMode, int]
BOOT_MODE: Mode = (MainMode.AUTO, int(AutoMode.LOITER))

# COM_OBL_RC_ACT → the failsafe action (PX4 ``Failsafe::fromOffboardLossActParam``).
OFFBOARD_LOSS_ACTIONS = {
    0: FailsafeAction.FALLBACK_POSCTRL,
    1: FailsafeAction.FALLBACK_ALTCTRL,
    2: FailsafeAction.FALLBACK_STABILIZED,
    3: FailsafeAction.RTL,
    4: FailsafeAction.LAND,
    5: FailsafeAction.HOLD,
    6: FailsafeAction.TERMINATE,
    7: FailsafeAction.DISARM,
}
# The mode each lasting action flies (and the heartbeat shows).
FAILSAFE_MODES: dict[FailsafeAction, Mode] = {
    FailsafeAction.FALLBACK_POSCTRL: (MainMode.POSCTL, 0),
    FailsafeAction.FALLBACK_ALTCTRL: (MainMode.ALTCTL, 0),
    FailsafeAction.FALLBACK_STABILIZED: (MainMode.STABILIZED, 0),
    FailsafeAction.HOLD: (MainMode.AUTO, int(AutoMode.LOITER)),
    FailsafeAction.RTL: (MainMode.AUTO, int(AutoMode.RTL)),
    FailsafeAction.LAND: (MainMode.AUTO, int(AutoMode.LAND)),
}
# PX4's navigation_mode_t of a (main, sub) mode (commander_modeswitch_not_avail's argument).
NAVIGATION_MODES: dict[Mode, int] = {
    (MainMode.MANUAL, 0): 0,
    (MainMode.ALTCTL, 0): 1,
    (MainMode.POSCTL, 0): 2,
    (MainMode.AUTO, int(AutoMode.MISSION)): 3,
    (MainMode.AUTO, int(AutoMode.LOITER)): 4,
    (MainMode.AUTO, int(AutoMode.RTL)): 5,
    (MainMode.ACRO, 0): 6,
    (MainMode.OFFBOARD, 0): 7,
    (MainMode.STABILIZED, 0): 8,
    (MainMode.AUTO, int(AutoMode.TAKEOFF)): 10,
    (MainMode.AUTO, int(AutoMode.LAND)): 11,
}
# PX4's navigation mode groups (navigation_mode_group_t bits), as the firmware's event
# definitions map custom modes to them ("For now we directly map group == mode").
MODE_GROUPS: dict[Mode, int] = {
    (MainMode.MANUAL, 0): 1 << 0,
    (MainMode.ALTCTL, 0): 1 << 1,
    (MainMode.POSCTL, 0): 1 << 2,
    (MainMode.AUTO, int(AutoMode.MISSION)): 1 << 3,
    (MainMode.AUTO, int(AutoMode.LOITER)): 1 << 4,
    (MainMode.AUTO, int(AutoMode.RTL)): 1 << 5,
    (MainMode.ACRO, 0): 1 << 10,
    (MainMode.OFFBOARD, 0): 1 << 14,
    (MainMode.STABILIZED, 0): 1 << 15,
    (MainMode.AUTO, int(AutoMode.TAKEOFF)): 1 << 17,
    (MainMode.AUTO, int(AutoMode.LAND)): 1 << 18,
}
ALL_GROUPS = sum(MODE_GROUPS.values())
POSITION_GROUPS = sum(
    bit
    for mode, bit in MODE_GROUPS.items()
    if mode[0] in (MainMode.POSCTL, MainMode.OFFBOARD, MainMode.AUTO)
)
# health_component_t bit indices the checks report.
HEALTH_VISION = 5
HEALTH_ATTITUDE = 16
HEALTH_LOCAL_POSITION = 17
HEALTH_SYSTEM = 20
HEALTH_ACCEL = 28
HEALTH_GYRO = 29

# libevents log levels, as EVENT.log_levels = internal << 4 | external (the pairs PX4 used).
LOG_INFO = 0x66
LOG_REFUSED = 0x62  # critical to the user, info internally: denied arming, mode, disarm
LOG_FAILSAFE = 0x42  # critical to the user, warning internally
LOG_CHECK_ERROR = 0x33
LOG_PROTOCOL = 0x88  # the arming-check report's summaries


def custom_mode_of(mode: Mode) -> int:
    """PX4's custom_mode: main mode in bits 16–23, sub mode in bits 24–31."""
    return (int(mode[0]) << 16) | (int(mode[1]) << 24)


# ---- parameters ----------------------------------------------------------------------------------
class ParamType(IntEnum):
    """MAV_PARAM_TYPE of PX4's two parameter types."""

    INT32 = 6
    REAL32 = 9


@dataclass(frozen=True)
class ParamSpec:
    """A PX4 parameter: name, type, PX4's default, whether PX4 reads it only at boot."""

    name: str
    type: ParamType
    default: float
    reboot_required: bool = False


_I, _F = ParamType.INT32, ParamType.REAL32
# PX4 v1.15.4's definitions (etc/extras/parameters.json.xz of the build), sorted by name as
# PX4 indexes them. Units: s, m/s, ms (EKF2_EV_DELAY), normalized (MPC_THR_HOVER).
PARAMETERS: tuple[ParamSpec, ...] = tuple(
    sorted(
        (
            ParamSpec("COM_DISARM_LAND", _F, 2.0),
            ParamSpec("COM_DISARM_PRFLT", _F, 10.0),
            ParamSpec("COM_FAIL_ACT_T", _F, 5.0),
            ParamSpec("COM_OBL_RC_ACT", _I, 0),
            ParamSpec("COM_OF_LOSS_T", _F, 1.0),
            ParamSpec("COM_RC_IN_MODE", _I, 3),
            ParamSpec("EKF2_BARO_CTRL", _I, 1),
            ParamSpec("EKF2_EV_CTRL", _I, 15),
            ParamSpec("EKF2_EV_DELAY", _F, 0.0, reboot_required=True),
            ParamSpec("EKF2_GPS_CTRL", _I, 7),
            ParamSpec("EKF2_HGT_REF", _I, 1, reboot_required=True),
            ParamSpec("EKF2_MAG_TYPE", _I, 0, reboot_required=True),
            ParamSpec("MAV_SYS_ID", _I, 1, reboot_required=True),
            ParamSpec("MPC_LAND_SPEED", _F, 0.7),
            ParamSpec("MPC_THR_HOVER", _F, 0.5),
            ParamSpec("NAV_DLL_ACT", _I, 0),
            ParamSpec("NAV_RCL_ACT", _I, 2),
            ParamSpec("SDLOG_MODE", _I, 0, reboot_required=True),
            ParamSpec("SYS_HAS_GPS", _I, 1, reboot_required=True),
            ParamSpec("THR_MDL_FAC", _F, 0.0),
        ),
        key=lambda spec: spec.name,
    )
)
PX4_NAMES = frozenset(spec.name for spec in PARAMETERS)
DRIVING = frozenset(
    {
        "COM_DISARM_LAND",  # auto-disarm after landing [s] (≤ 0: never)
        "COM_DISARM_PRFLT",  # auto-disarm without take-off [s] (≤ 0: never)
        "COM_OBL_RC_ACT",  # offboard-loss action
        "COM_OF_LOSS_T",  # offboard-loss timeout [s]
        "EKF2_EV_CTRL",  # bits 0–1: vision position fused (else vision gives no position)
        "EKF2_EV_DELAY",  # vision latency assumed [ms] (at boot)
        "MAV_SYS_ID",  # the system id (at boot)
        "MPC_LAND_SPEED",  # descent rate of AUTO.LAND [m/s]
        "MPC_THR_HOVER",  # hover thrust of the own modes [normalized]
    }
)
# What PX4 does *not* do that these parameters might suggest (measured on v1.15.4):
# COM_FAIL_ACT_T puts no hold before the offboard-loss action; NAV_DLL_ACT 0 ignores a
# lost ground station.


def float32(value: float) -> float:
    """``value`` as the float32 PX4 stores."""
    return float(struct.unpack("<f", struct.pack("<f", value))[0])


class Px4Parameters:
    """One vehicle's parameter table: PX4's names and types, values as PX4 holds them (int
    for INT32, float32 for REAL32), indexed in name order."""

    def __init__(self, values: Mapping[str, float] | None = None) -> None:
        self.specs = PARAMETERS
        self._index = {spec.name: k for k, spec in enumerate(self.specs)}
        self._values: dict[str, float] = {spec.name: spec.default for spec in self.specs}
        for spec in self.specs:
            self.set(spec.name, spec.default)
        for name, value in (values or {}).items():
            self.set(name, value)

    def __len__(self) -> int:
        return len(self.specs)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def spec(self, name: str) -> ParamSpec | None:
        k = self._index.get(name)
        return None if k is None else self.specs[k]

    def index(self, name: str) -> int:
        return self._index[name]

    def get(self, name: str) -> float:
        """The value (an int for INT32); ``KeyError`` for a name PX4 does not have."""
        return self._values[name]

    def set(self, name: str, value: float) -> bool:
        """Store ``value`` (no range check: PX4 stores out-of-range values too, measured);
        returns whether it changed. ``KeyError`` for an unknown name."""
        spec = self.specs[self._index[name]]
        new: float = int(value) if spec.type is ParamType.INT32 else float32(value)
        old = self._values[name]
        self._values[name] = new
        return bool(struct.pack("<d", old) != struct.pack("<d", new))

    def items(self) -> Iterable[tuple[ParamSpec, float]]:
        """Every parameter with its value, in index order."""
        return ((spec, self._values[spec.name]) for spec in self.specs)


# ---- time synchronization ------------------------------------------------------------------------
class Timesync:
    """PX4's TIMESYNC offset filter (``src/lib/timesync/Timesync.cpp``, v1.15): answers to
    our requests whose round trip is under 10 ms update a double-exponential filter of the
    offset (our clock minus the client's); 500 samples make it converged, and only then are
    a client's timestamps mapped onto our clock (``sync_stamp``: before, PX4 stamps each
    message with its arrival). Five samples in a row more than 100 ms off a converged
    estimate reset it (a clock jump). Times in ns/µs as on the wire.

    An answer counts only when its ts1 is one of our recent requests (PX4 itself relies on
    the round-trip gate for that: a foreign ts1 gives a round trip far out of it)."""

    CONVERGENCE_WINDOW = 500
    MAX_RTT_US = 10_000
    MAX_DEVIATION_US = 100_000
    MAX_CONSECUTIVE_HIGH_DEVIATION = 5
    ALPHA_INITIAL, ALPHA_FINAL = 0.05, 0.003
    BETA_INITIAL, BETA_FINAL = 0.05, 0.003

    def __init__(self) -> None:
        self._sent: deque[int] = deque(maxlen=20)
        self.samples = 0
        self.rejected = 0
        self.reset()

    def reset(self) -> None:
        self.sequence = 0
        self.offset_us = 0.0
        self._skew = 0.0
        self._high_deviation = 0

    @property
    def converged(self) -> bool:
        return self.sequence >= self.CONVERGENCE_WINDOW

    def sent(self, ts1_ns: int) -> None:
        """We sent a request carrying ``ts1_ns``."""
        self._sent.append(ts1_ns)

    def update(self, now_ns: int, tc1_ns: int, ts1_ns: int) -> bool:
        """An answer (tc1 ≠ 0) received at ``now_ns``: whether it updated the estimate."""
        if tc1_ns <= 0 or ts1_ns not in self._sent:
            self.rejected += 1
            return False
        now_us = now_ns // 1000
        offset_us = float(int((ts1_ns // 1000 + now_us - (tc1_ns // 1000) * 2) / 2))
        rtt_us = now_us - ts1_ns // 1000
        if rtt_us >= self.MAX_RTT_US:
            self.rejected += 1
            return False
        if self.converged and abs(self.offset_us - offset_us) > self.MAX_DEVIATION_US:
            self._high_deviation += 1
            if self._high_deviation > self.MAX_CONSECUTIVE_HIGH_DEVIATION:
                self.reset()
            return False
        self._add_sample(offset_us)
        self.sequence += 1
        self.samples += 1
        self._high_deviation = 0
        return True

    def _add_sample(self, offset_us: float) -> None:
        if self.converged:
            alpha, beta = self.ALPHA_FINAL, self.BETA_FINAL
        else:  # gain scheduling along a sigmoid over the convergence window
            progress = self.sequence / self.CONVERGENCE_WINDOW
            p = 1.0 - math.exp(0.5 * (1.0 - 1.0 / (1.0 - progress)))
            alpha = p * self.ALPHA_FINAL + (1.0 - p) * self.ALPHA_INITIAL
            beta = p * self.BETA_FINAL + (1.0 - p) * self.BETA_INITIAL
        previous = self.offset_us
        if self.sequence == 0:
            self.offset_us = offset_us
            return
        self.offset_us = alpha * offset_us + (1.0 - alpha) * (self.offset_us + self._skew)
        self._skew = beta * (self.offset_us - previous) + (1.0 - beta) * self._skew

    def local_time_s(self, remote_usec: int) -> float | None:
        """A client's timestamp [µs] on our clock [s] once converged; None before."""
        if not self.converged:
            return None
        return (remote_usec + self.offset_us) * 1e-6


# ---- the vehicle ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Px4Params:
    """One simulated vehicle: its physics-facing calibration, and the initial values of the
    PX4 parameters named in the comments (``boot_parameters`` are set over them at boot, as
    a ``px4-rc.params`` file would; names PX4 lacks are ignored)."""

    inertia_kgm2: tuple[float, float, float] = (0.0348, 0.0459, 0.0977)
    thrust_max_n: float = 26.0  # thrust at normalized 1.0 (the vehicle's true calibration)
    torque_max_nm: float = 1.0  # torque at normalized ±1.0
    thrust_scale: float = 1.0  # calibration mismatch: true thrust = scale × commanded
    hover_thrust_n: float = 13.2  # MPC_THR_HOVER × max × scale: UAV plus half the bar
    offboard_loss_timeout_s: float = 1.0  # COM_OF_LOSS_T
    offboard_loss_action: int = 0  # COM_OBL_RC_ACT (0: position mode, 4: land)
    proof_of_life_s: float = 1.0
    proof_of_life_rate_hz: float = 2.0
    land_speed_mps: float = 0.7  # MPC_LAND_SPEED
    auto_disarm_land_s: float = 2.0  # COM_DISARM_LAND
    auto_disarm_preflight_s: float = 10.0  # COM_DISARM_PRFLT
    require_vision: bool = False
    vision_timeout_s: float = 0.5
    boot_parameters: tuple[tuple[str, float], ...] = ()
    heartbeat_jitter: bool = True  # the endpoint's heartbeat timing (PX4 under load)
    latch_partner: bool = True  # the endpoint streams to its first sender only, as PX4
    seed: int = 0  # of the endpoint's heartbeat jitter


@dataclass(frozen=True)
class Setpoint:
    """The last offboard setpoint: body rates FLU [rad/s] or torque FLU [N m], thrust [N]."""

    kind: str  # "rates" or "actuator"
    thrust_n: float
    vector: FloatArray
    time_s: float


@dataclass(frozen=True)
class Px4Event:
    """An event to send: its name in the catalog (``sim/px4_events.json``), its argument
    values in order (enums as integers), EVENT.log_levels, and when it happened."""

    name: str
    values: tuple[float, ...]
    log_levels: int
    time_s: float


@dataclass(frozen=True)
class ArmingCheck:
    """A failing check of the arming-check report: event name, the mode groups it blocks,
    the health component (bit index) it belongs to."""

    name: str
    modes: int
    health_index: int
    words: str


CHECK_OFFBOARD = ArmingCheck(
    "check_modes_offboard_signal", MODE_GROUPS[(MainMode.OFFBOARD, 0)], HEALTH_SYSTEM,
    "no offboard setpoints",
)  # fmt: skip
CHECK_POSITION = ArmingCheck(
    "check_modes_local_pos", POSITION_GROUPS, HEALTH_LOCAL_POSITION,
    "no position estimate (external vision)",
)  # fmt: skip
CHECK_TERMINATED = ArmingCheck(
    "check_system_flight_term_active", ALL_GROUPS, HEALTH_SYSTEM, "flight termination active"
)


class Px4Model:
    """One vehicle's flight stack state machine."""

    def __init__(self, system_id: int, params: Px4Params | None = None) -> None:
        self.params = p = params or Px4Params()
        hover = p.hover_thrust_n / (p.thrust_max_n * p.thrust_scale)
        initial: dict[str, float] = {
            "COM_DISARM_LAND": p.auto_disarm_land_s,
            "COM_DISARM_PRFLT": p.auto_disarm_preflight_s,
            "COM_OBL_RC_ACT": p.offboard_loss_action,
            "COM_OF_LOSS_T": p.offboard_loss_timeout_s,
            "MAV_SYS_ID": system_id,
            "MPC_LAND_SPEED": p.land_speed_mps,
            "MPC_THR_HOVER": hover,
        }
        initial.update((name, value) for name, value in p.boot_parameters if name in PX4_NAMES)
        self.parameters = Px4Parameters(initial)
        # Read at boot only (PX4: reboot required).
        self.system_id = int(self.parameters.get("MAV_SYS_ID"))
        self.vision_delay_s = self.parameters.get("EKF2_EV_DELAY") * 1e-3
        self.armed = False
        self.intended: Mode = BOOT_MODE
        self.failsafe: FailsafeAction | None = None
        self.setpoints_in_failsafe = 0
        self.terminated = False
        self.setpoint: Setpoint | None = None
        self.last_vision_s = -math.inf
        """Capture time of the newest vision sample on our clock (arrival before timesync)."""
        self.vision_messages = 0
        self.events: deque[Px4Event] = deque(maxlen=256)
        """Events not yet sent (the endpoint drains them)."""
        self.status_texts: deque[tuple[int, str]] = deque(maxlen=32)
        """(MAVLink severity, words) per event, for tests and logs; not sent."""
        self._setpoint_times: deque[float] = deque(maxlen=64)
        self._armed_at_s = 0.0
        self._took_off = False
        self._landed_since_s: float | None = None
        self._home_m: FloatArray | None = None
        self._hold_target: FloatArray | None = None
        self._hold_yaw = 0.0
        self._rtl_landing = False
        self._last_step_s: float | None = None
        self._logged_mode: Mode | None = None
        self._next_commander_s = 0.0
        self._reported: tuple[ArmingCheck, ...] | None = None
        self.rates = RateController(p.inertia_kgm2, p.torque_max_nm)
        self.hold = HoldController(p.hover_thrust_n)

    # ---- what the heartbeat shows --------------------------------------------------------
    @property
    def nav_mode(self) -> Mode:
        """The mode flown and shown: the failsafe's, else the user's intended one."""
        if self.failsafe is not None and self.failsafe in FAILSAFE_MODES:
            return FAILSAFE_MODES[self.failsafe]
        return self.intended

    @property
    def main_mode(self) -> MainMode:
        return self.nav_mode[0]

    @property
    def sub_mode(self) -> int:
        return self.nav_mode[1]

    @property
    def custom_mode(self) -> int:
        """PX4's custom_mode of the mode shown: main in bits 16–23, sub in bits 24–31."""
        return custom_mode_of(self.nav_mode)

    @property
    def intended_custom_mode(self) -> int:
        return custom_mode_of(self.intended)

    @property
    def base_mode(self) -> int:
        """HEARTBEAT.base_mode as PX4 v1.15 sets it (measured: 29 in AUTO disarmed, 209 in
        POSCTL armed, 129 in OFFBOARD armed)."""
        flags = 1  # MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.armed:
            flags |= 128  # SAFETY_ARMED
        main = self.main_mode
        if main in (MainMode.MANUAL, MainMode.ALTCTL, MainMode.POSCTL, MainMode.STABILIZED):
            flags |= 64 | 16  # MANUAL_INPUT_ENABLED | STABILIZE_ENABLED (a multicopter)
        elif main is MainMode.ACRO:
            flags |= 64
        elif main is MainMode.AUTO:
            flags |= 4 | 8 | 16  # AUTO | GUIDED | STABILIZE
        return flags

    @property
    def standard_mode(self) -> int:
        """CURRENT_MODE.standard_mode as v1.15.4 sends it (measured: 8 in AUTO.LAND, 5 in
        AUTO.RTL, 0 otherwise — its 8 is MAVLink's TAKEOFF, not LAND)."""
        return {(MainMode.AUTO, int(AutoMode.LAND)): 8, (MainMode.AUTO, int(AutoMode.RTL)): 5}.get(
            self.nav_mode, 0
        )

    @property
    def mode_name(self) -> str:
        main, sub = self.nav_mode
        if main is not MainMode.AUTO:
            return main.name
        try:
            return f"AUTO.{AutoMode(sub).name}"
        except ValueError:
            return "AUTO"

    # ---- events ---------------------------------------------------------------------------
    def _event(
        self, name: str, values: tuple[float, ...], log_levels: int, now_s: float, words: str
    ) -> None:
        self.events.append(Px4Event(name, values, log_levels, now_s))
        if log_levels & 0x0F < 8:
            self.status_texts.append((log_levels & 0x0F, words))

    def request_report(self) -> None:
        """Send the arming-check report at the next commander step, changed or not (PX4
        does so when a ground station appears)."""
        self._reported = None

    def failing_checks(self, now_s: float) -> tuple[ArmingCheck, ...]:
        """The arming checks that fail at ``now_s``."""
        checks = []
        if not self.offboard_signal(now_s):
            checks.append(CHECK_OFFBOARD)
        if self.params.require_vision and not self.vision_fresh(now_s):
            checks.append(CHECK_POSITION)
        if self.terminated:
            checks.append(CHECK_TERMINATED)
        return tuple(checks)

    def _report(self, now_s: float) -> None:
        """The arming-check report, when the failing checks changed: summary, each check,
        then the health summary (the order PX4 sends, and receivers finish a report on)."""
        checks = self.failing_checks(now_s)
        if checks == self._reported:
            return
        self._reported = checks
        errors = sum({1 << c.health_index for c in checks})
        blocked = 0
        for check in checks:
            blocked |= check.modes
        can = ALL_GROUPS & ~blocked
        summary = "commander_arming_check_summary"
        self.events.append(Px4Event(summary, (0, errors, 0, can, can), LOG_PROTOCOL, now_s))
        for check in checks:
            values = (check.modes, check.health_index)
            self.events.append(Px4Event(check.name, values, LOG_CHECK_ERROR, now_s))
        present = sum(1 << k for k in (HEALTH_ATTITUDE, HEALTH_LOCAL_POSITION, HEALTH_SYSTEM))
        present |= (1 << HEALTH_ACCEL) | (1 << HEALTH_GYRO)
        if self.vision_messages:
            present |= 1 << HEALTH_VISION
        health_errors = errors & (1 << HEALTH_LOCAL_POSITION)
        self.events.append(
            Px4Event(
                "commander_health_summary", (0, present, health_errors, 0), LOG_PROTOCOL, now_s
            )
        )

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

    def offboard_signal(self, now_s: float) -> bool:
        """A setpoint within COM_OF_LOSS_T (PX4's offboard-signal check)."""
        sp = self.setpoint
        return sp is not None and not now_s - sp.time_s > self.parameters.get("COM_OF_LOSS_T")

    def rate_setpoint(self, rates_frd: FloatArray, thrust: float, now_s: float) -> None:
        """SET_ATTITUDE_TARGET, type_mask 128: body rates (FRD) and thrust in [0, 1]."""
        if not (np.all(np.isfinite(rates_frd)) and math.isfinite(thrust)):
            return  # PX4 ignores non-finite setpoints
        p = self.params
        rates_flu = np.array([rates_frd[0], -rates_frd[1], -rates_frd[2]])
        thrust_n = float(np.clip(thrust, 0.0, 1.0)) * p.thrust_max_n * p.thrust_scale
        self._record(Setpoint("rates", thrust_n, rates_flu, now_s))

    def actuator_setpoint(self, controls: FloatArray, now_s: float) -> None:
        """SET_ACTUATOR_CONTROL_TARGET group 0: roll, pitch, yaw torque (FRD) and thrust."""
        if not np.all(np.isfinite(controls[:4])):
            return
        p = self.params
        torque_frd = np.clip(controls[:3], -1.0, 1.0) * p.torque_max_nm
        torque_flu = np.array([torque_frd[0], -torque_frd[1], -torque_frd[2]])
        thrust_n = float(np.clip(controls[3], 0.0, 1.0)) * p.thrust_max_n * p.thrust_scale
        self._record(Setpoint("actuator", thrust_n, torque_flu, now_s))

    def _record(self, setpoint: Setpoint) -> None:
        if self.failsafe is not None:
            # The stream back ends the failsafe (below): whoever sends flies the vehicle again.
            if not self.setpoints_in_failsafe:
                log.warning(
                    "PX4 %d: an offboard setpoint arrived in its failsafe (%s)",
                    self.system_id,
                    self.failsafe.name.lower(),
                )
            self.setpoints_in_failsafe += 1
        self.setpoint = setpoint
        self._setpoint_times.append(setpoint.time_s)

    def vision(self, now_s: float, sample_s: float | None = None) -> None:
        """An external vision pose (VISION_POSITION_ESTIMATE or ODOMETRY) arrived at
        ``now_s``, captured at ``sample_s`` on our clock (None: unknown, its arrival counts,
        as PX4 does before TIMESYNC converged). EKF2 takes the sample as EKF2_EV_DELAY older;
        a stamp from the future counts as arrived now."""
        self.vision_messages += 1
        captured = now_s if sample_s is None or not math.isfinite(sample_s) else sample_s
        captured = min(captured, now_s) - self.vision_delay_s
        self.last_vision_s = max(self.last_vision_s, captured)

    def vision_fresh(self, now_s: float) -> bool:
        """Whether the estimator has a vision position: EKF2_EV_CTRL fuses it (bits 0–1)
        and the newest sample is at most ``vision_timeout_s`` old."""
        fused = int(self.parameters.get("EKF2_EV_CTRL")) & 0b11
        return bool(fused) and now_s - self.last_vision_s <= self.params.vision_timeout_s

    def command(
        self, command: int, params: tuple[float, ...], now_s: float, state: AirframeState
    ) -> Result:
        """A COMMAND_LONG: the MAV_RESULT it is acknowledged with."""
        if command == 400:  # MAV_CMD_COMPONENT_ARM_DISARM
            force = round(params[1]) == FORCE_MAGIC
            if params[0] > 0.5:
                return self._arm(now_s, state, force)
            return self._disarm(now_s, state, force)
        if command == 176:  # MAV_CMD_DO_SET_MODE
            return self.set_mode(int(params[0]), int(params[1]), int(params[2]), now_s, state)
        if command == 185 and params[0] > 0.5:  # DO_FLIGHTTERMINATION: motors off, latched
            self._terminate(now_s)
            return Result.ACCEPTED
        if command in (21, 185):  # NAV_LAND (and termination off) → land
            return self.set_mode(1, int(MainMode.AUTO), int(AutoMode.LAND), now_s, state)
        if command == 511:  # SET_MESSAGE_INTERVAL: HEARTBEAT's cannot change (measured 4)
            return Result.FAILED if round(params[0]) == 0 else Result.ACCEPTED
        if command in (512, 520):  # REQUEST_MESSAGE, capabilities
            return Result.ACCEPTED
        return Result.UNSUPPORTED

    def set_mode(
        self, base_mode: int, main: int, sub: int, now_s: float, state: AirframeState
    ) -> Result:
        """DO_SET_MODE (or SET_MODE) with custom main/sub mode: the user's intended mode."""
        if not base_mode & 1:
            return Result.UNSUPPORTED
        try:
            target = MainMode(main)
        except ValueError:
            return Result.UNSUPPORTED
        mode: Mode = (target, sub if target is MainMode.AUTO else 0)
        if target is MainMode.AUTO and mode not in NAVIGATION_MODES:
            return Result.UNSUPPORTED
        if target is MainMode.OFFBOARD and self.armed and not self._stream_alive(now_s):
            self._event(
                "commander_modeswitch_not_avail",
                (custom_mode_of(mode), NAVIGATION_MODES[mode]), LOG_REFUSED, now_s,
                "Switching to Offboard is currently not available",
            )  # fmt: skip
            return Result.TEMPORARILY_REJECTED
        shown = self.nav_mode
        self.intended = mode
        self.failsafe = None  # the user took over
        if self.nav_mode != shown:
            self._enter_mode(state)
        return Result.ACCEPTED

    def _enter_mode(self, state: AirframeState) -> None:
        self._hold_target = np.array(state.position_m, dtype=float)
        self._hold_yaw = float(euler_zyx_from_quaternion(state.quaternion)[2])
        self._rtl_landing = False
        self.hold.reset()

    def _arm_refusal(self, now_s: float, state: AirframeState) -> str | None:
        """Why arming (not forced) is refused now, or None."""
        if self.terminated:
            return "flight termination active"
        if not state.on_ground:
            return "not landed"
        if self.params.require_vision and not self.vision_fresh(now_s):
            return CHECK_POSITION.words
        if self.main_mode is MainMode.OFFBOARD and not self._stream_alive(now_s):
            return "offboard setpoints not streaming"
        return None

    def _arm(self, now_s: float, state: AirframeState, force: bool) -> Result:
        if self.armed:
            return Result.ACCEPTED
        refusal = None if force else self._arm_refusal(now_s, state)
        if refusal is not None:
            self._event(
                "commander_arm_denied_resolve_failures", (), LOG_REFUSED, now_s,
                f"Arming denied: {refusal}",
            )  # fmt: skip
            return Result.TEMPORARILY_REJECTED
        self.armed = True
        self._armed_at_s = now_s
        self._took_off = False
        self._landed_since_s = None
        self._home_m = np.array(state.position_m, dtype=float)
        self.rates.reset()
        self._enter_mode(state)
        reason = ArmDisarmReason.COMMAND_EXTERNAL
        self._event("commander_armed_by", (reason,), LOG_INFO, now_s, "Armed by external command")
        return Result.ACCEPTED

    def _disarm(self, now_s: float, state: AirframeState, force: bool) -> Result:
        if not self.armed:
            return Result.ACCEPTED
        if not force and not state.on_ground:
            self._event(
                "commander_disarm_denied_not_landed", (), LOG_REFUSED, now_s,
                "Disarming denied: not landed",
            )  # fmt: skip
            return Result.TEMPORARILY_REJECTED
        words = "Disarmed by external command" + (" (forced)" if force else "")
        self._disarmed(now_s, ArmDisarmReason.COMMAND_EXTERNAL, words)
        return Result.ACCEPTED

    def _disarmed(self, now_s: float, reason: ArmDisarmReason, words: str) -> None:
        """Disarm: any failsafe ends with it, so the intended mode shows again."""
        self.armed = False
        self.failsafe = None
        self._event("commander_disarmed_by", (int(reason),), LOG_INFO, now_s, words)

    def _terminate(self, now_s: float) -> None:
        self.armed = False
        self.failsafe = None
        self.terminated = True
        self.status_texts.append((2, "Flight termination active"))

    # ---- the flight-control step ------------------------------------------------------------
    def step(self, now_s: float, state: AirframeState) -> tuple[float, FloatArray]:
        """Failsafes (every ``COMMANDER_PERIOD_S``) and the active mode's control at
        ``now_s``: (thrust [N], torque FLU [N m]) for the airframe; zeros when disarmed."""
        dt = 0.0 if self._last_step_s is None else max(0.0, now_s - self._last_step_s)
        self._last_step_s = now_s
        if now_s >= self._next_commander_s - 1e-6:  # (a tick's time as floats round it)
            self._commander(now_s, state)
            self._next_commander_s = (math.floor(now_s / COMMANDER_PERIOD_S) + 1) * (
                COMMANDER_PERIOD_S
            )
        if self.nav_mode != self._logged_mode:  # when each change took effect, in world time
            self._logged_mode = self.nav_mode
            log.info("PX4 %d: mode %s at %.3f s", self.system_id, self.mode_name, now_s)
        if not self.armed:
            return 0.0, np.zeros(3)
        p = self.params
        hover = self.parameters.get("MPC_THR_HOVER") * p.thrust_max_n * p.thrust_scale
        if math.isfinite(hover):
            self.hold.hover_thrust_n = hover
        return self._control(state, dt)

    def _control(self, state: AirframeState, dt: float) -> tuple[float, FloatArray]:
        rates_now = np.asarray(state.body_rates_radps, dtype=float)
        main, sub = self.nav_mode
        if main is MainMode.OFFBOARD:
            sp = self.setpoint
            if sp is None:
                return 0.0, np.zeros(3)
            if sp.kind == "actuator":
                return sp.thrust_n, sp.vector.copy()
            return sp.thrust_n, self.rates.torque(sp.vector, rates_now, dt)
        if main in (MainMode.MANUAL, MainMode.ACRO):
            return 0.0, np.zeros(3)  # no pilot: motors idle
        landing = (main, sub) == (MainMode.AUTO, AutoMode.LAND) or self._rtl_landing
        if state.on_ground and (landing or not self._took_off):
            return 0.0, np.zeros(3)  # on the ground: idle (no take-off without a pilot)
        if self._hold_target is None:
            self._enter_mode(state)
        rotation = rotation_from_quaternion(state.quaternion)
        if main is MainMode.STABILIZED:
            thrust, rates_sp = self.hold.level(self._hold_yaw, rotation)
        else:
            thrust, rates_sp = self._hold_command(state, rotation, landing, dt)
        return min(thrust, self.params.thrust_max_n), self.rates.torque(rates_sp, rates_now, dt)

    def _hold_command(
        self, state: AirframeState, rotation: FloatArray, landing: bool, dt: float
    ) -> tuple[float, FloatArray]:
        """Position hold (POSCTL, AUTO.LOITER), height hold (ALTCTL), landing, RTL."""
        assert self._hold_target is not None
        position = np.asarray(state.position_m, dtype=float)
        if (self.main_mode, self.sub_mode) == (MainMode.AUTO, AutoMode.RTL) and not landing:
            home = self._home_m if self._home_m is not None else position
            self._hold_target[0:2] = home[0:2]  # back over home at the height it had
            if math.hypot(*(position[0:2] - home[0:2])) < RTL_ARRIVED_M:
                self._rtl_landing = landing = True
        land_speed = float(self.parameters.get("MPC_LAND_SPEED"))
        if not math.isfinite(land_speed):  # a NaN set over MAVLink must not reach the plant
            land_speed = 0.7
        return self.hold.command(
            self._hold_target,
            -land_speed if landing else None,
            self._hold_yaw,
            position,
            np.asarray(state.velocity_mps, dtype=float),
            rotation,
            dt,
            hold_horizontal=self.main_mode is not MainMode.ALTCTL,
        )

    def _commander(self, now_s: float, state: AirframeState) -> None:
        """PX4's commander at its rate: take-off/landing, offboard loss, auto-disarm, the
        arming-check report (measured: the report of a lost offboard signal 10 ms before the
        failsafe's event)."""
        self._report(now_s)
        if self.armed:
            self._land_detector(now_s, state)
            self._offboard_loss(now_s, state)
            self._auto_disarm(now_s)

    def _land_detector(self, now_s: float, state: AirframeState) -> None:
        if not state.on_ground:
            if not self._took_off or self._landed_since_s is not None:
                self._event("commander_takeoff_detected", (), LOG_INFO, now_s, "Takeoff detected")
            self._took_off = True
            self._landed_since_s = None
        elif self._landed_since_s is None:
            self._landed_since_s = now_s
            if self._took_off:
                self._event("commander_landing_detected", (), LOG_INFO, now_s, "Landing detected")

    def _offboard_loss(self, now_s: float, state: AirframeState) -> None:
        """Enter the COM_OBL_RC_ACT failsafe when OFFBOARD is intended and the setpoints
        stopped; leave it when they are back."""
        if self.intended[0] is not MainMode.OFFBOARD:
            return
        signal = self.offboard_signal(now_s)
        if signal and self.failsafe is not None:
            self.failsafe = None
            self._enter_mode(state)
        if signal or self.failsafe is not None:
            return
        value = int(self.parameters.get("COM_OBL_RC_ACT"))
        # Values PX4 does not define: as the default (not measured).
        action = OFFBOARD_LOSS_ACTIONS.get(value, FailsafeAction.FALLBACK_POSCTRL)
        self._event(
            "commander_failsafe_enter_generic", (self.intended_custom_mode, int(action)),
            LOG_FAILSAFE, now_s, f"Failsafe: offboard lost, {action.name.lower()}",
        )  # fmt: skip
        if action is FailsafeAction.DISARM:
            self._disarmed(now_s, ArmDisarmReason.FAILSAFE, "Disarmed: failsafe")
        elif action is FailsafeAction.TERMINATE:
            self._terminate(now_s)
        else:
            self.failsafe = action
            self._enter_mode(state)

    def _auto_disarm(self, now_s: float) -> None:
        disarm_land_s = self.parameters.get("COM_DISARM_LAND")
        disarm_preflight_s = self.parameters.get("COM_DISARM_PRFLT")
        landing = self.nav_mode == (MainMode.AUTO, AutoMode.LAND) or self._rtl_landing
        landed_for = now_s - self._landed_since_s if self._landed_since_s is not None else 0.0
        if self._took_off and landing and 0.0 < disarm_land_s < landed_for:
            self._disarmed(now_s, ArmDisarmReason.AUTO_DISARM_LAND, "Disarmed: landed")
        elif not self._took_off and 0.0 < disarm_preflight_s < now_s - self._armed_at_s:
            self._disarmed(
                now_s, ArmDisarmReason.AUTO_DISARM_PREFLIGHT, "Disarmed: no takeoff after arming"
            )
