"""The asyncio MAVLink link against a scripted vehicle on loopback: heartbeat identity,
TIMESYNC answers and mocap stamps on one clock, mocap once per frame, parameters verified
by their echo, and refusals that wait for PX4's reason."""

from __future__ import annotations

import asyncio
import struct
from collections.abc import AsyncIterator, Callable
from typing import Any

import numpy as np
import pytest

from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.events import EventCatalog
from px4_mavlink.transport import Address, UdpTransport
from supervisor.mavlink.link import LinkConfig, MavlinkLink
from supervisor.mavlink.parameters import (
    MAV_PARAM_TYPE_INT32,
    MAV_PARAM_TYPE_REAL32,
    decode_param_value,
)
from supervisor.vehicles.sequences import apply_parameters, check_failsafe_parameters
from supervisor.vehicles.types import UavCommand, VehicleCommandError
from tests.mocap.test_client import wait_until
from tests.supervisor.test_mavlink_events import PX4_EVENTS_EXCERPT
from tests.supervisor.test_mavlink_px4_messages import frame

Message = Any  # pymavlink is untyped


class ScriptedVehicle:
    """A stand-in for PX4 instance 7 (system 8, component 1) on loopback: records what it
    receives and answers through ``on_message``; parameters as PX4 keeps them."""

    def __init__(self) -> None:
        self.codec = MavlinkCodec(8, 1)
        self.received: list[Message] = []
        self.on_message: Callable[[Message], None] = self.px4_parameters
        self.parameters = {"COM_OBL_RC_ACT": (0.0, MAV_PARAM_TYPE_INT32), "COM_OF_LOSS_T": (1.0, 9)}
        self.echo_sets = True
        self._transport: UdpTransport | None = None
        self._arrived = asyncio.Event()

    async def open(self) -> Address:
        self._transport = await UdpTransport.open(("127.0.0.1", 0), self._datagram)
        return ("127.0.0.1", self._transport.local_port)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()

    def _datagram(self, data: bytes, sender: Address) -> None:
        assert self._transport is not None
        self._transport.peer = sender
        for message in self.codec.decode(data).messages:
            self.received.append(message)
            self.on_message(message)
        self._arrived.set()

    async def until(self, condition: Callable[[], bool], timeout_s: float = 2.0) -> None:
        """Wait until what arrived satisfies ``condition``."""
        async with asyncio.timeout(timeout_s):
            while not condition():
                self._arrived.clear()
                await self._arrived.wait()

    def send_raw(self, datagram: bytes) -> None:
        assert self._transport is not None
        self._transport.send([datagram])

    def flush(self) -> None:
        assert self._transport is not None
        self._transport.send(self.codec.outgoing())

    def of_type(self, kind: str) -> list[Message]:
        return [m for m in self.received if m.get_type() == kind]

    def px4_parameters(self, message: Message) -> None:
        """PARAM_REQUEST_READ answered, PARAM_SET stored (bytes as they come) and echoed."""
        kind = message.get_type()
        if kind not in ("PARAM_REQUEST_READ", "PARAM_SET"):
            return
        name = message.param_id
        if name not in self.parameters:
            return  # PX4 stays silent about a name it does not have
        if kind == "PARAM_SET" and self.echo_sets:
            self.parameters[name] = (message.param_value, self.parameters[name][1])
        raw, param_type = self.parameters[name]
        self.codec.messages.param_value_send(name.encode(), raw, param_type, 900, 289)
        self.flush()


@pytest.fixture
async def vehicle() -> AsyncIterator[ScriptedVehicle]:
    scripted = ScriptedVehicle()
    yield scripted
    scripted.close()


class Clock:
    """The link's clock, set by the test [s]."""

    def __init__(self, now_s: float) -> None:
        self.now_s = now_s

    def __call__(self) -> float:
        return self.now_s


async def open_link(
    vehicle: ScriptedVehicle, clock: Callable[[], float] | None = None, **config: object
) -> MavlinkLink:
    address = await vehicle.open()
    settings = LinkConfig(
        system_id=8,
        local_host="127.0.0.1",
        local_port=0,
        vehicle_address=address,
        ack_timeout_s=0.1,
        **config,  # type: ignore[arg-type]
    )
    catalog = EventCatalog.from_json(PX4_EVENTS_EXCERPT)
    link = (
        MavlinkLink(settings, catalog=catalog)
        if clock is None
        else MavlinkLink(settings, clock, catalog=catalog)
    )
    await link.start()
    await vehicle.until(lambda: bool(vehicle.of_type("HEARTBEAT")))  # it knows where we are
    return link


async def test_the_link_announces_itself_as_a_ground_station(vehicle: ScriptedVehicle) -> None:
    link = await open_link(vehicle)
    try:
        await vehicle.until(lambda: bool(vehicle.of_type("HEARTBEAT")))
        [beat] = vehicle.of_type("HEARTBEAT")
        assert (beat.type, beat.autopilot) == (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID)
        assert (beat.get_srcSystem(), beat.get_srcComponent()) == (255, 190)
    finally:
        await link.close()


