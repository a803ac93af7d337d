"""MAVLink 2 signing on loopback: the link against a signing vehicle and a forger with real
UDP sockets (unsigned, wrongly signed, replayed, from the vehicle's port and from another),
and the signature check itself."""

from __future__ import annotations

import secrets
import time
from collections.abc import AsyncIterator

import numpy as np
import pytest

from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.signing import SignatureCheck, SigningKey, Verdict, signing_timestamp
from supervisor.mavlink.link import LinkConfig, MavlinkLink
from supervisor.vehicles.types import UavCommand
from tests.mocap.test_client import wait_until
from tests.supervisor.test_mavlink_link import Clock, ScriptedVehicle, heartbeat, vehicle

__all__ = ["vehicle"]  # the fixture

KEY = secrets.token_bytes(32)
SETPOINT = UavCommand(10.0, np.zeros(3), np.zeros(3), True)


def signing(vehicle: ScriptedVehicle, key: bytes = KEY, timestamp: int | None = None) -> None:
    """The vehicle signs with ``key`` (PX4 after SETUP_SIGNING)."""
    stamp = signing_timestamp(time.time()) if timestamp is None else timestamp
    vehicle.codec.sign(SigningKey(key), stamp)


def statustext(vehicle: ScriptedVehicle, text: str) -> None:
    vehicle.codec.messages.statustext_send(mavlink.MAV_SEVERITY_CRITICAL, text.encode())
    vehicle.flush()


def captured(vehicle: ScriptedVehicle, armed: bool) -> bytes:
    """A true heartbeat of the vehicle, as a listener on the network records it."""
    base_mode = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        base_mode |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    vehicle.codec.messages.heartbeat_send(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base_mode, 0x00060000, 4
    )
    [frame] = vehicle.codec.outgoing()
    return frame


@pytest.fixture
async def forger() -> AsyncIterator[ScriptedVehicle]:
    """Someone else on the network claiming to be the vehicle (system 8) from its own port."""
    other = ScriptedVehicle()
    await other.open()
    yield other
    other.close()


async def open_signed_link(
    vehicle: ScriptedVehicle, clock: Clock, *, addressed: bool = True
) -> MavlinkLink:
    address = await vehicle.open()
    settings = LinkConfig(
        system_id=8,
        local_host="127.0.0.1",
        local_port=0,
        vehicle_address=address if addressed else None,
        link_loss_s=1.5,
        signing_key=KEY,
    )
    link = MavlinkLink(settings, clock)
    await link.start()
    if addressed:
        await vehicle.until(lambda: bool(vehicle.of_type("HEARTBEAT")))
    assert vehicle._transport is not None
    vehicle._transport.peer = ("127.0.0.1", link.local_port)
    return link


def aim(sender: ScriptedVehicle, link: MavlinkLink) -> None:
    assert sender._transport is not None
    sender._transport.peer = ("127.0.0.1", link.local_port)


async def test_no_forged_unsigned_or_replayed_frame_is_accepted(
    vehicle: ScriptedVehicle, forger: ScriptedVehicle
) -> None:
    """One of each kind, from the vehicle's own port (an address spoofer) and from
    another: 0 accepted; the vehicle's state and texts stay the true ones."""
    clock = Clock(100.0)
    link = await open_signed_link(vehicle, clock)
    try:
        true_heartbeat = captured(vehicle, armed=False)  # recorded before it is sent
        signing(vehicle)
        heartbeat(vehicle, armed=True)
        statustext(vehicle, "the true text")
        await wait_until(lambda: link.counters.messages == 2)
        assert link.view().armed and link.view().status_text == "the true text"

        aim(forger, link)
        wrong_key = ScriptedVehicle()
        signing(wrong_key, secrets.token_bytes(32))
        forged: list[bytes] = []
        for text in ("forged unsigned", "forged wrong key"):
            codec = forger.codec if text.endswith("unsigned") else wrong_key.codec
            codec.messages.heartbeat_send(
                mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0x00040000, 3
            )
            codec.messages.statustext_send(mavlink.MAV_SEVERITY_EMERGENCY, text.encode())
            forged += codec.outgoing()
        # Replayed: the vehicle's true frames once more (signed: the one just accepted).
        vehicle.codec.messages.heartbeat_send(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0x00040000, 3
        )
        [signed_disarmed] = vehicle.codec.outgoing()
        vehicle.send_raw(signed_disarmed)
        await wait_until(lambda: link.counters.messages == 3 and not link.view().armed)
        heartbeat(vehicle, armed=True)
        await wait_until(lambda: link.counters.messages == 4 and link.view().armed)
        forged += [signed_disarmed, true_heartbeat]
        refused_before = link.counters.unsigned + link.counters.bad_signature
        for datagram in forged:
            vehicle.send_raw(datagram)  # from the vehicle's address
            forger.send_raw(datagram)  # from another port
        c = link.counters
        await wait_until(lambda: c.unsigned + c.bad_signature + c.replayed >= 2 * len(forged))
        assert c.messages == 4  # 0 accepted
        assert c.unsigned - refused_before == 2 * 3  # 2 unsigned forgeries + the capture
        assert c.bad_signature == 2 * 2 and c.replayed == 2 * 1
        view = link.view()
        assert view.armed and view.px4_mode == "OFFBOARD"
        assert view.status_text == "the true text"
        assert "forged" not in " ".join(link.session.status_texts)
        assert view.refused["replayed"] == 2 and view.refused["bad_signature"] == 4
        link.send_setpoint(SETPOINT)
        await vehicle.until(lambda: bool(vehicle.of_type("SET_ACTUATOR_CONTROL_TARGET")))
        assert not forger.received
    finally:
        await link.close()


