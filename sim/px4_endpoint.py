"""A simulated PX4's MAVLink 2 endpoint on UDP, driving one airframe of the plant.

PX4 SITL's conventions (docs/reference/px4-offboard.md §5, ../shared/reference/
px4-observed.md): instance i (0-based) sends from UDP 14580+i to the offboard/API client at
14540+i; system id MAV_SYS_ID (i+1 unless set), component 1 (autopilot). It streams
HEARTBEAT (1 Hz, jittered: ``HeartbeatSchedule``), ATTITUDE and ATTITUDE_QUATERNION
(50 Hz), LOCAL_POSITION_NED (30 Hz, NED), TIMESYNC requests (10 Hz), SYS_STATUS and
EXTENDED_SYS_STATE (5 Hz), BATTERY_STATUS (1 Hz), CURRENT_MODE (0.5 Hz),
CURRENT_EVENT_SEQUENCE (every 3 s, as measured), and EVENTs as they happen (ids and
argument layouts from ``sim/px4_events.json``, the firmware's). It answers every
COMMAND_LONG with COMMAND_ACK (3 UNSUPPORTED when unknown), AUTOPILOT_VERSION and
CURRENT_MODE when asked, TIMESYNC requests, REQUEST_EVENT, and the parameter protocol.

Measured on v1.15.4 and done the same way here:

* **STATUSTEXT** goes only to a link on which a ground station (HEARTBEAT type GCS) was
  heard within 3 s, each text ending in a tab (PX4's mark of a text that is also an event).
  Companions (ONBOARD_CONTROLLER, as the supervisor) get none: events only.
* **Parameters**: PARAM_REQUEST_READ by index when ``param_index`` ≥ 0 (even with a name),
  else by name; PARAM_REQUEST_LIST sends all; PARAM_SET is echoed by PARAM_VALUE (twice when
  the value changed: the answer and the change notice); an unknown name, an index out of
  range, a PARAM_SET whose type is not the parameter's, or a target system other than ours
  get no answer. INT32 values travel bytewise in the float field.
* **Partner**: telemetry goes to the configured client port until a datagram arrives, then
  to the first sender for good; later senders are heard but get nothing.
* **Signing** (docs/reference/mavlink-signing.md; PX4 v1.15.4 has none, this is PX4's
  current behaviour, v1.18/main ``mavlink_sign_control.cpp``): without a key everything is
  accepted and nothing signed. SETUP_SIGNING addressed to us sets the key — any link, but
  while a key is held only a frame signed with it gets through (so only its holder can
  change or clear it), never while armed; the same key again keeps the later timestamp;
  an all-zero key and timestamp clears it. With a key every frame we send is signed
  (link id ``SIGNING_LINK_ID``) and a frame that is unsigned, signed with another key or
  replayed is refused and counted, except the unsigned HEARTBEAT, RADIO_STATUS,
  ADSB_VEHICLE and COLLISION PX4 lets through. The key and timestamp survive a reboot (PX4
  keeps them on its SD card).
* **TIMESYNC**: a client's request (tc1 0) is answered with tc1 = our clock [ns] and ts1
  echoed; answers to our requests feed ``Timesync``, which maps vision timestamps
  (VISION_POSITION_ESTIMATE.usec, ODOMETRY.time_usec) onto our clock once converged.
* **Reboot** (the world's ``px4_reboot`` fault, ``sim.faults``): ``power_off`` stops the
  motors and the link at once; ``boot`` starts again as at power-on — a fresh model in its
  boot mode, disarmed, with the parameters held before (PX4 stores them), its clock (time
  since boot), TIMESYNC, event sequence and partner starting afresh; the first event after
  it is announced by CURRENT_EVENT_SEQUENCE with the reset flag (as v1.15.4 does, measured
  for ``supervisor.mavlink.session``: that message with sequence 0, then EVENT 0).

The ``Px4Model`` holds the behaviour; this module moves datagrams. ``handle_datagram`` is
the whole receive path (also what the fuzzer drives). Our clock is the time since boot:
the world time minus the world time of the last boot (0 until a reboot).
"""

from __future__ import annotations

