"""The supervisor's MAVLink 2 link to one PX4: the asyncio shell around the sans-IO codec
(``codec``) and session (``session``), over the shared UDP transport (``transport``).

Like a MAVLink client on PX4's offboard/API link (docs/reference/px4-offboard.md §2–4): it
listens on a local UDP port (14540+i by default; PX4 sends there) and answers the address
the vehicle's datagrams come from; given the vehicle's address it also announces itself first (the
embedded simulator, whose ports are picked at run time). It sends a HEARTBEAT at 1 Hz as a
ground station (MAV_TYPE_GCS: PX4 does not count an ONBOARD_CONTROLLER as one, §5 item 10),
detects link loss when the vehicle's messages stop (any of them: PX4's heartbeat alone has
2 s gaps), answers PX4's TIMESYNC requests, reads and sets parameters (PARAM_VALUE echo
verified), sends commands and waits for their COMMAND_ACK (with retries; a refusal carries
PX4's own reason, from its EVENT), and sends exactly the setpoints the control loop hands
it — nothing repeats them, so when the loop stops the stream stops and PX4's offboard-loss
failsafe takes over.

Setpoints: ``actuator`` mode sends SET_ACTUATOR_CONTROL_TARGET group 0 (torques FRD
normalized by ``torque_max_nm``, thrust by ``thrust_max_n``: the vehicle's calibration);
``rates`` mode sends SET_ATTITUDE_TARGET with type_mask 128 (body rates FRD + thrust).
Mocap is forwarded as VISION_POSITION_ESTIMATE or ODOMETRY in NED/FRD, once per new frame,
stamped with the frame's capture time on the link's clock: the clock our TIMESYNC answers
carry, so PX4 maps the stamp onto its own time (§5 item 8).

Signing (``signing_key``; docs/reference/mavlink-signing.md): everything the link sends is
signed and every frame without our key's valid, fresh signature is refused and counted
(``unsigned``, ``bad_signature``, ``replayed``) before anything reads it — so a forged
heartbeat neither keeps the link alive nor changes the armed state or mode, and a forged
STATUSTEXT never reaches the operator. A PX4 without a key sends unsigned frames; then, and
only while its frames have never come signed, the link sends it SETUP_SIGNING with the key
(at most once per ``SETUP_SIGNING_PERIOD_S``, to the vehicle's known address only: the key
crosses the network in clear, MAVLink has no other way). PX4 signs from then on; arming
needs a connected link, so SETUP_SIGNING always precedes arming, as PX4 requires (it
refuses key changes while armed).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import logging
import math
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import (
    flu_to_frd,
)
from px4_mavlink.codec import MavlinkCodec, Refused, mavlink
from px4_mavlink.events import EventCatalog
from px4_mavlink.px4_messages import request_event_send
from px4_mavlink.signing import SigningKey, Verdict, signing_timestamp
from px4_mavlink.transport import Address, UdpTransport
from supervisor.mavlink.parameters import (
    ParameterClient,
    ParameterError,
    ParamNumber,
    ParamValue,
    format_value,
    param_id_bytes,
)
from supervisor.mavlink.session import (
    AUTOPILOT_COMPONENT,
    REASON_WAIT_S,
    CommandAck,
    EventRequest,
    TimesyncReply,
    VehicleSession,
)
from supervisor.mavlink.vision import VisionEncoder
from supervisor.vehicles.types import UavCommand, VehicleCommandError, VehicleView

log = logging.getLogger(__name__)

FORCE_MAGIC = 21196
SETUP_SIGNING_PERIOD_S = 1.0


@dataclass(frozen=True)
class LinkConfig:
    """One vehicle's link. ``local_port`` 0: any free port. ``vehicle_address`` (host,
    port), when known, is contacted first; otherwise the vehicle's first datagram tells.
    ``link_loss_s``: silence of the vehicle's autopilot (any message) that counts as lost.
    ``events_path``: the firmware's event definitions (``etc/extras/all_events.json.xz`` of
    the PX4 build), to put PX4's events in words; None: events are shown by their id.
    ``signing_key``: this vehicle's 32-byte MAVLink 2 signing key (None: no signing)."""

    system_id: int
    local_host: str = "127.0.0.1"
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
    events_path: str | None = None
    signing_key: bytes | None = field(default=None, repr=False)


def resolved(address: Address | None) -> Address | None:
    """``address`` with its host as the IP datagrams come from ("localhost" → 127.0.0.1)."""
    if address is None:
        return None
    return socket.gethostbyname(address[0]), address[1]