async def test_forged_heartbeats_do_not_delay_link_loss(
    vehicle: ScriptedVehicle, forger: ScriptedVehicle
) -> None:
    """The vehicle falls silent at t = 0 while a forger keeps sending its heartbeats
    (unsigned, wrongly signed, replayed; from its port and the vehicle's): the link is lost
    exactly when the silence passes link_loss_s, as without them."""
    clock = Clock(0.0)
    link = await open_signed_link(vehicle, clock)
    try:
        signing(vehicle)
        recorded = captured(vehicle, armed=True)
        vehicle.send_raw(recorded)
        await wait_until(lambda: link.counters.messages == 1)
        aim(forger, link)
        wrong_key = ScriptedVehicle()
        signing(wrong_key, secrets.token_bytes(32))
        for step in range(1, 16):
            clock.now_s = step * 0.1
            heartbeat(forger, armed=True)  # unsigned, another port
            forger.send_raw(recorded)  # replayed, another port
            vehicle.send_raw(recorded)  # replayed, the vehicle's port
            vehicle.send_raw(captured(wrong_key, armed=True))  # wrong key, the vehicle's port
            refused = 4 * step
            c = link.counters
            await wait_until(lambda: c.unsigned + c.bad_signature + c.replayed == refused)  # noqa: B023
            assert link.connected == (clock.now_s <= 1.5)
        clock.now_s = 1.5001
        assert not link.connected and not link.view().armed
        assert link.counters.messages == 1
    finally:
        await link.close()


async def test_the_setpoint_stream_never_follows_a_forged_sender(
    vehicle: ScriptedVehicle, forger: ScriptedVehicle
) -> None:
    """No configured address: forgeries before the vehicle speaks and after it falls
    silent never become the link's peer (without signing the second one would: the test
    next to this one in test_mavlink_link.py)."""
    clock = Clock(100.0)
    link = await open_signed_link(vehicle, clock, addressed=False)
    try:
        aim(forger, link)
        heartbeat(forger, armed=False)  # unsigned, first to speak
        await wait_until(lambda: link.counters.unsigned == 1)
        link.send_setpoint(SETPOINT)  # nowhere to go yet
        signing(vehicle)
        heartbeat(vehicle, armed=True)
        await wait_until(lambda: link.counters.messages == 1)
        clock.now_s += 5.0  # the vehicle silent far beyond link_loss_s
        assert not link.connected
        wrong_key = ScriptedVehicle()
        signing(wrong_key, secrets.token_bytes(32))
        forger.send_raw(captured(wrong_key, armed=False))
        heartbeat(forger, armed=False)
        await wait_until(lambda: link.counters.unsigned + link.counters.bad_signature == 3)
        link.send_setpoint(SETPOINT)
        await vehicle.until(lambda: bool(vehicle.of_type("SET_ACTUATOR_CONTROL_TARGET")))
        assert link.counters.messages == 1 and not forger.received
        assert link.counters.setup_signing_sent == 0  # the key never went to the forger
    finally:
        await link.close()


async def test_a_vehicle_without_a_key_gets_setup_signing_then_must_sign(
    vehicle: ScriptedVehicle,
) -> None:
    """Unsigned telemetry from the vehicle's address: the link sends it SETUP_SIGNING with
    the key (signed, at most once a second) and accepts nothing until the vehicle signs."""
    clock = Clock(100.0)
    link = await open_signed_link(vehicle, clock)
    try:
        for _ in range(3):
            heartbeat(vehicle, armed=False)
        await vehicle.until(lambda: bool(vehicle.of_type("SETUP_SIGNING")))
        await wait_until(lambda: link.counters.unsigned == 3)
        [setup] = vehicle.of_type("SETUP_SIGNING")
        assert bytes(setup.secret_key) == KEY and setup.target_system == 8
        assert setup.initial_timestamp == pytest.approx(signing_timestamp(time.time()), abs=10**6)
        assert not link.connected and link.counters.messages == 0
        signing(vehicle, timestamp=setup.initial_timestamp)
        heartbeat(vehicle, armed=False)
        await wait_until(lambda: link.connected)
        clock.now_s += 2.0
        vehicle.codec.sign(None)
        heartbeat(vehicle, armed=False)  # it signed once: unsigned now is a forgery
        await wait_until(lambda: link.counters.unsigned == 4)
        assert link.counters.setup_signing_sent == 1
    finally:
        await link.close()


def test_a_forged_future_timestamp_does_not_block_the_true_stream() -> None:
    """pymavlink 2.4.50 records a stream's timestamp before checking the signature; ours
    checks the signature first, as the C library does."""
    now = signing_timestamp(time.time())
    check = SignatureCheck(SigningKey(KEY), now)
    true_sender, forger = MavlinkCodec(1, 1), MavlinkCodec(1, 1)
    true_sender.sign(SigningKey(KEY), now)
    forger.sign(SigningKey(secrets.token_bytes(32)), now + 10**9)
    for codec in (forger, true_sender):
        codec.messages.heartbeat_send(2, 12, 0, 0, 4)
    [fake], [real] = forger.outgoing(), true_sender.outgoing()
    assert check.check(fake, 0, 1, 1) is Verdict.BAD_SIGNATURE
    assert check.check(real, 0, 1, 1) is Verdict.ACCEPTED
    assert check.check(real, 0, 1, 1) is Verdict.REPLAYED


def test_a_new_stream_more_than_a_minute_old_is_a_replay() -> None:
    now = signing_timestamp(time.time())
    old = MavlinkCodec(1, 1)
    old.sign(SigningKey(KEY), now - 61 * 100_000)
    old.messages.heartbeat_send(2, 12, 0, 0, 4)
    [frame] = old.outgoing()
    assert SignatureCheck(SigningKey(KEY), now).check(frame, 0, 1, 1) is Verdict.REPLAYED