import dataclasses
import math
import random
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from geometry.frames import (
    enu_to_ned,
    euler_zyx_from_rotation,
    flu_to_frd,
    quaternion_from_rotation,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.events import EventCatalog, EventDefinition, encode_event_arguments
from px4_mavlink.px4_messages import (
    MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET,
    current_event_sequence_send,
    event_send,
    response_event_error_send,
)
from px4_mavlink.signing import SigningKey, Verdict
from px4_mavlink.transport import Address, UdpTransport
from sim.ports import AirframePort, AirframeState
from sim.px4 import ParamSpec, ParamType, Px4Event, Px4Model, Px4Params, Timesync

API_CLIENT_PORT = 14540
API_LOCAL_PORT = 14580
AUTOPILOT_VERSION_ID = 148
CURRENT_MODE_ID = 436
CATALOG_PATH = Path(__file__).with_name("px4_events.json")
"""The events this simulated PX4 sends (libevents format): what a receiver decodes them by."""
CAPABILITIES = (
    mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
    | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT  # PX4 sets both (measured 0xE8FF)
    | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    | mavlink.MAV_PROTOCOL_CAPABILITY_FLIGHT_TERMINATION
)
STREAM_PERIODS_S = {
    "attitude": 0.02,
    "local_position": 1.0 / 30.0,
    "timesync": 0.1,
    "status": 0.2,
    "battery": 1.0,
    "current_mode": 2.0,
    "event_sequence": 3.0,
}
GCS_TIMEOUT_S = 3.0  # a ground station counts as connected this long after its heartbeat
EVENT_BUFFER = 32  # events kept for REQUEST_EVENT
STATUSTEXT_LEN = 50
NO_EVENT_YET = 0xFFFF  # CURRENT_EVENT_SEQUENCE before the first event (the next is 0)
SIGNING_LINK_ID = 0  # PX4 signs with its MAVLink instance number; this is our one link
UNSIGNED_ALLOWED = frozenset(
    {
        mavlink.MAVLINK_MSG_ID_HEARTBEAT,
        mavlink.MAVLINK_MSG_ID_RADIO_STATUS,
        mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE,
        mavlink.MAVLINK_MSG_ID_COLLISION,
    }
)
"""What PX4 accepts unsigned while it signs (``unsigned_messages`` in its sign control)."""


class HeartbeatSchedule:
    """When PX4 sends its 1 Hz HEARTBEAT, on a loaded machine: each beat leaves a little
    after it is due (0–20 ms), now and then (3 %) 0.3–0.8 s late — gaps up to 1.8 s, as the
    1.77 s and 2.01 s measured while the other streams kept their rates. Its scheduling
    rule is PX4's (``MavlinkStream::update``): a beat less than 1.5 periods after the last
    keeps the fixed rate (the next is due one period after the last *due* time), a later
    one restarts the schedule. Seeded; ``rng`` None: no jitter."""

    PERIOD_S = 1.0
    LATE_PROBABILITY = 0.03
    DELAY_S = (0.0, 0.02)
    LATE_DELAY_S = (0.3, 0.8)

    def __init__(self, rng: random.Random | None) -> None:
        self._rng = rng
        self._anchor_s: float | None = None
        self._delay_s = 0.0

    def restart(self) -> None:
        """The next ``due`` sends at once and anchors the schedule again (after a boot)."""
        self._anchor_s = None

    def _draw(self) -> float:
        if self._rng is None:
            return 0.0
        late = self._rng.random() < self.LATE_PROBABILITY
        low, high = self.LATE_DELAY_S if late else self.DELAY_S
        return self._rng.uniform(low, high)

    def due(self, now_s: float) -> bool:
        """Whether a heartbeat goes out at ``now_s``; a True answer counts it as sent."""
        if self._anchor_s is None:
            self._anchor_s, self._delay_s = now_s, self._draw()
            return True
        if now_s < self._anchor_s + self.PERIOD_S + self._delay_s:
            return False
        late = now_s - self._anchor_s >= 1.5 * self.PERIOD_S
        self._anchor_s = now_s if late else self._anchor_s + self.PERIOD_S
        self._delay_s = self._draw()
        return True


def wire_value(spec: ParamSpec, value: float) -> float:
    """The PARAM_VALUE float field carrying ``value`` (INT32: its four bytes)."""
    if spec.type is ParamType.INT32:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def from_wire(spec: ParamSpec, raw: float) -> float:
    """The value a PARAM_SET's float field carries for ``spec``."""
    if spec.type is ParamType.INT32:
        return int(struct.unpack("<i", struct.pack("<f", raw))[0])
    return float(raw)


def _text(raw: Any) -> str:
    """A char[] field as text (pymavlink gives str or bytes)."""
    text = raw.decode("ascii", errors="replace") if isinstance(raw, bytes | bytearray) else str(raw)
    return text.split("\x00", 1)[0]


@dataclass
class EndpointCounters:
    """What arrived: datagrams, messages parsed, bad data (failed CRC, garbage), frames
    signing refused (by why), messages handled and messages of kinds this endpoint
    ignores."""

    datagrams: int = 0
    messages: int = 0
    bad_data: int = 0
    unsigned: int = 0
    bad_signature: int = 0
    replayed: int = 0
    handled: int = 0
    ignored: int = 0
    per_type: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class SentEvent:
    """An EVENT as sent (kept for REQUEST_EVENT)."""

    sequence: int
    event_id: int
    time_boot_ms: int
    log_levels: int
    arguments: bytes


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
        catalog: EventCatalog | None = None,
    ) -> None:
        self.instance = instance
        self.airframe = airframe
        params = params or Px4Params()
        self.model = Px4Model(system_id=instance + 1, params=params)
        self.host = host
        self.local_port = API_LOCAL_PORT + instance if local_port is None else local_port
        self.client_port = API_CLIENT_PORT + instance if client_port is None else client_port
        self.counters = EndpointCounters()
        self.texts_sent: deque[str] = deque(maxlen=64)
        """The STATUSTEXTs sent (only while a ground station listens)."""
        self.events_sent: deque[tuple[str, str]] = deque(maxlen=256)
        """(event name, its text) of every EVENT sent."""
        self.catalog = catalog or EventCatalog.load(CATALOG_PATH)
        self._definitions: dict[str, EventDefinition] = {}
        self.codec = MavlinkCodec(system=self.model.system_id, component=1)
        self.timesync = Timesync()
        rng = random.Random(params.seed * 1009 + instance) if params.heartbeat_jitter else None
        self.heartbeats = HeartbeatSchedule(rng)
        self.outbox: deque[bytes] | None = None
        """Set to a deque to collect the frames instead of sending them (tests)."""
        self.datagram_filter: Callable[[bool], bool] | None = None
        """Asked for every datagram, with True for one arriving and False for one leaving;
        False drops it — the simulated world's fault injection (``sim.faults``)."""
        self.powered = True
        """False from ``power_off`` to ``boot``: motors off, nothing sent or handled."""
        self._boot_s = 0.0  # world time of the last boot: our clock counts from it
        self._announce_reset = False
        self._transport: UdpTransport | None = None
        self._client_address: Address | None = None
        self._partner: Address | None = None
        self._next_send_s = dict.fromkeys(STREAM_PERIODS_S, 0.0)
        self._now_s = 0.0
        self._gcs_heard_s = -math.inf
        self._event_sequence = 0
        self._sent_events: deque[SentEvent] = deque(maxlen=EVENT_BUFFER)
        self._statustext_id = 0
        self._battery_capacity_s = battery_capacity_s
        self._flight_time_s = 0.0
        self._signing_key: SigningKey | None = None  # kept across reboots (the SD card)
        self._handlers: dict[str, Callable[[Any, float], bool]] = {
            "SET_ATTITUDE_TARGET": self._attitude_target,
            "SET_ACTUATOR_CONTROL_TARGET": self._actuator_target,
            "COMMAND_LONG": self._command,
            "COMMAND_INT": self._command,
            "SET_MODE": self._set_mode,
            "VISION_POSITION_ESTIMATE": self._vision,
            "ODOMETRY": self._vision,
            "HEARTBEAT": self._heartbeat,
            "TIMESYNC": self._timesync,
            "PARAM_REQUEST_READ": self._param_read,
            "PARAM_REQUEST_LIST": self._param_list,
            "PARAM_SET": self._param_set,
            "REQUEST_EVENT": self._request_event,
            "SETUP_SIGNING": self._setup_signing,
        }

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
        if not self.handle_datagram(data, self.clock_s()):
            return
        # PX4's UDP link latches the first sender as its partner and streams to it for good
        # (``partner IP`` in its log; measured: a second sender's messages are handled, but
        # it gets nothing, whichever of the two spoke first). ``latch_partner`` False: the
        # latest sender instead (this simulator's old behaviour, not PX4's).
        if self._partner is None:
            self._partner = sender
            self.client_address = sender
            self.model.request_report()  # the new partner gets the arming-check report
        elif not self.model.params.latch_partner:
            self.client_address = sender

    def _flush(self) -> None:
        frames = self.codec.outgoing()
        keep = self.datagram_filter
        if keep is not None:
            frames = [frame for frame in frames if keep(False)]
        if self.outbox is not None:
            self.outbox.extend(frames)
        elif self._transport is not None:
            self._transport.send(frames)

    def describe(self) -> str:
        return f"{self.host}:{self.local_port}"

    def clock_s(self) -> float:
        """Our clock at the last ``step``: seconds since boot (received messages are
        stamped with it)."""
        return self._now_s

    @property
    def armed(self) -> bool:
        """Whether the motors are armed."""
        return self.powered and self.model.armed

    # ---- reboot and reset (the world's faults) ---------------------------------------------
    def _fresh_model(self) -> Px4Model:
        """A model booting with the parameters this one holds (PX4 stores every change), so
        the ones read only at boot (MAV_SYS_ID, EKF2_EV_DELAY, ...) take effect now."""
        held = tuple((spec.name, value) for spec, value in self.model.parameters.items())
        params = dataclasses.replace(self.model.params, boot_parameters=held)
        return Px4Model(system_id=self.instance + 1, params=params)

    def power_off(self) -> None:
        """Power lost (a reboot begins): motors off now, nothing sent or handled."""
        self.powered = False
        self.airframe.command(0.0, np.zeros(3))
        self.codec.outgoing()  # what was queued dies with the power

    def boot(self, world_s: float) -> None:
        """Boot at world time ``world_s`` as at power-on (see the module's docstring)."""
        self.model = self._fresh_model()
        timestamp = self.codec.signing_timestamp
        self.codec = MavlinkCodec(system=self.model.system_id, component=1)
        self.codec.sign(self._signing_key, timestamp)
        self.timesync = Timesync()
        self.heartbeats.restart()
        self._next_send_s = dict.fromkeys(STREAM_PERIODS_S, 0.0)
        self._boot_s = world_s
        self._now_s = 0.0
        self._gcs_heard_s = -math.inf
        self._event_sequence = 0
        self._sent_events.clear()
        self._statustext_id = 0
        self._announce_reset = True
        self._partner = None
        self.client_address = (self.host, self.client_port)  # as at start: PX4's remote port
        self.powered = True

    def reset_model(self) -> None:
        """Back to the boot state without a reboot (the world's reset, disarmed): a fresh
        model with the parameters held; link, clock and event sequence go on."""
        self.model = self._fresh_model()

    # ---- receive ------------------------------------------------------------------------------
    @property
    def client_address(self) -> Address | None:
        """Where telemetry goes: the configured client port until a client talks to us,
        then that first client (``partner``)."""
        return self._client_address

    @client_address.setter
    def client_address(self, address: Address) -> None:
        self._client_address = address
        if self._transport is not None:
            self._transport.peer = address

    def handle_datagram(self, data: bytes, now_s: float) -> bool:
        """Parse and act on one datagram; malformed input is counted, never raised.
        Returns whether it held at least one valid message. While powered off, or when the
        world's faults drop it (``datagram_filter``), it never arrived."""
        if not self.powered or (
            self.datagram_filter is not None and not self.datagram_filter(True)
        ):
            return False
        self.counters.datagrams += 1
        decoded = self.codec.decode(data)
        self.counters.bad_data += decoded.bad_data
        for refused in decoded.refused:
            if refused.verdict is Verdict.UNSIGNED:
                self.counters.unsigned += 1
            elif refused.verdict is Verdict.BAD_SIGNATURE:
                self.counters.bad_signature += 1
            else:
                self.counters.replayed += 1
        for message in decoded.messages:
            kind = message.get_type()
            self.counters.messages += 1
            self.counters.per_type[kind] = self.counters.per_type.get(kind, 0) + 1
            handler = self._handlers.get(kind)
            try:
                handled = handler(message, now_s) if handler is not None else False
            except (ValueError, TypeError, IndexError, OverflowError, struct.error):
                self.counters.bad_data += 1
                continue
            if handled:
                self.counters.handled += 1
            else:
                self.counters.ignored += 1
        self._flush()
        return bool(decoded.messages)

    def _for_me(self, message: Any) -> bool:
        target = int(getattr(message, "target_system", 0))
        return target in (0, self.model.system_id)

    def _addressed(self, message: Any) -> bool:
        """PX4's test for parameter and event requests: our system exactly, our component
        or all components."""
        return bool(
            message.target_system == self.model.system_id and message.target_component in (0, 1)
        )

    def _attitude_target(self, message: Any, now_s: float) -> bool:
        # Body rates + thrust: attitude ignored (128), rates not ignored (1, 2 clear).
        if not self._for_me(message) or not message.type_mask & 128 or message.type_mask & 3:
            return False
        rates = np.array([message.body_roll_rate, message.body_pitch_rate, message.body_yaw_rate])
        self.model.rate_setpoint(rates, float(message.thrust), now_s)
        return True

    def _actuator_target(self, message: Any, now_s: float) -> bool:
        if not self._for_me(message) or message.group_mlx != 0:
            return False
        self.model.actuator_setpoint(np.asarray(message.controls, dtype=float), now_s)
        return True

    def _set_mode(self, message: Any, now_s: float) -> bool:
        if message.target_system != self.model.system_id:
            return False
        main = (message.custom_mode >> 16) & 0xFF
        sub = (message.custom_mode >> 24) & 0xFF
        self.model.set_mode(message.base_mode, main, sub, now_s, self.airframe.state())
        return True

    def _vision(self, message: Any, now_s: float) -> bool:
        usec = message.usec if message.get_type() == "VISION_POSITION_ESTIMATE" else None
        usec = message.time_usec if usec is None else usec
        self.model.vision(now_s, self.timesync.local_time_s(int(usec)))
        return True

    def _heartbeat(self, message: Any, now_s: float) -> bool:
        if message.type == mavlink.MAV_TYPE_GCS:
            self._gcs_heard_s = now_s
        return True

    def _setup_signing(self, message: Any, now_s: float) -> bool:
        """A new key (or none): refused while armed. While a key is held the codec let
        this message through only if it was signed with that key."""
        if not self._addressed(message) or self.model.armed:
            return False
        secret = bytes(message.secret_key)
        timestamp = int(message.initial_timestamp)
        held = self._signing_key
        if not any(secret) and timestamp == 0:
            self._signing_key = None
            self.codec.sign(None)
            return True
        key = SigningKey(secret, SIGNING_LINK_ID, UNSIGNED_ALLOWED)
        if held is not None and held.secret == secret:
            timestamp = max(timestamp, self.codec.signing_timestamp)
        self._signing_key = key
        self.codec.sign(key, timestamp)
        return True

    @property
    def signing(self) -> bool:
        """Whether this PX4 holds a signing key (signs, and refuses the unsigned)."""
        return self._signing_key is not None

    def _timesync(self, message: Any, now_s: float) -> bool:
        now_ns = round(now_s * 1e9)
        if message.tc1 == 0:  # a request: our clock, their stamp echoed
            self.codec.messages.timesync_send(now_ns, message.ts1)
        else:
            self.timesync.update(now_ns, int(message.tc1), int(message.ts1))
        return True

    def _command(self, message: Any, now_s: float) -> bool:
        if not self._for_me(message):
            return False
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
        requested = round(params[0]) if message.command == 512 else None
        if message.command == 520 or requested == AUTOPILOT_VERSION_ID:
            self._send_version()
        elif requested == CURRENT_MODE_ID:
            self._send_current_mode()
        return True

    # ---- parameters -------------------------------------------------------------------------
    def _send_param(self, spec: ParamSpec) -> None:
        table = self.model.parameters
        self.codec.messages.param_value_send(
            spec.name.encode(), wire_value(spec, table.get(spec.name)), int(spec.type),
            len(table), table.index(spec.name),
        )  # fmt: skip

    def _param_read(self, message: Any, now_s: float) -> bool:
        if not self._addressed(message):
            return False
        table = self.model.parameters
        index = int(message.param_index)
        if index >= 0:
            spec = table.specs[index] if index < len(table) else None
        else:
            spec = table.spec(_text(message.param_id))
        if spec is not None:
            self._send_param(spec)
        return True

    def _param_list(self, message: Any, now_s: float) -> bool:
        if not self._addressed(message):
            return False
        for spec in self.model.parameters.specs:
            self._send_param(spec)
        return True

    def _param_set(self, message: Any, now_s: float) -> bool:
        if not self._addressed(message):
            return False
        table = self.model.parameters
        spec = table.spec(_text(message.param_id))
        if spec is None or int(message.param_type) != int(spec.type):
            return True  # PX4 neither answers nor sets (measured)
        changed = table.set(spec.name, from_wire(spec, float(message.param_value)))
        self._send_param(spec)
        if changed:
            self._send_param(spec)  # PX4's notice of a changed parameter follows the answer
        return True

    # ---- events -------------------------------------------------------------------------------
    def _definition(self, name: str) -> EventDefinition:
        definition = self._definitions.get(name)
        if definition is None:
            definition = self._definitions[name] = self.catalog.find(name)
        return definition

    def _send_event(self, event: Px4Event) -> None:
        definition = self._definition(event.name)
        arguments = encode_event_arguments(
            self.catalog, definition.event_id, [int(v) for v in event.values]
        )
        sent = SentEvent(
            self._event_sequence,
            definition.event_id,
            int(event.time_s * 1000) & 0xFFFFFFFF,
            event.log_levels,
            arguments,
        )
        self._event_sequence = (self._event_sequence + 1) & 0xFFFF
        self._sent_events.append(sent)
        if self._announce_reset:
            self._announce_reset = False
            current_event_sequence_send(
                self.codec.messages, sent.sequence, MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET
            )
        self._emit(sent)
        text = self.catalog.text(definition.event_id, arguments)
        self.events_sent.append((event.name, text))
        if definition.group == "default" and self._gcs_connected():
            self._send_statustext(event.log_levels & 0x0F, text)

    def _emit(self, sent: SentEvent) -> None:
        event_send(
            self.codec.messages, 0, 0, sent.event_id, sent.time_boot_ms, sent.sequence,
            sent.log_levels, sent.arguments,
        )  # fmt: skip

    def _gcs_connected(self) -> bool:
        return self._now_s - self._gcs_heard_s <= GCS_TIMEOUT_S

    def _send_statustext(self, severity: int, text: str) -> None:
        """PX4's STATUSTEXT: the text and a tab, in 50-byte chunks under one id."""
        raw = (text + "\t").encode()
        chunks = [raw[k : k + STATUSTEXT_LEN] for k in range(0, len(raw), STATUSTEXT_LEN)]
        for seq, chunk in enumerate(chunks):
            self.codec.messages.statustext_send(severity, chunk, self._statustext_id, seq)
        self._statustext_id = (self._statustext_id + 1) & 0xFFFF
        self.texts_sent.append(text)

    def _request_event(self, message: Any, now_s: float) -> bool:
        """Re-send requested events still held; for the first one gone, an error naming
        the oldest held (then stop, as PX4)."""
        if not self._addressed(message):
            return False
        held = {sent.sequence: sent for sent in self._sent_events}
        span = ((message.last_sequence - message.first_sequence) & 0xFFFF) + 1
        for k in range(min(span, EVENT_BUFFER)):
            sequence = (message.first_sequence + k) & 0xFFFF
            sent = held.get(sequence)
            if sent is None:
                oldest = self._sent_events[0].sequence if self._sent_events else sequence
                response_event_error_send(
                    self.codec.messages, message.get_srcSystem(), message.get_srcComponent(),
                    sequence, oldest,
                )  # fmt: skip
                break
            self._emit(sent)
        return True

    # ---- send -----------------------------------------------------------------------------------
    def _send_version(self) -> None:
        version = (1 << 24) | (15 << 16) | (4 << 8) | 255  # 1.15.4, release
        self.codec.messages.autopilot_version_send(
            CAPABILITIES, version, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1000 + self.instance
        )

    def _send_current_mode(self) -> None:
        model = self.model
        self.codec.messages.current_mode_send(
            model.standard_mode, model.custom_mode, model.intended_custom_mode
        )

    def step(self, world_s: float) -> None:
        """Run the flight stack to world time ``world_s``: command the airframe, send due
        telemetry (powered off: motors off, nothing else)."""
        if not self.powered:
            self.airframe.command(0.0, np.zeros(3))
            return
        now_s = max(0.0, world_s - self._boot_s)
        dt = max(0.0, now_s - self._now_s)
        self._now_s = now_s
        state = self.airframe.state()
        if self.model.armed and not state.on_ground:
            self._flight_time_s += dt
        thrust_n, torque_nm = self.model.step(now_s, state)
        self.airframe.command(thrust_n, torque_nm)
        while self.model.events:
            self._send_event(self.model.events.popleft())
        self._send_telemetry(now_s, state)
        self._flush()

    def _due(self, stream: str, now_s: float) -> bool:
        if now_s < self._next_send_s[stream]:
            return False
        self._next_send_s[stream] = max(self._next_send_s[stream] + STREAM_PERIODS_S[stream], now_s)
        return True

    def _send_heartbeat(self) -> None:
        model = self.model
        if model.armed:
            failsafe = model.failsafe is not None
            status = mavlink.MAV_STATE_CRITICAL if failsafe else mavlink.MAV_STATE_ACTIVE
        else:
            status = mavlink.MAV_STATE_STANDBY
        self.codec.messages.heartbeat_send(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, model.base_mode,
            model.custom_mode, status,
        )  # fmt: skip

    def _send_telemetry(self, now_s: float, state: AirframeState) -> None:
        if self.heartbeats.due(now_s):
            self._send_heartbeat()
        if self._due("attitude", now_s):
            self._send_attitude(state, now_s)
        if self._due("local_position", now_s):
            n, e, d = enu_to_ned(state.position_m)
            vn, ve, vd = enu_to_ned(state.velocity_mps)
            self.codec.messages.local_position_ned_send(self._time_ms(now_s), n, e, d, vn, ve, vd)
        if self._due("timesync", now_s):
            ts1_ns = int(now_s * 1e6) * 1000  # PX4's clock has µs resolution
            self.timesync.sent(ts1_ns)
            self.codec.messages.timesync_send(0, ts1_ns)
        if self._due("status", now_s):
            self._send_status(state)
        if self._due("battery", now_s):
            cells = [int(self.battery_voltage() / 4 * 1000)] * 4 + [65535] * 6
            self.codec.messages.battery_status_send(
                0, 0, 0, 32767, cells, -1, -1, -1, self.battery_percent()
            )
        if self._due("current_mode", now_s):
            self._send_current_mode()
        if self._due("event_sequence", now_s):
            latest = (self._event_sequence - 1) & 0xFFFF if self._sent_events else NO_EVENT_YET
            current_event_sequence_send(self.codec.messages, latest)

    @staticmethod
    def _time_ms(now_s: float) -> int:
        return int(now_s * 1000) & 0xFFFFFFFF

    def _send_attitude(self, state: AirframeState, now_s: float) -> None:
        # PX4 reports FRD body → NED world.
        R = rotation_enu_flu_to_ned_frd(rotation_from_quaternion(state.quaternion))
        roll, pitch, yaw = euler_zyx_from_rotation(R)
        p, q, r = flu_to_frd(state.body_rates_radps)
        time_ms = self._time_ms(now_s)
        self.codec.messages.attitude_send(time_ms, roll, pitch, yaw, p, q, r)
        quaternion = [float(v) for v in quaternion_from_rotation(R)]
        self.codec.messages.attitude_quaternion_send(time_ms, *quaternion, p, q, r, [0.0] * 4)

    def _send_status(self, state: AirframeState) -> None:
        voltage_mv = int(self.battery_voltage() * 1000)
        self.codec.messages.sys_status_send(
            0, 0, 0, 100, voltage_mv, -1, self.battery_percent(), 0, 0, 0, 0, 0, 0
        )
        landed = mavlink.MAV_LANDED_STATE_IN_AIR
        if state.on_ground:
            landed = mavlink.MAV_LANDED_STATE_ON_GROUND
        self.codec.messages.extended_sys_state_send(0, landed)

    def battery_voltage(self) -> float:
        """A 4S pack sagging linearly with flight time."""
        used = min(1.0, self._flight_time_s / self._battery_capacity_s)
        return 16.8 - 2.0 * used

    def battery_percent(self) -> int:
        return round(100 * (1.0 - min(1.0, self._flight_time_s / self._battery_capacity_s)))