async def test_timesync_answers_and_mocap_stamps_share_the_link_clock(
    vehicle: ScriptedVehicle,
) -> None:
    clock = Clock(100.25)
    link = await open_link(vehicle, clock)
    try:
        vehicle.send_raw(frame("timesync_request"))  # PX4's own request (ts1 its time)
        await vehicle.until(lambda: bool(vehicle.of_type("TIMESYNC")))
        [answer] = vehicle.of_type("TIMESYNC")
        assert (answer.tc1, answer.ts1) == (100_250_000_000, 990224164000)
        assert link.counters.timesync_answered == 1
        position, attitude = np.array([1.0, 2.0, 0.5]), np.array([1.0, 0.0, 0.0, 0.0])
        link.send_mocap(position, attitude, 100.25)  # a frame captured "now"
        link.send_mocap(position, attitude, 100.25)  # the same frame again: skipped
        link.send_mocap(position, attitude, 100.24)  # an older one: skipped
        link.send_mocap(position, attitude, 100.26)
        await vehicle.until(lambda: len(vehicle.of_type("VISION_POSITION_ESTIMATE")) == 2)
        stamps = [m.usec for m in vehicle.of_type("VISION_POSITION_ESTIMATE")]
        assert stamps == [100_250_000, 100_260_000]
        assert stamps[0] * 1000 == answer.tc1  # one time base: PX4's offset maps both
        assert (link.counters.mocap_sent, link.counters.mocap_skipped) == (2, 2)
        [first] = vehicle.of_type("VISION_POSITION_ESTIMATE")[:1]
        assert (first.x, first.y, first.z) == pytest.approx((2.0, 1.0, -0.5))  # ENU → NED
    finally:
        await link.close()


async def test_parameters_read_set_and_verified(vehicle: ScriptedVehicle) -> None:
    link = await open_link(vehicle)
    try:
        assert await link.read_parameter("COM_OF_LOSS_T") == 1.0
        assert await link.read_parameter("COM_OBL_RC_ACT") == 0
        await link.set_parameter("COM_OBL_RC_ACT", 4)
        [set_message] = vehicle.of_type("PARAM_SET")
        assert set_message.param_type == MAV_PARAM_TYPE_INT32
        assert struct.pack("<f", set_message.param_value) == b"\x04\x00\x00\x00"  # bytewise
        assert await link.read_parameter("COM_OBL_RC_ACT") == 4
        await link.set_parameter("COM_OF_LOSS_T", 0.5)
        assert vehicle.of_type("PARAM_SET")[-1].param_type == MAV_PARAM_TYPE_REAL32
        assert await link.read_parameter("COM_OF_LOSS_T") == 0.5
    finally:
        await link.close()


async def test_setting_a_parameter_reads_its_type_first(vehicle: ScriptedVehicle) -> None:
    link = await open_link(vehicle)
    try:
        await link.set_parameter("COM_OBL_RC_ACT", 4)  # never read before
        kinds = [m.get_type() for m in vehicle.received if m.get_type().startswith("PARAM")]
        assert kinds == ["PARAM_REQUEST_READ", "PARAM_SET"]
        raw, param_type = vehicle.parameters["COM_OBL_RC_ACT"]
        assert decode_param_value(raw, param_type) == 4
    finally:
        await link.close()


async def test_an_echo_that_differs_is_an_error_after_the_retries(
    vehicle: ScriptedVehicle,
) -> None:
    vehicle.echo_sets = False  # the vehicle keeps its value and says so
    link = await open_link(vehicle)
    try:
        with pytest.raises(VehicleCommandError) as raised:
            await link.set_parameter("COM_OBL_RC_ACT", 4)
        assert "COM_OBL_RC_ACT: set to 4, vehicle says 0" in str(raised.value)
        assert len(vehicle.of_type("PARAM_SET")) == 3
    finally:
        await link.close()


async def test_silence_about_a_parameter_is_an_error(vehicle: ScriptedVehicle) -> None:
    link = await open_link(vehicle, retries=2)
    try:
        with pytest.raises(VehicleCommandError, match="NO_SUCH_PARAM: no answer after 2 tries"):
            await link.read_parameter("NO_SUCH_PARAM")
        with pytest.raises(VehicleCommandError, match="1–16 characters"):
            await link.read_parameter("A_NAME_LONGER_THAN_16")
    finally:
        await link.close()


