"""The supervisor's MAVLink 2 link to one PX4 (pymavlink codec, asyncio UDP).

Like a MAVLink client on PX4's offboard/API link (protocols.md §2–4): it listens on a local
UDP port (14540+i by default; PX4 sends there) and answers the address the vehicle's
datagrams come from; given the vehicle's address it also announces itself first (the
embedded simulator, whose ports are picked at run time). It sends a HEARTBEAT at 1 Hz,
detects link loss when the vehicle's heartbeats stop, sends commands and waits for their
COMMAND_ACK (with retries), and sends exactly the setpoints the control loop hands it —
nothing repeats them, so when the loop stops the stream stops and PX4's offboard-loss
failsafe takes over.

Setpoints: ``actuator`` mode sends SET_ACTUATOR_CONTROL_TARGET group 0 (torques FRD
normalized by ``torque_max_nm``, thrust by ``thrust_max_n``: the vehicle's calibration);
``rates`` mode sends SET_ATTITUDE_TARGET with type_mask 128 (body rates FRD + thrust).
Mocap is forwarded as VISION_POSITION_ESTIMATE or ODOMETRY in NED/FRD.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pymavlink.dialects.v20 import common as mavlink

from geometry.frames import (
    enu_to_ned,
    euler_zyx_from_rotation,
    flu_to_frd,
    quaternion_from_rotation,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from supervisor.vehicles.types import UavCommand, VehicleCommandError, VehicleView

FloatArray = NDArray[np.float64]
FORCE_MAGIC = 21196
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
class LinkConfig:
    """One vehicle's link. ``local_port`` 0: any free port. ``vehicle_address`` (host,
    port), when known, is contacted first; otherwise the vehicle's first datagram tells."""

    system_id: int
    local_host: str = "0.0.0.0"
    local_port: int = 14540
    vehicle_address: tuple[str, int] | None = None
    command_mode: Literal["actuator", "rates"] = "actuator"
    mocap_message: Literal["vision_position_estimate", "odometry"] = "vision_position_estimate"
    thrust_max_n: float = 26.0
    torque_max_nm: float = 1.0
    ack_timeout_s: float = 0.5
    retries: int = 3
    link_loss_s: float = 1.5
    source_system: int = 255
    source_component: int = 190


@dataclass
class LinkCounters:
    """Traffic seen on the link."""

    datagrams: int = 0
    messages: int = 0
    bad_data: int = 0
    foreign: int = 0
    setpoints_sent: int = 0
    thrust_clipped: int = 0
    torque_clipped: int = 0
    mocap_sent: int = 0


class _Sink:
    def __init__(self) -> None:
        self.transport: asyncio.DatagramTransport | None = None
        self.address: tuple[str, int] | None = None

    def write(self, data: bytes) -> None:
        if self.transport is not None and self.address is not None:
            self.transport.sendto(data, self.address)


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, link: MavlinkLink) -> None:
        self.link = link

    def datagram_received(self, data: bytes, addr: tuple[str | int, ...]) -> None:
        self.link.handle_datagram(data, (str(addr[0]), int(addr[1])))


