"""A simulated PX4's MAVLink 2 endpoint on UDP, driving one airframe of the plant.

PX4 SITL's conventions (docs/reference/px4-offboard.md §5): instance i (0-based) sends from
UDP 14580+i to the offboard/API client at 14540+i; system id i+1, component 1 (autopilot).
It streams HEARTBEAT (1 Hz), ATTITUDE and ATTITUDE_QUATERNION (50 Hz), LOCAL_POSITION_NED
(30 Hz, NED),
SYS_STATUS and EXTENDED_SYS_STATE (5 Hz), BATTERY_STATUS (1 Hz), STATUSTEXT as events
happen; answers every COMMAND_LONG with COMMAND_ACK (3 UNSUPPORTED when unknown) and
AUTOPILOT_VERSION when asked. The ``Px4Model`` holds the behaviour; this module only moves
datagrams. ``handle_datagram`` is the whole receive path (also what the fuzzer drives).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from geometry.frames import (
    enu_to_ned,
    euler_zyx_from_rotation,
    flu_to_frd,
    quaternion_from_rotation,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from sim.ports import AirframePort, AirframeState
from sim.px4 import Px4Model, Px4Params
from supervisor.mavlink.codec import MavlinkCodec
from supervisor.mavlink.transport import Address, UdpTransport

API_CLIENT_PORT = 14540
API_LOCAL_PORT = 14580
AUTOPILOT_VERSION_ID = 148
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
)
STREAM_PERIODS_S = {
    "heartbeat": 1.0,
    "attitude": 0.02,
    "local_position": 1.0 / 30.0,
    "status": 0.2,
    "battery": 1.0,
}


@dataclass
class EndpointCounters:
    """What arrived: datagrams, messages parsed, bad data (failed CRC, garbage),
    messages handled and messages of kinds this endpoint ignores."""

    datagrams: int = 0
    messages: int = 0
    bad_data: int = 0
    handled: int = 0
    ignored: int = 0
    per_type: dict[str, int] = field(default_factory=dict)


class Px4Endpoint:
    """Vehicle ``instance`` (0-based): its model, its UDP socket, its airframe port."""

    def __init__(
        self,
        instance: int,
        airframe: AirframePort,
        params: Px4Params | None = None,
        *,
        host: str = "127.0.0.1",
        local_port: int | None = None,
        client_port: int | None = None,
        battery_capacity_s: float = 1200.0,
    ) -> None:
        self.instance = instance
        self.airframe = airframe
        self.model = Px4Model(system_id=instance + 1, params=params or Px4Params())
        self.host = host
        self.local_port = API_LOCAL_PORT + instance if local_port is None else local_port
        self.client_port = API_CLIENT_PORT + instance if client_port is None else client_port
        self.counters = EndpointCounters()
        self.texts_sent: deque[str] = deque(maxlen=64)
        self.codec = MavlinkCodec(system=instance + 1, component=1)
        self._transport: UdpTransport | None = None
        self._client_address: Address | None = None
        self._next_send_s = dict.fromkeys(STREAM_PERIODS_S, 0.0)
        self._now_s = 0.0
        self._battery_capacity_s = battery_capacity_s
        self._flight_time_s = 0.0

    # ---- lifecycle --------------------------------------------------------------------------
    async def start(self) -> None:
        self._client_address = (self.host, self.client_port)
        self._transport = await UdpTransport.open(
            (self.host, self.local_port), self._datagram_received, self._client_address
        )
        self.local_port = self._transport.local_port

    async def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def _datagram_received(self, data: bytes, sender: Address) -> None:
        if self.handle_datagram(data, self.clock_s()):
            # Like PX4's UDP link, answer the client that talks to us.
            self.client_address = sender

    def _flush(self) -> None:
        frames = self.codec.outgoing()
        if self._transport is not None:
            self._transport.send(frames)

    def describe(self) -> str:
        return f"{self.host}:{self.local_port}"

    def clock_s(self) -> float:
        """The world time of the last ``step`` (received messages are stamped with it)."""
        return self._now_s

    # ---- receive ------------------------------------------------------------------------------
    @property
    def client_address(self) -> Address | None:
        """Where telemetry goes: the configured client port until a client talks to us."""
        return self._client_address

    @client_address.setter
    def client_address(self, address: Address) -> None:
        self._client_address = address
        if self._transport is not None:
            self._transport.peer = address

    def handle_datagram(self, data: bytes, now_s: float) -> bool:
        """Parse and act on one datagram; malformed input is counted, never raised.
        Returns whether it held at least one valid message."""
        self.counters.datagrams += 1
        decoded = self.codec.decode(data)
        self.counters.bad_data += decoded.bad_data
        for message in decoded.messages:
            kind = message.get_type()
            self.counters.messages += 1
            self.counters.per_type[kind] = self.counters.per_type.get(kind, 0) + 1
            try:
                handled = self._handle(message, now_s)
            except (ValueError, TypeError, IndexError, OverflowError):
                self.counters.bad_data += 1
                continue
            if handled:
                self.counters.handled += 1
            else:
                self.counters.ignored += 1
        self._flush()
        return bool(decoded.messages)

    def _for_me(self, message: mavlink.MAVLink_message) -> bool:
        target = int(getattr(message, "target_system", 0))
        return target in (0, self.model.system_id)

    def _handle(self, message: mavlink.MAVLink_message, now_s: float) -> bool:
        kind = message.get_type()
        model = self.model
        if kind == "SET_ATTITUDE_TARGET" and self._for_me(message):
            # Body rates + thrust: attitude ignored (128), rates not ignored (1, 2 clear).
            if message.type_mask & 128 and not message.type_mask & 3:
                rates = np.array(
                    [message.body_roll_rate, message.body_pitch_rate, message.body_yaw_rate]
                )
                model.rate_setpoint(rates, float(message.thrust), now_s)
                return True
            return False
        if kind == "SET_ACTUATOR_CONTROL_TARGET" and self._for_me(message):
            if message.group_mlx == 0:
                model.actuator_setpoint(np.asarray(message.controls, dtype=float), now_s)
                return True
            return False
        if kind in ("COMMAND_LONG", "COMMAND_INT") and self._for_me(message):
            self._command(message, now_s)
            return True
        if kind == "SET_MODE" and message.target_system == model.system_id:
            main = (message.custom_mode >> 16) & 0xFF
            sub = (message.custom_mode >> 24) & 0xFF
            model.set_mode(message.base_mode, main, sub, now_s, self.airframe.state())
            return True
        if kind in ("VISION_POSITION_ESTIMATE", "ODOMETRY"):
            model.vision(now_s)
            return True
        return bool(kind == "HEARTBEAT")

    def _command(self, message: mavlink.MAVLink_message, now_s: float) -> None:
        raw: tuple[float, ...]
        if message.get_type() == "COMMAND_LONG":
            raw = (
                message.param1,
                message.param2,
                message.param3,
                message.param4,
                message.param5,
                message.param6,
                message.param7,
            )
        else:
            raw = (message.param1, message.param2, message.param3, message.param4)
        params = tuple(float(p) if math.isfinite(p) else 0.0 for p in raw)
        result = self.model.command(message.command, params, now_s, self.airframe.state())
        self.codec.messages.command_ack_send(
            message.command, int(result), 0, 0, message.get_srcSystem(), message.get_srcComponent()
        )
        wants_version = message.command == 520 or (
            message.command == 512 and round(params[0]) == AUTOPILOT_VERSION_ID
        )
        if wants_version:
            self._send_version()

    # ---- send -----------------------------------------------------------------------------------
    def _send_version(self) -> None:
        version = (1 << 24) | (15 << 16) | (4 << 8) | 255  # 1.15.4, release
        self.codec.messages.autopilot_version_send(
            CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1000 + self.instance
        )

    def step(self, now_s: float) -> None:
        """Run the flight stack to ``now_s``: command the airframe, send due telemetry."""
        dt = max(0.0, now_s - self._now_s)
        self._now_s = now_s
        state = self.airframe.state()
        if self.model.armed and not state.on_ground:
            self._flight_time_s += dt
        thrust_n, torque_nm = self.model.step(now_s, state)
        self.airframe.command(thrust_n, torque_nm)
        self._send_telemetry(now_s, state)
        self._flush()

    def _due(self, stream: str, now_s: float) -> bool:
        if now_s < self._next_send_s[stream]:
            return False
        self._next_send_s[stream] = max(self._next_send_s[stream] + STREAM_PERIODS_S[stream], now_s)
        return True

    def _send_telemetry(self, now_s: float, state: AirframeState) -> None:
        model = self.model
        time_ms = int(now_s * 1000) & 0xFFFFFFFF
        while model.status_texts:
            severity, text = model.status_texts.popleft()
            self.codec.messages.statustext_send(severity, text.encode()[:50])
            self.texts_sent.append(text)
        if self._due("heartbeat", now_s):
            base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            if model.armed:
                base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            status = mavlink.MAV_STATE_ACTIVE if model.armed else mavlink.MAV_STATE_STANDBY
            self.codec.messages.heartbeat_send(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base_mode,
                model.custom_mode, status,
            )  # fmt: skip
        if self._due("attitude", now_s):
            # PX4 reports FRD body → NED world.
            R = rotation_enu_flu_to_ned_frd(rotation_from_quaternion(state.quaternion))
            roll, pitch, yaw = euler_zyx_from_rotation(R)
            p, q, r = flu_to_frd(state.body_rates_radps)
            self.codec.messages.attitude_send(time_ms, roll, pitch, yaw, p, q, r)
            quaternion = [float(v) for v in quaternion_from_rotation(R)]
            self.codec.messages.attitude_quaternion_send(time_ms, *quaternion, p, q, r, [0.0] * 4)
        if self._due("local_position", now_s):
            n, e, d = enu_to_ned(state.position_m)
            vn, ve, vd = enu_to_ned(state.velocity_mps)
            self.codec.messages.local_position_ned_send(time_ms, n, e, d, vn, ve, vd)
        if self._due("status", now_s):
            voltage_mv = int(self.battery_voltage() * 1000)
            self.codec.messages.sys_status_send(
                0, 0, 0, 100, voltage_mv, -1, self.battery_percent(), 0, 0, 0, 0, 0, 0
            )
            landed = (
                mavlink.MAV_LANDED_STATE_ON_GROUND
                if state.on_ground
                else mavlink.MAV_LANDED_STATE_IN_AIR
            )
            self.codec.messages.extended_sys_state_send(0, landed)
        if self._due("battery", now_s):
            cells = [int(self.battery_voltage() / 4 * 1000)] * 4 + [65535] * 6
            self.codec.messages.battery_status_send(
                0, 0, 0, 32767, cells, -1, -1, -1, self.battery_percent()
            )

    def battery_voltage(self) -> float:
        """A 4S pack sagging linearly with flight time."""
        used = min(1.0, self._flight_time_s / self._battery_capacity_s)
        return 16.8 - 2.0 * used

    def battery_percent(self) -> int:
        return round(100 * (1.0 - min(1.0, self._flight_time_s / self._battery_capacity_s)))