async def test_the_parameter_sequences_name_each_vehicle(vehicle: ScriptedVehicle) -> None:
    link = await open_link(vehicle)
    try:
        expected = {"COM_OBL_RC_ACT": 4.0, "COM_OF_LOSS_T": 1.0}
        assert await check_failsafe_parameters((link,), expected) == [
            "vehicle 1: COM_OBL_RC_ACT is 0, expected 4"
        ]
        assert await apply_parameters((link,), {"COM_OBL_RC_ACT": 4}) == []
        assert await check_failsafe_parameters((link,), expected) == []
        problems = await check_failsafe_parameters((link,), {"NO_SUCH_PARAM": 1.0})
        assert problems == [
            "vehicle 1: NO_SUCH_PARAM unreadable (parameter NO_SUCH_PARAM: no answer after 3 tries)"
        ]
    finally:
        await link.close()


async def test_a_refusal_waits_for_px4s_reason(vehicle: ScriptedVehicle) -> None:
    """Real PX4 sends the ACK first and its EVENT 9 ms later (the capture's bytes here)."""

    def refuse(message: Message) -> None:
        if message.get_type() == "COMMAND_LONG" and message.command == 400:
            vehicle.send_raw(frame("ack_arm_rejected"))
            asyncio.get_running_loop().call_later(
                0.009, vehicle.send_raw, frame("event_arming_denied")
            )

    vehicle.on_message = refuse
    link = await open_link(vehicle)
    try:
        with pytest.raises(VehicleCommandError) as raised:
            await link.arm()
        assert str(raised.value) == (
            "command 400 temporarily rejected (Arming denied: Resolve system health failures first)"
        )
        assert len(vehicle.of_type("COMMAND_LONG")) == 1  # a refusal is not retried
    finally:
        await link.close()


async def test_a_refusal_without_a_reason_does_not_wait_long(vehicle: ScriptedVehicle) -> None:
    def refuse(message: Message) -> None:
        if message.get_type() == "COMMAND_LONG":
            vehicle.send_raw(frame("ack_arm_rejected"))

    vehicle.on_message = refuse
    link = await open_link(vehicle)
    try:
        loop = asyncio.get_running_loop()
        started = loop.time()
        with pytest.raises(VehicleCommandError, match=r"^command 400 temporarily rejected$"):
            await link.arm()
        assert loop.time() - started < 0.5
    finally:
        await link.close()


def heartbeat(vehicle: ScriptedVehicle, armed: bool) -> None:
    base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    vehicle.codec.messages.heartbeat_send(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base_mode, 0x00060000, 4
    )
    vehicle.flush()


async def test_another_sender_with_the_vehicles_id_changes_nothing(
    vehicle: ScriptedVehicle,
) -> None:
    """A second simulator (or a misconfigured vehicle) sending as system 8, disarmed: the
    link keeps to the vehicle's address, its state and its commands."""
    link = await open_link(vehicle)
    impostor = ScriptedVehicle()
    try:
        heartbeat(vehicle, armed=True)
        await wait_until(lambda: link.view().armed)
        await impostor.open()
        assert impostor._transport is not None
        impostor._transport.peer = ("127.0.0.1", link.local_port)
        for _ in range(3):
            heartbeat(impostor, armed=False)
        await wait_until(lambda: link.counters.impostor == 3)
        assert link.view().armed and link.px4_mode == "OFFBOARD"
        link.send_setpoint(UavCommand(10.0, np.zeros(3), np.zeros(3), True))
        await vehicle.until(lambda: bool(vehicle.of_type("SET_ACTUATOR_CONTROL_TARGET")))
        assert not impostor.received
    finally:
        impostor.close()
        await link.close()


async def test_without_a_vehicle_address_the_first_sender_is_kept_until_it_falls_silent(
    vehicle: ScriptedVehicle,
) -> None:
    clock = Clock(100.0)
    await vehicle.open()
    settings = LinkConfig(system_id=8, local_host="127.0.0.1", local_port=0, link_loss_s=1.5)
    link = MavlinkLink(settings, clock)
    await link.start()
    impostor = ScriptedVehicle()
    await impostor.open()
    try:
        for sender, armed in ((vehicle, True), (impostor, False)):
            assert sender._transport is not None
            sender._transport.peer = ("127.0.0.1", link.local_port)
            heard = link.counters.messages + link.counters.impostor
            heartbeat(sender, armed)
            await wait_until(lambda: link.counters.messages + link.counters.impostor > heard)  # noqa: B023
        assert link.view().armed and link.counters.impostor == 1
        link.send_setpoint(UavCommand(10.0, np.zeros(3), np.zeros(3), True))
        await vehicle.until(lambda: bool(vehicle.of_type("SET_ACTUATOR_CONTROL_TARGET")))
        clock.now_s += 2.0  # the first has been silent beyond link_loss_s: the next is it
        heartbeat(impostor, armed=False)
        await wait_until(lambda: link.counters.messages == 2)
        assert not link.view().armed
        link.send_setpoint(UavCommand(10.0, np.zeros(3), np.zeros(3), True))
        await impostor.until(lambda: bool(impostor.of_type("SET_ACTUATOR_CONTROL_TARGET")))
    finally:
        impostor.close()
        await link.close()