class MavlinkLink:
    """``supervisor.vehicles.link.VehicleLink`` over MAVLink 2 / UDP."""

    def __init__(self, config: LinkConfig) -> None:
        self.config = config
        self.counters = LinkCounters()
        self._clock = time.monotonic
        self._sink = _Sink()
        self._sink.address = config.vehicle_address
        self.mav = mavlink.MAVLink(
            self._sink, srcSystem=config.source_system, srcComponent=config.source_component
        )
        self.mav.robust_parsing = True
        self._transport: asyncio.DatagramTransport | None = None
        self._tasks: list[asyncio.Task[None]] = []
        self._acks: dict[int, asyncio.Future[int]] = {}
        self._last_heartbeat_s = -math.inf
        self.armed = False
        self.custom_mode = 0
        self.battery_v = math.nan
        self.status_texts: deque[str] = deque(maxlen=20)
        self.attitude_rad: tuple[float, float, float] | None = None
        self._boot_s = self._clock()

    # ---- lifecycle ----------------------------------------------------------------------------
    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        c = self.config
        transport, _ = await loop.create_datagram_endpoint(
            lambda: _Protocol(self), local_addr=(c.local_host, c.local_port)
        )
        self._transport = transport
        self._sink.transport = transport
        self._tasks.append(loop.create_task(self._heartbeats(), name=f"mavlink-hb-{c.system_id}"))

    async def close(self) -> None:
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError):
                await task
        self._tasks.clear()
        if self._transport is not None:
            self._transport.close()
            self._transport = None
            self._sink.transport = None

    @property
    def local_port(self) -> int:
        if self._transport is None:
            return self.config.local_port
        return int(self._transport.get_extra_info("sockname")[1])

    async def _heartbeats(self) -> None:
        while True:
            self.mav.heartbeat_send(
                mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                mavlink.MAV_STATE_ACTIVE,
            )  # fmt: skip
            await asyncio.sleep(1.0)

    # ---- receive ------------------------------------------------------------------------------
    def handle_datagram(self, data: bytes, sender: tuple[str, int]) -> None:
        """Decode and apply one datagram; bad data is counted, never raised."""
        self.counters.datagrams += 1
        try:
            messages = self.mav.parse_buffer(data) or []
        except (mavlink.MAVError, ValueError, IndexError, TypeError, OverflowError):
            self.counters.bad_data += 1
            return
        finally:
            # A datagram holds whole frames: what is left is garbage, not the start of the
            # next datagram's frame (pymavlink's parser would prepend it).
            self.mav.buf, self.mav.buf_index = bytearray(), 0
            self.mav.expected_length = mavlink.HEADER_LEN_V1 + 2
        for message in messages:
            if message.get_type() == "BAD_DATA":
                self.counters.bad_data += 1
                continue
            if message.get_srcSystem() != self.config.system_id:
                self.counters.foreign += 1
                continue
            self.counters.messages += 1
            if self._sink.address is None or self.config.vehicle_address is None:
                self._sink.address = sender  # answer where the vehicle talks from
            self._apply(message)

    def _apply(self, message: mavlink.MAVLink_message) -> None:
        kind = message.get_type()
        if kind == "HEARTBEAT" and message.get_srcComponent() == 1:
            self._last_heartbeat_s = self._clock()
            self.armed = bool(message.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = int(message.custom_mode)
        elif kind == "COMMAND_ACK":
            future = self._acks.get(int(message.command))
            if future is not None and not future.done() and message.result != 5:
                future.set_result(int(message.result))
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

    # ---- state --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._clock() - self._last_heartbeat_s <= self.config.link_loss_s

    @property
    def px4_mode(self) -> str:
        return px4_mode_name(self.custom_mode) if self.connected else "unknown"

    def view(self) -> VehicleView:
        return VehicleView(
            connected=self.connected,
            armed=self.armed and self.connected,
            px4_mode=self.px4_mode,
            battery_v=self.battery_v,
            status_text=self.status_texts[-1] if self.status_texts else "",
        )

    # ---- commands -------------------------------------------------------------------------------
    async def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG until acknowledged (``retries`` tries of ``ack_timeout_s``); raises
        ``VehicleCommandError`` naming the result, or the silence."""
        c = self.config
        if self._sink.address is None:
            raise VehicleCommandError("no link to the vehicle yet")
        padded = (*params, *([0.0] * (7 - len(params))))
        loop = asyncio.get_running_loop()
        for attempt in range(c.retries):
            future: asyncio.Future[int] = loop.create_future()
            self._acks[command] = future
            try:
                self.mav.command_long_send(c.system_id, 1, command, attempt, *padded)
                async with asyncio.timeout(c.ack_timeout_s):
                    result = await future
            except TimeoutError:
                continue
            finally:
                self._acks.pop(command, None)
            if result == 0:
                return
            reason = RESULT_NAMES.get(result, f"result {result}")
            said = f" ({self.status_texts[-1]})" if self.status_texts else ""
            raise VehicleCommandError(f"command {command} {reason}{said}")
        raise VehicleCommandError(f"command {command}: no acknowledgement after {c.retries} tries")

    async def arm(self) -> None:
        await self.command(400, 1.0, 0.0)

    async def disarm(self) -> None:
        await self.command(400, 0.0, 0.0)

    async def kill(self) -> None:
        await self.command(400, 0.0, float(FORCE_MAGIC))

    async def set_offboard(self) -> None:
        await self.command(176, 1.0, 6.0, 0.0)

    async def set_hold(self) -> None:
        await self.command(176, 1.0, 4.0, 3.0)  # AUTO.LOITER, as MAVSDK's offboard.stop()

    # ---- streams --------------------------------------------------------------------------------
    def _time_boot_ms(self) -> int:
        return int((self._clock() - self._boot_s) * 1000) & 0xFFFFFFFF

    def normalized_thrust(self, thrust_n: float) -> float:
        """Thrust [N] as PX4's normalized [0, 1], by this vehicle's calibration."""
        value = thrust_n / self.config.thrust_max_n
        if not 0.0 <= value <= 1.0:
            self.counters.thrust_clipped += 1
        return float(np.clip(value, 0.0, 1.0))

    def send_setpoint(self, command: UavCommand) -> None:
        """This tick's setpoint; motors off sends zero thrust (the stream never pauses)."""
        c = self.config
        if not (math.isfinite(command.thrust_n) and np.all(np.isfinite(command.torque_nm))):
            command = UavCommand.off()
        thrust = self.normalized_thrust(command.thrust_n) if command.motors_on else 0.0
        if c.command_mode == "actuator":
            torque = (
                flu_to_frd(command.torque_nm) / c.torque_max_nm
                if command.motors_on
                else np.zeros(3)
            )
            if np.any(np.abs(torque) > 1.0):
                self.counters.torque_clipped += 1
            torque = np.clip(torque, -1.0, 1.0)
            controls = [
                float(torque[0]),
                float(torque[1]),
                float(torque[2]),
                thrust,
                0.0,
                0.0,
                0.0,
                0.0,
            ]
            self.mav.set_actuator_control_target_send(
                self._time_boot_ms() * 1000, 0, c.system_id, 1, controls
            )
        else:
            rates = flu_to_frd(command.body_rates_radps) if command.motors_on else np.zeros(3)
            if not np.all(np.isfinite(rates)):
                rates = np.zeros(3)
            self.mav.set_attitude_target_send(
                self._time_boot_ms(), c.system_id, 1, 128, [1.0, 0.0, 0.0, 0.0],
                float(rates[0]), float(rates[1]), float(rates[2]), thrust,
            )  # fmt: skip
        self.counters.setpoints_sent += 1

    def send_mocap(self, position_m: FloatArray, quaternion: FloatArray, time_s: float) -> None:
        """The vehicle's pose (arena ENU, FLU body → ENU quaternion) in NED/FRD."""
        if not (np.all(np.isfinite(position_m)) and np.all(np.isfinite(quaternion))):
            return
        north, east, down = enu_to_ned(position_m)
        R = rotation_enu_flu_to_ned_frd(rotation_from_quaternion(quaternion))
        usec = int(time_s * 1e6)
        if self.config.mocap_message == "vision_position_estimate":
            roll, pitch, yaw = euler_zyx_from_rotation(R)
            self.mav.vision_position_estimate_send(usec, north, east, down, roll, pitch, yaw)
        else:
            q = [float(v) for v in quaternion_from_rotation(R)]
            nan21 = [math.nan] * 21
            self.mav.odometry_send(
                usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                north, east, down, q, math.nan, math.nan, math.nan,
                math.nan, math.nan, math.nan, nan21, nan21,
            )  # fmt: skip
        self.counters.mocap_sent += 1