@dataclass
class LinkCounters:
    """Traffic seen on the link."""

    datagrams: int = 0
    messages: int = 0
    bad_data: int = 0
    foreign: int = 0
    impostor: int = 0  # the vehicle's system id, from an address not the vehicle's
    unsigned: int = 0  # signing on: a frame without a signature
    bad_signature: int = 0  # signing on: signed, not with the vehicle's key
    replayed: int = 0  # signing on: our key, but a timestamp already seen
    setup_signing_sent: int = 0
    setpoints_sent: int = 0
    thrust_clipped: int = 0
    torque_clipped: int = 0
    mocap_sent: int = 0
    mocap_skipped: int = 0  # a frame not newer than the last one sent
    timesync_answered: int = 0
    events_requested: int = 0


class MavlinkLink:
    """``supervisor.vehicles.link.VehicleLink`` over MAVLink 2 / UDP. ``clock`` [s] is the
    time base of everything the link stamps: liveness, TIMESYNC answers, mocap ``time_s``.
    ``catalog`` overrides ``config.events_path``."""

    def __init__(
        self,
        config: LinkConfig,
        clock: Callable[[], float] = time.monotonic,
        catalog: EventCatalog | None = None,
        sock: socket.socket | None = None,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        """``sock``: an already bound socket to use instead of binding ``config``'s port
        (``serve`` binds it, so that the mocap relay sends from the same address: PX4
        streams its link to the first address that talks to it, and only there).
        ``wall_clock``: Unix time [s], the base of signing timestamps."""
        self.config = config
        self.counters = LinkCounters()
        self._clock = clock
        self._wall_clock = wall_clock
        self.codec = MavlinkCodec(config.source_system, config.source_component)
        if config.signing_key is not None:
            self.codec.sign(SigningKey(config.signing_key), signing_timestamp(wall_clock()))
        self._vehicle_signed = False  # a frame of the vehicle came signed with our key
        self._next_setup_s = -math.inf
        self._warned: set[tuple[str, Address]] = set()
        if catalog is None and config.events_path:
            catalog = EventCatalog.load(config.events_path)
        self.session = VehicleSession(config.system_id, config.link_loss_s, clock(), catalog)
        self.parameters = ParameterClient()
        self._socket = sock
        self._transport: UdpTransport | None = None
        self._peer: Address | None = resolved(config.vehicle_address)
        self._impostors: set[tuple[str, int]] = set()
        self._tasks: list[asyncio.Task[None]] = []
        self._acks: dict[int, asyncio.Future[CommandAck]] = {}
        self._param_waiters: dict[str, asyncio.Future[ParamValue]] = {}
        self._text_arrived = asyncio.Event()
        self._vision = VisionEncoder(self.codec.messages, config.mocap_message)

    # ---- lifecycle ----------------------------------------------------------------------------
    async def start(self) -> None:
        c = self.config
        self._transport = await UdpTransport.open(
            (c.local_host, c.local_port), self.handle_datagram, self._peer, self._socket
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
            if self.codec.signing_key is not None:
                self.codec.keep_time(signing_timestamp(self._wall_clock()))
            if self.session.heartbeat_due(self._clock()):
                # A ground station: PX4 counts no ONBOARD_CONTROLLER heartbeat as a GCS.
                self.codec.messages.heartbeat_send(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
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
        if decoded.refused:
            self._refused(decoded.refused, sender, now_s)
        for message in decoded.messages:
            if not self.session.is_from_vehicle(message):
                self.counters.foreign += 1
                continue
            if not self._from_peer(sender, now_s):
                self.counters.impostor += 1
                continue
            self._vehicle_signed = self.codec.signing_key is not None
            self.counters.messages += 1
            texts = self.session.text_count
            ack = self.session.receive(message, now_s)
            if ack is not None:
                future = self._acks.get(ack.command)
                if future is not None and not future.done():
                    future.set_result(ack)
            if self.session.text_count != texts:
                self._text_arrived.set()
            if message.get_type() == "PARAM_VALUE":
                self._parameter_value(message)
        self._answer()

    def _from_peer(self, sender: tuple[str, int], now_s: float) -> bool:
        """Whether the vehicle's message from ``sender`` is the vehicle's. The link keeps to
        one address, as PX4 does: the configured one, else the first that spoke — until the
        vehicle has been silent for ``link_loss_s``. Anyone else sending with the vehicle's
        system id (a second simulator, a misconfigured vehicle) is ignored: it must never
        change what the link believes, nor where its commands go."""
        if sender == self._peer:
            return True
        if self.config.vehicle_address is None and (
            self._peer is None or not self.session.connected(now_s)
        ):
            if self._peer is not None:
                log.warning("vehicle %d now talks from %s:%d", self.config.system_id, *sender)
            self._peer = sender  # answer where the vehicle talks from
            if self._transport is not None:
                self._transport.peer = sender
            return True
        if sender not in self._impostors:
            self._impostors.add(sender)
            log.warning(
                "vehicle %d: ignoring messages with its system id from %s:%d (it is at %s)",
                self.config.system_id,
                *sender,
                self._peer,
            )
        return False

    def _refused(self, refused: tuple[Refused, ...], sender: Address, now_s: float) -> None:
        """Count the frames signing refused; a vehicle that has never signed and sends
        unsigned frames from its address has no key yet: send it ours."""
        counters = self.counters
        for frame in refused:
            if frame.verdict is Verdict.UNSIGNED:
                counters.unsigned += 1
            elif frame.verdict is Verdict.BAD_SIGNATURE:
                counters.bad_signature += 1
            else:
                counters.replayed += 1
            self._warn_once(frame, sender)
        from_vehicle = any(
            f.verdict is Verdict.UNSIGNED and f.system == self.config.system_id for f in refused
        )
        if from_vehicle and not self._vehicle_signed and sender == self._peer:
            self._setup_signing(now_s)

    def _warn_once(self, frame: Refused, sender: Address) -> None:
        key = (frame.verdict.value, sender)
        if key in self._warned or len(self._warned) > 64:
            return
        self._warned.add(key)
        log.warning(
            "vehicle %d: refused a %s %s of system %d from %s:%d%s",
            self.config.system_id,
            frame.verdict.value.replace("_", " "),
            frame.message_type,
            frame.system,
            *sender,
            " (no vehicle address to send the key to: set vehicles.addresses)"
            if frame.verdict is Verdict.UNSIGNED and self._peer is None
            else "",
        )

    def _setup_signing(self, now_s: float) -> None:
        """SETUP_SIGNING with our key to the vehicle's autopilot (rate-limited)."""
        key = self.codec.signing_key
        if key is None or now_s < self._next_setup_s:
            return
        self._next_setup_s = now_s + SETUP_SIGNING_PERIOD_S
        self.codec.messages.setup_signing_send(
            self.config.system_id, AUTOPILOT_COMPONENT, list(key.secret),
            self.codec.signing_timestamp,
        )  # fmt: skip
        self.counters.setup_signing_sent += 1
        self._flush()

    def _parameter_value(self, message: object) -> None:
        value = self.parameters.receive(message)
        if value is not None:
            waiter = self._param_waiters.get(value.name)
            if waiter is not None and not waiter.done():
                waiter.set_result(value)

    def _answer(self) -> None:
        """Send what the session says the vehicle expects back: at once, since PX4 uses a
        TIMESYNC answer only when its round trip is under 10 ms (``Timesync.cpp``)."""
        replies = self.session.replies()
        for reply in replies:
            if isinstance(reply, TimesyncReply):
                self.codec.messages.timesync_send(reply.tc1_ns, reply.ts1_ns)
                self.counters.timesync_answered += 1
            elif isinstance(reply, EventRequest):
                request_event_send(
                    self.codec.messages, reply.target_system, reply.target_component,
                    reply.first_sequence, reply.last_sequence,
                )  # fmt: skip
                self.counters.events_requested += 1
        if replies:
            self._flush()

    # ---- state --------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self.session.connected(self._clock())

    @property
    def px4_mode(self) -> str:
        return self.session.px4_mode(self._clock())

    def view(self) -> VehicleView:
        view = self.session.view(self._clock())
        c = self.counters
        refused = {
            "impostor": c.impostor,
            "unsigned": c.unsigned,
            "bad_signature": c.bad_signature,
            "replayed": c.replayed,
        }
        return dataclasses.replace(view, refused=refused)

    # ---- commands -------------------------------------------------------------------------------
    async def command(self, command: int, *params: float) -> None:
        """COMMAND_LONG until acknowledged (``retries`` tries of ``ack_timeout_s``); raises
        ``VehicleCommandError`` naming the result, or the silence."""
        c = self.config
        if self._peer is None:
            raise VehicleCommandError("no link to the vehicle yet")
        padded = (*params, *([0.0] * (7 - len(params))))
        loop = asyncio.get_running_loop()
        self.session.await_ack(command, *padded)
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
                await self._await_reason(ack)
                raise VehicleCommandError(self.session.refusal(ack))
        finally:
            self.session.forget_ack(command)
        raise VehicleCommandError(f"command {command}: no acknowledgement after {c.retries} tries")

    async def _await_reason(self, ack: CommandAck) -> None:
        """Give PX4's reason for a refusal time to arrive: its EVENT (and STATUSTEXT) follow
        the ACK by 2–9 ms (measured on v1.15.4), so wait up to ``REASON_WAIT_S`` (50 ms)
        for a text received after the ACK."""
        self._text_arrived.clear()
        if self.session.heard_after(ack):
            return
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(REASON_WAIT_S):
                await self._text_arrived.wait()

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

    async def land(self) -> None:
        await self.command(176, 1.0, 4.0, 6.0)  # AUTO.LAND

    # ---- parameters ----------------------------------------------------------------------------
    async def _parameter_exchange(self, name: str, send: Callable[[], None]) -> ParamValue | None:
        """Send once with ``send`` and wait ``ack_timeout_s`` for ``name``'s PARAM_VALUE."""
        future: asyncio.Future[ParamValue] = asyncio.get_running_loop().create_future()
        self._param_waiters[name] = future
        self.parameters.await_value(name)
        try:
            send()
            self._flush()
            async with asyncio.timeout(self.config.ack_timeout_s):
                return await future
        except TimeoutError:
            return None
        finally:
            self._param_waiters.pop(name, None)
            self.parameters.forget(name)

    async def read_parameter(self, name: str) -> ParamNumber:
        """The vehicle's value of parameter ``name`` (int for integer parameters): a
        PARAM_REQUEST_READ until answered (``retries`` tries of ``ack_timeout_s``); raises
        ``VehicleCommandError`` on silence."""
        c = self.config
        if self._peer is None:
            raise VehicleCommandError("no link to the vehicle yet")
        try:
            param_id = param_id_bytes(name)
        except ParameterError as error:
            raise VehicleCommandError(str(error)) from error
        for _ in range(c.retries):
            value = await self._parameter_exchange(
                name,
                lambda: self.codec.messages.param_request_read_send(
                    c.system_id, AUTOPILOT_COMPONENT, param_id, -1
                ),
            )
            if value is not None:
                return value.value
        raise VehicleCommandError(f"parameter {name}: no answer after {c.retries} tries")

    async def set_parameter(self, name: str, value: ParamNumber) -> None:
        """Set parameter ``name`` to ``value`` and check PX4's echo (a PARAM_VALUE) says the
        same, retrying on silence or a different echo like commands. The parameter is read
        first if its type is not known yet (PX4 copies a PARAM_SET's four bytes whatever type
        it claims, so the value must be encoded in the parameter's own type). Raises
        ``VehicleCommandError`` naming the mismatch or the silence."""
        c = self.config
        if name not in self.parameters.known:
            await self.read_parameter(name)
        try:
            request = self.parameters.set_request(name, value)
            param_id = param_id_bytes(name)
        except ParameterError as error:
            raise VehicleCommandError(str(error)) from error
        problem = f"parameter {name}: no echo after {c.retries} tries"
        for _ in range(c.retries):
            echoed = await self._parameter_exchange(
                name,
                lambda: self.codec.messages.param_set_send(
                    c.system_id, AUTOPILOT_COMPONENT, param_id, request.raw, request.param_type
                ),
            )
            if echoed is None:
                continue
            mismatch = self.parameters.mismatch(request, echoed)
            if mismatch is None:
                return
            problem = f"parameter {mismatch} (set {format_value(request.value)} refused?)"
        raise VehicleCommandError(problem)

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
        """The vehicle's pose (arena ENU, FLU body → ENU quaternion) in NED/FRD, captured at
        ``time_s`` — the camera's capture time *on this link's clock* [s] (the caller maps
        QTM's timestamp onto it). Sent once per frame (``supervisor.mavlink.vision``); its
        ``usec`` is in the time base of our TIMESYNC answers, so PX4 maps it onto its own."""
        if self._vision.queue(position_m, quaternion, time_s):
            self._flush()
        self.counters.mocap_sent = self._vision.sent
        self.counters.mocap_skipped = self._vision.skipped
