"""The sans-IO MAVLink codec and vehicle session, driven with bytes and times only."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from supervisor.mavlink.codec import MavlinkCodec
from supervisor.mavlink.session import VehicleSession, px4_mode_name

OFFBOARD = 6 << 16
ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED


def vehicle_frames(system: int = 1, component: int = 1) -> MavlinkCodec:
    return MavlinkCodec(system, component)


def heartbeat(codec: MavlinkCodec, base_mode: int = ARMED, custom_mode: int = OFFBOARD) -> bytes:
    codec.messages.heartbeat_send(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base_mode, custom_mode, 4
    )
    [frame] = codec.outgoing()
    return frame


def test_the_codec_queues_frames_and_decodes_them_back() -> None:
    vehicle, ground = vehicle_frames(), MavlinkCodec(255, 190)
    vehicle.messages.heartbeat_send(2, 12, 0, 0, 3)
    vehicle.messages.statustext_send(6, b"ready")
    frames = vehicle.outgoing()
    assert len(frames) == 2 and vehicle.outgoing() == []
    decoded = [ground.decode(frame) for frame in frames]
    assert [d.messages[0].get_type() for d in decoded] == ["HEARTBEAT", "STATUSTEXT"]
    assert all(d.bad_data == 0 for d in decoded)
    seqs = [d.messages[0].get_seq() for d in decoded]
    assert seqs == [0, 1]  # pymavlink's sequence numbers survive the queue


def test_a_truncated_datagram_is_bad_data_and_does_not_spoil_the_next() -> None:
    frame = heartbeat(vehicle_frames())
    ground = MavlinkCodec(255, 190)
    first = ground.decode(frame[:7])
    assert first.messages == []
    second = ground.decode(frame)
    assert [m.get_type() for m in second.messages] == ["HEARTBEAT"]


@pytest.mark.parametrize("garbage", [b"", b"\x00", b"\xfd" * 40, bytes(range(256))])
def test_garbage_never_raises(garbage: bytes) -> None:
    assert MavlinkCodec(255, 190).decode(garbage).messages == []


def test_liveness_follows_heartbeats_on_the_given_clock() -> None:
    ground = MavlinkCodec(255, 190)
    session = VehicleSession(system_id=1, link_loss_s=1.5, boot_s=0.0)
    assert not session.connected(0.0) and session.px4_mode(0.0) == "unknown"
    [message] = ground.decode(heartbeat(vehicle_frames())).messages
    assert session.is_from_vehicle(message)
    session.receive(message, 10.0)
    view = session.view(11.5)
    assert view.connected and view.armed and view.px4_mode == "OFFBOARD"
    assert not session.connected(11.51) and not session.view(11.51).armed


def test_messages_of_another_system_are_not_the_vehicle() -> None:
    [message] = MavlinkCodec(255, 190).decode(heartbeat(vehicle_frames(system=2))).messages
    assert not VehicleSession(1, 1.5, 0.0).is_from_vehicle(message)


def test_an_ack_counts_only_for_an_awaited_command_and_not_in_progress() -> None:
    vehicle, ground = vehicle_frames(), MavlinkCodec(255, 190)
    session = VehicleSession(1, 1.5, 0.0)

    def ack(command: int, result: int) -> mavlink.MAVLink_message:
        vehicle.messages.command_ack_send(command, result, 0, 0, 255, 190)
        [frame] = vehicle.outgoing()
        [message] = ground.decode(frame).messages
        return message

    assert session.receive(ack(400, 0), 1.0) is None  # nobody asked
    session.await_ack(400)
    assert session.receive(ack(400, 5), 1.0) is None  # in progress: the final one follows
    vehicle.messages.statustext_send(4, b"Arming denied: no position")
    [text] = ground.decode(vehicle.outgoing()[0]).messages
    session.receive(text, 1.0)
    final = session.receive(ack(400, 1), 1.1)
    assert final is not None and not final.accepted
    assert session.refusal(final) == (
        "command 400 temporarily rejected (Arming denied: no position)"
    )
    session.forget_ack(400)
    assert session.receive(ack(400, 0), 1.2) is None


def test_own_heartbeats_are_due_once_a_second() -> None:
    session = VehicleSession(1, 1.5, boot_s=100.0)
    assert session.heartbeat_due(100.0)
    assert not session.heartbeat_due(100.5)
    assert session.next_heartbeat_s == 101.0 and session.heartbeat_due(101.0)
    assert session.time_boot_ms(101.25) == 1250


def test_px4_mode_names() -> None:
    assert px4_mode_name(3 << 16) == "POSCTL"
    assert px4_mode_name((4 << 16) | (3 << 24)) == "AUTO.LOITER"
    assert px4_mode_name(9 << 16) == "MODE9"
