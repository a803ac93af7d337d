"""The supervisor's MAVLink 2 link to one PX4: the asyncio shell around the sans-IO codec
(``codec``) and session (``session``), over the shared UDP transport (``transport``).

Like a MAVLink client on PX4's offboard/API link (docs/reference/px4-offboard.md §2–4): it
listens on a local UDP port (14540+i by default; PX4 sends there) and answers the address
the vehicle's datagrams come from; given the vehicle's address it also announces itself first (the
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
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from geometry.arrays import FloatArray
from geometry.frames import (
    enu_to_ned,
    euler_zyx_from_rotation,
    flu_to_frd,
    quaternion_from_rotation,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from supervisor.mavlink.codec import MavlinkCodec
from supervisor.mavlink.session import CommandAck, VehicleSession
from supervisor.mavlink.transport import Address, UdpTransport
from supervisor.vehicles.types import UavCommand, VehicleCommandError, VehicleView

FORCE_MAGIC = 21196


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


class MavlinkLink:
    """``supervisor.vehicles.link.VehicleLink`` over MAVLink 2 / UDP."""

    def __init__(self, config: LinkConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.config = config
        self.counters = LinkCounters()
        self._clock = clock
        self.codec = MavlinkCodec(config.source_system, config.source_component)
        self.session = VehicleSession(config.system_id, config.link_loss_s, clock())
        self._transport: UdpTransport | None = None
        self._peer: Address | None = config.vehicle_address
        self._tasks: list[asyncio.Task[None]] = []
        self._acks: dict[int, asyncio.Future[CommandAck]] = {}

    # ---- lifecycle ----------------------------------------------------------------------------
    async def start(self) -> None:
        c = self.config
        self._transport = await UdpTransport.open(
            (c.local_host, c.local_port), self.handle_datagram, self._peer
        )
        loop = asyncio.get_running_loop()
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

    @property
    def local_port(self) -> int:
        if self._transport is None:
            return self.config.local_port
        return self._transport.local_port

    def _flush(self) -> None:
        frames = self.codec.outgoing()
        if self._transport is not None:
            self._transport.send(frames)

    async def _heartbeats(self) -> None:
        while True:
            if self.session.heartbeat_due(self._clock()):
                self.codec.messages.heartbeat_send(
                    mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink.MAV_STATE_ACTIVE,
                )  # fmt: skip
                self._flush()
            await asyncio.sleep(max(0.0, self.session.next_heartbeat_s - self._clock()))

    # ---- receive ------------------------------------------------------------------------------
    def handle_datagram(self, data: bytes, sender: tuple[str, int]) -> None:
        """Decode and apply one datagram; bad data is counted, never raised."""
        now_s = self._clock()
        self.counters.datagrams += 1
        decoded = self.codec.decode(data)
        self.counters.bad_data += decoded.bad_data
        for message in decoded.messages:
            if not self.session.is_from_vehicle(message):
                self.counters.foreign += 1
                continue
            self.counters.messages += 1
            ack = self.session.receive(message, now_s)
            if self.config.vehicle_address is None:
                self._peer = sender  # answer where the vehicle talks from
                if self._transport is not None:
                    self._transport.peer = sender
            if ack is not None:
                future = self._acks.get(ack.command)
                if future is not None and not future.done():
                    future.set_result(ack)

    # ---- state --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.session.connected(self._clock())

    @property
    def px4_mode(self) -> str:
        return self.session.px4_mode(self._clock())

    def view(self) -> VehicleView:
        return self.session.view(self._clock())

    # ---- commands -------------------------------------------------------------------------------
    async def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG until acknowledged (``retries`` tries of ``ack_timeout_s``); raises
        ``VehicleCommandError`` naming the result, or the silence."""
        c = self.config
        if self._peer is None:
            raise VehicleCommandError("no link to the vehicle yet")
        padded = (*params, *([0.0] * (7 - len(params))))
        loop = asyncio.get_running_loop()
        self.session.await_ack(command)
        try:
            for attempt in range(c.retries):
                future: asyncio.Future[CommandAck] = loop.create_future()
                self._acks[command] = future
                try:
                    self.codec.messages.command_long_send(c.system_id, 1, command, attempt, *padded)
                    self._flush()
                    async with asyncio.timeout(c.ack_timeout_s):
                        ack = await future
                except TimeoutError:
                    continue
                finally:
                    self._acks.pop(command, None)
                if ack.accepted:
                    return
                raise VehicleCommandError(self.session.refusal(ack))
        finally:
            self.session.forget_ack(command)
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
            self.codec.messages.set_actuator_control_target_send(
                self.session.time_boot_ms(self._clock()) * 1000, 0, c.system_id, 1, controls
            )
        else:
            rates = flu_to_frd(command.body_rates_radps) if command.motors_on else np.zeros(3)
            if not np.all(np.isfinite(rates)):
                rates = np.zeros(3)
            self.codec.messages.set_attitude_target_send(
                self.session.time_boot_ms(self._clock()), c.system_id, 1, 128, [1.0, 0.0, 0.0, 0.0],
                float(rates[0]), float(rates[1]), float(rates[2]), thrust,
            )  # fmt: skip
        self._flush()
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
            self.codec.messages.vision_position_estimate_send(
                usec, north, east, down, roll, pitch, yaw
            )
        else:
            q = [float(v) for v in quaternion_from_rotation(R)]
            nan21 = [math.nan] * 21
            self.codec.messages.odometry_send(
                usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                north, east, down, q, math.nan, math.nan, math.nan,
                math.nan, math.nan, math.nan, nan21, nan21,
            )  # fmt: skip
        self._flush()
        self.counters.mocap_sent += 1
