"""What the supervisor knows of one PX4 over MAVLink, without I/O: time is an argument.

The session takes decoded messages with their receive time and tells the adapter what
they mean — the vehicle's liveness, arming, mode, battery and texts, and the COMMAND_ACK
for a command it waits for — when its own heartbeat is due, and which replies the vehicle
expects (``replies()``: TIMESYNC answers, REQUEST_EVENT for lost events). The asyncio link
(``supervisor.mavlink.link``) moves the bytes and runs the timers it asks for.

As PX4 v1.15.4 behaves (docs/reference/px4-offboard.md §5):

* **Liveness** is any message of the vehicle's autopilot component, not heartbeats alone:
  PX4's HEARTBEAT is 1 Hz and cannot be raised, gaps reach 2.01 s under load while its
  streams keep arriving at 30–100 Hz (item 3).
* **Mode and armed state** are taken from whatever shows them first: HEARTBEAT, CURRENT_MODE
  (~0.5 Hz, sooner than the next heartbeat after a change), and the accepted COMMAND_ACK of
  an arm/disarm/force-disarm/set-mode command this session sent (the command's parameters
  are kept until its ACK, so the ACK can be applied).
* **Reasons** arrive as EVENT messages (item 5), decoded through the firmware's event
  catalog (``px4_mavlink.events``); STATUSTEXT is kept too (multi-chunk texts joined).
  A refusal carries the text PX4 sent around the ACK (measured: the event 2–9 ms *after*
  the ACK, so the link waits ``REASON_WAIT_S`` for it) and, for arming, the arming checks
  PX4 last reported as failing in the current mode.
* **TIMESYNC** requests (tc1 = 0, 10 Hz) are answered with tc1 = our clock in ns and ts1
  echoed (item 8), so PX4 maps the timestamps we send (mocap) onto its own clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from px4_mavlink.codec import mavlink
from px4_mavlink.events import (
    LOG_LEVEL_ERROR,
    LOG_LEVEL_PROTOCOL,
    EventCatalog,
    fallback_text,
)
from px4_mavlink.px4_messages import MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET
from supervisor.vehicles.types import VehicleView

HEARTBEAT_PERIOD_S = 1.0
AUTOPILOT_COMPONENT = 1
IN_PROGRESS = 5  # MAV_RESULT_IN_PROGRESS: a final ACK follows
ARM_DISARM = 400  # MAV_CMD_COMPONENT_ARM_DISARM: param1 1 arm, 0 disarm (param2 21196: forced)
SET_MODE = 176  # MAV_CMD_DO_SET_MODE: param1 base mode (1: custom), param2 main, param3 sub
REASON_BEFORE_S = 0.3
"""A text received up to this long before a refusal's ACK may be its reason."""
REASON_WAIT_S = 0.05
"""How long the link waits after a refusal's ACK for PX4's event (measured 2–9 ms after)."""
REPEAT_TEXT_S = 1.0  # the same words again within this: the EVENT and its STATUSTEXT twin
MAX_EVENT_REQUEST = 32  # lost events asked again at most this many at a time
STATUSTEXT_LEN = 50
MAX_OPEN_TEXTS = 8  # multi-chunk STATUSTEXTs being joined at once (a lost last chunk: dropped)
RESULT_NAMES = {
    0: "accepted",
    1: "temporarily rejected",
    2: "denied",
    3: "unsupported",
    4: "failed",
    5: "in progress",
    6: "cancelled",
}
PX4_MAIN_MODES = {
    1: "MANUAL",
    2: "ALTCTL",
    3: "POSCTL",
    4: "AUTO",
    5: "ACRO",
    6: "OFFBOARD",
    7: "STABILIZED",
    8: "RATTITUDE",
}
PX4_AUTO_MODES = {1: "READY", 2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND"}


def px4_mode_name(custom_mode: int) -> str:
    """PX4's mode from a heartbeat's custom_mode: main in bits 16–23, sub in 24–31."""
    main = (custom_mode >> 16) & 0xFF
    sub = (custom_mode >> 24) & 0xFF
    name = PX4_MAIN_MODES.get(main, f"MODE{main}")
    if main == 4 and sub:
        return f"AUTO.{PX4_AUTO_MODES.get(sub, sub)}"
    return name


@dataclass(frozen=True)
class CommandAck:
    """The final COMMAND_ACK of a command the session was waiting for, received at
    ``time_s`` (the session's clock), with the parameters the command was sent with."""

    command: int
    result: int
    time_s: float = math.nan
    params: tuple[float, ...] = ()

    @property
    def accepted(self) -> bool:
        return self.result == 0


@dataclass(frozen=True)
class VehicleText:
    """Something the vehicle said, received at ``time_s``: ``source`` "event" or
    "statustext", ``level`` 0 (emergency) … 7 (debug), as MAVLink severities."""

    time_s: float
    text: str
    source: str
    level: int


@dataclass(frozen=True)
class ArmingCheck:
    """A failing check of PX4's latest arming-check report: its text, log level, and the
    navigation mode groups (bitfield) it prevents."""

    text: str
    level: int
    modes: int


@dataclass(frozen=True)
class TimesyncReply:
    """A TIMESYNC to send: ``tc1_ns`` our clock, ``ts1_ns`` the request's, echoed."""

    tc1_ns: int
    ts1_ns: int
    target_system: int
    target_component: int


@dataclass(frozen=True)
class EventRequest:
    """A REQUEST_EVENT to send for the lost events ``first_sequence`` … ``last_sequence``."""

    first_sequence: int
    last_sequence: int
    target_system: int
    target_component: int


Reply = TimesyncReply | EventRequest


class VehicleSession:
    """One vehicle (MAVLink system ``system_id``) as seen from the ground station.
    ``catalog``: PX4's event definitions (None: events shown by id only)."""

    def __init__(
        self,
        system_id: int,
        link_loss_s: float,
        boot_s: float,
        catalog: EventCatalog | None = None,
    ) -> None:
        self.system_id = system_id
        self.link_loss_s = link_loss_s
        self.boot_s = boot_s
        self.catalog = catalog
        self.armed = False
        self.custom_mode = 0
        self.battery_v = math.nan
        self.status_texts: deque[str] = deque(maxlen=20)
        """The vehicle's latest texts (events and STATUSTEXT), oldest first."""
        self.texts: deque[VehicleText] = deque(maxlen=20)
        self.arming_checks: tuple[ArmingCheck, ...] = ()
        """The failing checks of PX4's latest complete arming-check report."""
        self.attitude_rad: tuple[float, float, float] | None = None
        self.text_count = 0
        """How many texts arrived so far (the link watches it for a refusal's reason)."""
        self.events_lost = 0
        self._last_heard_s = -math.inf
        self._last_heartbeat_s = -math.inf
        self._next_own_heartbeat_s = -math.inf
        self._awaited: dict[int, tuple[float, ...]] = {}
        self._replies: list[Reply] = []
        self._chunks: dict[int, list[str]] = {}
        self._event_sequence: int | None = None
        self._requested_events: set[int] = set()
        self._pending_checks: list[ArmingCheck] | None = None
        self._handlers: dict[str, Callable[[Any, float], CommandAck | None]] = {
            "HEARTBEAT": self._heartbeat,
            "CURRENT_MODE": self._current_mode,
            "COMMAND_ACK": self._command_ack,
            "STATUSTEXT": self._statustext,
            "EVENT": self._event,
            "CURRENT_EVENT_SEQUENCE": self._current_event_sequence,
            "TIMESYNC": self._timesync,
            "SYS_STATUS": self._sys_status,
            "ATTITUDE": self._attitude,
        }

    # ---- timers -----------------------------------------------------------------------------
    def heartbeat_due(self, now_s: float) -> bool:
        """Whether our own heartbeat is due at ``now_s``; a True answer counts it as sent."""
        if now_s < self._next_own_heartbeat_s:
            return False
        self._next_own_heartbeat_s = now_s + HEARTBEAT_PERIOD_S
        return True

    @property
    def next_heartbeat_s(self) -> float:
        """When our next heartbeat is due."""
        return self._next_own_heartbeat_s

    def time_boot_ms(self, now_s: float) -> int:
        """Milliseconds since the session started, as MAVLink's uint32 time_boot_ms."""
        return int((now_s - self.boot_s) * 1000) & 0xFFFFFFFF

    # ---- commands ---------------------------------------------------------------------------
    def await_ack(self, command: int, *params: float) -> None:
        """A COMMAND_LONG ``command`` with ``params`` was sent: its final ACK is wanted (and,
        when accepted, applied: arming, disarming, mode)."""
        self._awaited[command] = tuple(params)

    def forget_ack(self, command: int) -> None:
        """No longer wait for ``command``'s ACK (answered, or given up)."""
        self._awaited.pop(command, None)

    def reason_since(self, ack: CommandAck) -> VehicleText | None:
        """The vehicle's latest text from ``REASON_BEFORE_S`` before ``ack`` on (any text
        when the ACK's time is unknown)."""
        if not self.texts:
            return None
        latest = self.texts[-1]
        if math.isnan(ack.time_s) or latest.time_s >= ack.time_s - REASON_BEFORE_S:
            return latest
        return None

    def heard_after(self, ack: CommandAck) -> bool:
        """Whether a text arrived at or after ``ack`` (PX4 sends its reason just after)."""
        return bool(self.texts) and self.texts[-1].time_s >= ack.time_s

    def refusal(self, ack: CommandAck) -> str:
        """Why a command was refused, in words: the result, PX4's own reason received around
        the ACK, and for arming the checks PX4 reports failing in the current mode."""
        reason = RESULT_NAMES.get(ack.result, f"result {ack.result}")
        said = self.reason_since(ack)
        details = [said.text] if said is not None else []
        if ack.command == ARM_DISARM and ack.params[:1] == (1.0,):
            details += [c.text for c in self.arming_problems() if c.text not in details]
        return f"command {ack.command} {reason}" + (f" ({'; '.join(details)})" if details else "")

    def arming_problems(self) -> list[ArmingCheck]:
        """The reported checks at error level or worse that prevent arming in the current mode
        (all of them when the catalog does not map the mode to its group)."""
        group = self.catalog.mode_groups.get(self.custom_mode) if self.catalog else None
        return [
            check
            for check in self.arming_checks
            if check.level <= LOG_LEVEL_ERROR and (group is None or check.modes & group)
        ]

    # ---- receive ----------------------------------------------------------------------------
    def is_from_vehicle(self, message: Any) -> bool:
        """Whether ``message`` comes from this session's vehicle (its system id)."""
        return bool(message.get_srcSystem() == self.system_id)

    def receive(self, message: Any, now_s: float) -> CommandAck | None:
        """Apply one decoded message of the vehicle, received at ``now_s``; returns the ACK
        of an awaited command when this message is one."""
        if message.get_srcComponent() == AUTOPILOT_COMPONENT:
            self._last_heard_s = now_s
        handler = self._handlers.get(message.get_type())
        return handler(message, now_s) if handler is not None else None

    def replies(self) -> list[Reply]:
        """What the vehicle expects back since the last call (the link sends it)."""
        replies, self._replies = self._replies, []
        return replies

    def _heartbeat(self, message: Any, now_s: float) -> None:
        if message.get_srcComponent() != AUTOPILOT_COMPONENT:
            return  # a camera's or gimbal's heartbeat says nothing of the autopilot
        self._last_heartbeat_s = now_s
        self.armed = bool(message.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        self.custom_mode = int(message.custom_mode)

    def _current_mode(self, message: Any, now_s: float) -> None:
        if message.get_srcComponent() == AUTOPILOT_COMPONENT and message.custom_mode:
            self.custom_mode = int(message.custom_mode)

    def _command_ack(self, message: Any, now_s: float) -> CommandAck | None:
        command = int(message.command)
        if command not in self._awaited or message.result == IN_PROGRESS:
            return None
        ack = CommandAck(command, int(message.result), now_s, self._awaited[command])
        if ack.accepted:
            self._apply(ack)
        return ack

    def _apply(self, ack: CommandAck) -> None:
        """What an accepted command changed, before any heartbeat shows it."""
        params = ack.params
        if ack.command == ARM_DISARM and params:
            self.armed = params[0] == 1.0
        elif ack.command == SET_MODE and len(params) >= 2 and int(params[0]) & 1:
            main = int(params[1]) & 0xFF
            sub = int(params[2]) & 0xFF if len(params) >= 3 else 0
            self.custom_mode = (main << 16) | (sub << 24)

    def _statustext(self, message: Any, now_s: float) -> None:
        raw = message.text
        text = raw.decode(errors="replace") if isinstance(raw, bytes) else str(raw)
        text = text.rstrip("\x00")
        chunk_id = int(getattr(message, "id", 0) or 0)
        if chunk_id:  # one of several chunks: the last is shorter than the field
            if chunk_id not in self._chunks and len(self._chunks) >= MAX_OPEN_TEXTS:
                self._chunks.pop(next(iter(self._chunks)))  # the oldest never finished
            chunks = self._chunks.setdefault(chunk_id, [])
            chunks.append(text)
            if len(text) == STATUSTEXT_LEN and len(chunks) < 10:
                return
            text = "".join(self._chunks.pop(chunk_id))
        self._add_text(VehicleText(now_s, text.strip(), "statustext", int(message.severity)))

    def _event(self, message: Any, now_s: float) -> None:
        if not self._new_event(int(message.sequence), message.get_srcComponent()):
            return
        level = int(message.log_levels) & 0x0F
        event_id = int(message.id)
        if self.catalog is None:
            if level < LOG_LEVEL_PROTOCOL:
                self._add_text(VehicleText(now_s, fallback_text(event_id), "event", level))
            return
        event = self.catalog.decode(event_id, bytes(message.arguments))
        if event.group == "arming_check":
            if event.kind == "summary":
                if not event.values or event.values[0] == 0:  # chunk 0 starts a report
                    self._pending_checks = []
            elif self._pending_checks is not None and event.values:
                self._pending_checks.append(ArmingCheck(event.text, level, int(event.values[0])))
        elif event.group == "health":
            if event.kind == "summary" and self._pending_checks is not None:
                self.arming_checks, self._pending_checks = tuple(self._pending_checks), None
        elif level < LOG_LEVEL_PROTOCOL and event.kind != "summary":
            self._add_text(VehicleText(now_s, event.text, "event", level))

    def _new_event(self, sequence: int, component: int) -> bool:
        """Whether an EVENT's ``sequence`` is new (a re-sent one we asked for counts once);
        a gap before it is asked for again."""
        if sequence in self._requested_events:
            self._requested_events.discard(sequence)
            return True
        latest = self._event_sequence
        if latest is None:
            self._event_sequence = sequence
            return True
        ahead = (sequence - latest) & 0xFFFF
        if ahead == 0 or ahead >= 0x8000:
            return False  # a duplicate or an old one
        self._event_sequence = sequence
        if ahead > 1:
            self._request_events(latest + 1, sequence - 1, component)
        return True

    def _current_event_sequence(self, message: Any, now_s: float) -> None:
        sequence = int(message.sequence)
        if int(message.flags) & MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET:
            # Restarted (a reboot): PX4 announces the reset with the sequence of the event it
            # is about to send (measured: CURRENT_EVENT_SEQUENCE 0 then EVENT 0, 0.6 ms later),
            # so the next event starts the count again.
            self._event_sequence, self._requested_events = None, set()
            return
        latest = self._event_sequence
        if latest is None:  # joined late: what came before is not ours to ask for
            self._event_sequence = sequence
            return
        ahead = (sequence - latest) & 0xFFFF
        if 0 < ahead < 0x8000:  # events we never saw
            self._request_events(latest + 1, sequence, message.get_srcComponent())
            self._event_sequence = sequence

    def _request_events(self, first: int, last: int, component: int) -> None:
        count = ((last - first) & 0xFFFF) + 1
        self.events_lost += count
        first = (last - min(count, MAX_EVENT_REQUEST) + 1) & 0xFFFF  # the newest ones
        last &= 0xFFFF
        span = ((last - first) & 0xFFFF) + 1
        self._requested_events.update((first + k) & 0xFFFF for k in range(span))
        self._replies.append(EventRequest(first, last, self.system_id, component))

    def _timesync(self, message: Any, now_s: float) -> None:
        if int(message.tc1) != 0:
            return  # a reply to someone's request, not a request
        self._replies.append(
            TimesyncReply(
                tc1_ns=round(now_s * 1e9),
                ts1_ns=int(message.ts1),
                target_system=message.get_srcSystem(),
                target_component=message.get_srcComponent(),
            )
        )

    def _sys_status(self, message: Any, now_s: float) -> None:
        if message.voltage_battery not in (0, 65535):
            self.battery_v = message.voltage_battery / 1000.0

    def _attitude(self, message: Any, now_s: float) -> None:
        self.attitude_rad = (float(message.roll), float(message.pitch), float(message.yaw))

    def _add_text(self, text: VehicleText) -> None:
        if not text.text:
            return
        previous = self.texts[-1] if self.texts else None
        if (
            previous
            and previous.text == text.text
            and text.time_s - previous.time_s < REPEAT_TEXT_S
        ):
            # Said again: PX4 sends an event and its STATUSTEXT twin. Keep the newer time
            # (a refusal's reason is looked up by time) and the event's source and level.
            kept = previous if previous.source == "event" else text
            self.texts[-1] = replace(kept, time_s=text.time_s)
        else:
            self.texts.append(text)
            self.status_texts.append(text.text)
        self.text_count += 1

    # ---- state ------------------------------------------------------------------------------
    def connected(self, now_s: float) -> bool:
        """A message of the vehicle's autopilot arrived within ``link_loss_s``."""
        return now_s - self._last_heard_s <= self.link_loss_s

    def silence_s(self, now_s: float) -> float:
        """Seconds since the vehicle's autopilot was last heard (inf: never)."""
        return now_s - self._last_heard_s

    def heartbeat_age_s(self, now_s: float) -> float:
        """Seconds since the vehicle's last heartbeat (inf: none yet)."""
        return now_s - self._last_heartbeat_s

    def px4_mode(self, now_s: float) -> str:
        """PX4's mode, "unknown" while not connected or before any message showed it."""
        if not self.connected(now_s) or self.custom_mode == 0:
            return "unknown"
        return px4_mode_name(self.custom_mode)

    def view(self, now_s: float) -> VehicleView:
        # Before its first heartbeat a vehicle's arming state is not known: not connected
        # for whoever reads the view (the status, the arming), however much else it sent.
        connected = self.connected(now_s) and math.isfinite(self._last_heartbeat_s)
        return VehicleView(
            connected=connected,
            armed=self.armed and connected,
            px4_mode=self.px4_mode(now_s),
            battery_v=self.battery_v,
            status_text=self.status_texts[-1] if self.status_texts else "",
        )
