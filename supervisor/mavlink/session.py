"""What the supervisor knows of one PX4 over MAVLink, without I/O: time is an argument.

The session takes decoded messages with their receive time and tells the adapter what
they mean — the vehicle's liveness, arming, mode, battery and texts, and the COMMAND_ACK
for a command it waits for — and when its own heartbeat is due. The asyncio link
(``supervisor.mavlink.link``) moves the bytes and runs the timers it asks for.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from supervisor.vehicles.types import VehicleView

HEARTBEAT_PERIOD_S = 1.0
AUTOPILOT_COMPONENT = 1
IN_PROGRESS = 5  # MAV_RESULT_IN_PROGRESS: a final ACK follows
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
    """The final COMMAND_ACK of a command the session was waiting for."""

    command: int
    result: int

    @property
    def accepted(self) -> bool:
        return self.result == 0


class VehicleSession:
    """One vehicle (MAVLink system ``system_id``) as seen from the ground station."""

    def __init__(self, system_id: int, link_loss_s: float, boot_s: float) -> None:
        self.system_id = system_id
        self.link_loss_s = link_loss_s
        self.boot_s = boot_s
        self.armed = False
        self.custom_mode = 0
        self.battery_v = math.nan
        self.status_texts: deque[str] = deque(maxlen=20)
        self.attitude_rad: tuple[float, float, float] | None = None
        self._last_heartbeat_s = -math.inf
        self._next_own_heartbeat_s = -math.inf
        self._awaited: set[int] = set()

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
    def await_ack(self, command: int) -> None:
        """A COMMAND_LONG ``command`` was sent: its final ACK is wanted."""
        self._awaited.add(command)

    def forget_ack(self, command: int) -> None:
        """No longer wait for ``command``'s ACK (answered, or given up)."""
        self._awaited.discard(command)

    def refusal(self, ack: CommandAck) -> str:
        """Why a command was refused, in words, with the vehicle's last text if any."""
        reason = RESULT_NAMES.get(ack.result, f"result {ack.result}")
        said = f" ({self.status_texts[-1]})" if self.status_texts else ""
        return f"command {ack.command} {reason}{said}"

    # ---- receive ----------------------------------------------------------------------------
    def is_from_vehicle(self, message: mavlink.MAVLink_message) -> bool:
        """Whether ``message`` comes from this session's vehicle (its system id)."""
        return bool(message.get_srcSystem() == self.system_id)

    def receive(self, message: mavlink.MAVLink_message, now_s: float) -> CommandAck | None:
        """Apply one decoded message of the vehicle, received at ``now_s``; returns the ACK
        of an awaited command when this message is one."""
        kind = message.get_type()
        if kind == "HEARTBEAT" and message.get_srcComponent() == AUTOPILOT_COMPONENT:
            self._last_heartbeat_s = now_s
            self.armed = bool(message.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = int(message.custom_mode)
        elif kind == "COMMAND_ACK":
            command = int(message.command)
            if command in self._awaited and message.result != IN_PROGRESS:
                return CommandAck(command, int(message.result))
        elif kind == "STATUSTEXT":
            text = (
                message.text.decode(errors="replace")
                if isinstance(message.text, bytes)
                else str(message.text)
            )
            self.status_texts.append(text.rstrip("\x00"))
        elif kind == "SYS_STATUS" and message.voltage_battery not in (0, 65535):
            self.battery_v = message.voltage_battery / 1000.0
        elif kind == "ATTITUDE":
            self.attitude_rad = (float(message.roll), float(message.pitch), float(message.yaw))
        return None

    # ---- state ------------------------------------------------------------------------------
    def connected(self, now_s: float) -> bool:
        """Heartbeats arrived within ``link_loss_s``."""
        return now_s - self._last_heartbeat_s <= self.link_loss_s

    def px4_mode(self, now_s: float) -> str:
        return px4_mode_name(self.custom_mode) if self.connected(now_s) else "unknown"

    def view(self, now_s: float) -> VehicleView:
        connected = self.connected(now_s)
        return VehicleView(
            connected=connected,
            armed=self.armed and connected,
            px4_mode=self.px4_mode(now_s),
            battery_v=self.battery_v,
            status_text=self.status_texts[-1] if self.status_texts else "",
        )
