"""The sans-IO MAVLink codec and vehicle session, driven with bytes and times only (some of
them bytes captured from real PX4 v1.15.4)."""

from __future__ import annotations

import pytest

from px4_mavlink import px4_messages
from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.events import EventCatalog, encode_event_arguments
from supervisor.mavlink.session import (
    ArmingCheck,
    EventRequest,
    TimesyncReply,
    VehicleSession,
    px4_mode_name,
)
from tests.supervisor.test_mavlink_events import PX4_EVENTS_EXCERPT, SENSOR_FAILOVER
from tests.supervisor.test_mavlink_px4_messages import ARMING_REFUSAL_REPLAY, decode_one

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


# ---- as real PX4 v1.15.4 behaves ----------------------------------------------------------------
LOITER = 0x03040000  # AUTO.LOITER, PX4's boot mode


def px4_session(catalog: bool = True) -> VehicleSession:
    """A session for instance 7 of the capture (system 8)."""
    events = EventCatalog.from_json(PX4_EVENTS_EXCERPT) if catalog else None
    return VehicleSession(system_id=8, link_loss_s=0.5, boot_s=0.0, catalog=events)


def attitude(codec: MavlinkCodec, component: int = 1) -> mavlink.MAVLink_message:
    codec.messages.srcComponent = component
    codec.messages.attitude_send(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    [message] = MavlinkCodec(255, 190).decode(codec.outgoing()[0]).messages
    return message


def test_liveness_comes_from_every_message_not_heartbeats_alone() -> None:
    """PX4's 1 Hz heartbeat had 2.01 s gaps under load while ATTITUDE kept coming at 50 Hz:
    a 0.5 s link-loss limit must not fire on such a gap."""
    session, vehicle = px4_session(), MavlinkCodec(8, 1)
    [beat] = MavlinkCodec(255, 190).decode(heartbeat(vehicle)).messages
    session.receive(beat, 0.0)
    for k in range(1, 101):  # ATTITUDE at 50 Hz for 2.01 s, no heartbeat
        session.receive(attitude(vehicle), k * 0.0201)
        assert session.connected(k * 0.0201 + 0.01)
    assert session.heartbeat_age_s(2.01) == pytest.approx(2.01)
    assert session.silence_s(2.01) == pytest.approx(0.0, abs=1e-9)
    assert session.view(2.3).connected
    assert not session.connected(2.01 + 0.51)  # silence: lost


def test_another_component_of_the_vehicle_does_not_keep_the_autopilot_alive() -> None:
    session, vehicle = px4_session(), MavlinkCodec(8, 1)
    session.receive(attitude(vehicle, component=154), 1.0)  # a gimbal, say
    assert not session.connected(1.0)


def test_mode_from_current_mode_before_any_heartbeat() -> None:
    session = px4_session()
    session.receive(decode_one("timesync_request"), 0.9)
    assert session.connected(1.0) and session.px4_mode(1.0) == "unknown"
    session.receive(decode_one("current_mode_loiter"), 1.0)
    assert session.custom_mode == LOITER and session.px4_mode(1.0) == "AUTO.LOITER"
    session.receive(decode_one("heartbeat_loiter"), 1.1)
    assert session.view(1.1).armed is False


def ack_frame(command: int, result: int) -> mavlink.MAVLink_message:
    vehicle = MavlinkCodec(8, 1)
    vehicle.messages.command_ack_send(command, result, 0, 0, 255, 190)
    [message] = MavlinkCodec(255, 190).decode(vehicle.outgoing()[0]).messages
    return message


@pytest.mark.parametrize(
    ("command", "params", "armed", "mode"),
    [
        (400, (1.0, 0.0), True, "AUTO.LOITER"),  # arm
        (400, (0.0, 0.0), False, "AUTO.LOITER"),  # disarm
        (400, (0.0, 21196.0), False, "AUTO.LOITER"),  # force-disarm
        (176, (1.0, 6.0, 0.0), None, "OFFBOARD"),  # set mode: offboard
        (176, (1.0, 4.0, 6.0), None, "AUTO.LAND"),
    ],
)
def test_an_accepted_ack_applies_what_was_asked(
    command: int, params: tuple[float, ...], armed: bool | None, mode: str
) -> None:
    session = px4_session()
    session.receive(decode_one("heartbeat_loiter"), 0.0)
    session.armed = not armed if armed is not None else session.armed
    before = session.armed
    session.await_ack(command, *params, 0.0, 0.0, 0.0, 0.0, 0.0)
    ack = session.receive(ack_frame(command, 0), 0.1)
    assert ack is not None and ack.accepted and ack.params[: len(params)] == params
    assert session.armed == (armed if armed is not None else before)
    assert session.px4_mode(0.1) == mode


def test_a_refused_ack_changes_nothing() -> None:
    session = px4_session()
    session.receive(decode_one("heartbeat_loiter"), 0.0)
    session.await_ack(176, 1.0, 6.0, 0.0)
    ack = session.receive(ack_frame(176, 1), 0.1)
    assert ack is not None and not ack.accepted
    assert session.px4_mode(0.1) == "AUTO.LOITER"


def test_a_timesync_request_is_answered_with_our_clock() -> None:
    session = px4_session()
    request = decode_one("timesync_request")  # PX4: tc1 0, ts1 its time [ns]
    assert (request.tc1, request.ts1) == (0, 990224164000)
    assert session.receive(request, 12.345678901) is None
    assert session.replies() == [TimesyncReply(12345678901, 990224164000, 8, 1)]
    assert session.replies() == []
    vehicle = MavlinkCodec(8, 1)
    vehicle.messages.timesync_send(5, 990224164000)  # an answer, not a request
    [answer] = MavlinkCodec(255, 190).decode(vehicle.outgoing()[0]).messages
    session.receive(answer, 13.0)
    assert session.replies() == []


def replay_arming_refusal(session: VehicleSession) -> None:
    """PX4's traffic of the capture up to the refused arm: the arming-check report at 2.44 s,
    CURRENT_MODE at 2.50 s, the arm sent at 4.0022 s."""
    for k, name in enumerate(ARMING_REFUSAL_REPLAY):
        session.receive(decode_one(name), 2.44 + 0.001 * k)
    session.await_ack(400, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


def test_a_refusal_carries_px4s_event_and_failing_checks() -> None:
    session = px4_session()
    replay_arming_refusal(session)
    assert [c.text for c in session.arming_checks] == [
        "No valid attitude estimate",
        "No valid local position estimate",
        "No valid global position estimate",
        "No valid mission available",
        "No offboard signal",
        "No manual control input",
    ]
    assert not session.status_texts  # the checks are not status texts
    ack = session.receive(decode_one("ack_arm_rejected"), 4.0027)
    assert ack is not None and not session.heard_after(ack)  # the reason follows the ACK
    session.receive(decode_one("statustext_chunk_0"), 4.0115)
    session.receive(decode_one("statustext_chunk_1"), 4.0116)
    session.receive(decode_one("event_arming_denied"), 4.0116)
    assert session.heard_after(ack)
    assert list(session.status_texts) == ["Arming denied: Resolve system health failures first"]
    assert (session.texts[-1].source, session.texts[-1].time_s) == ("event", 4.0116)
    # In AUTO.LOITER (group 4): the errors that keep it from arming there, not the mission
    # (info), offboard (other mode) or manual-control (warning) checks.
    assert session.refusal(ack) == (
        "command 400 temporarily rejected (Arming denied: Resolve system health failures first; "
        "No valid attitude estimate; No valid local position estimate; "
        "No valid global position estimate)"
    )


def test_arming_in_offboard_names_the_offboard_check() -> None:
    session = px4_session()
    replay_arming_refusal(session)
    session.custom_mode = 0x00060000
    ack = session.receive(decode_one("ack_arm_rejected"), 4.0027)
    assert ack is not None
    assert session.refusal(ack) == (  # the attitude check's groups include offboard's (14)
        "command 400 temporarily rejected (No valid attitude estimate; No offboard signal)"
    )


def test_without_a_catalog_a_refusal_still_has_px4s_words() -> None:
    session = px4_session(catalog=False)
    replay_arming_refusal(session)
    ack = session.receive(decode_one("ack_arm_rejected"), 4.0027)
    assert ack is not None
    session.receive(decode_one("event_arming_denied"), 4.0116)
    assert session.refusal(ack) == (
        "command 400 temporarily rejected (PX4 event 0x0102089d (component 1, sub id 133277))"
    )
    session.receive(decode_one("statustext_chunk_0"), 4.0117)
    session.receive(decode_one("statustext_chunk_1"), 4.0118)
    assert session.refusal(ack) == (
        "command 400 temporarily rejected (Arming denied: Resolve system health failures first)"
    )


def test_a_text_long_before_the_ack_is_not_its_reason() -> None:
    session = px4_session()
    session.receive(decode_one("statustext_chunk_0"), 1.0)
    session.receive(decode_one("statustext_chunk_1"), 1.0)
    session.await_ack(176, 1.0, 6.0)
    ack = session.receive(ack_frame(176, 4), 2.0)
    assert ack is not None and session.refusal(ack) == "command 176 failed"


def event_frame(sequence: int, flags_or_event: int = SENSOR_FAILOVER) -> mavlink.MAVLink_message:
    vehicle = MavlinkCodec(8, 1)
    catalog = EventCatalog.from_json(PX4_EVENTS_EXCERPT)
    arguments = encode_event_arguments(catalog, SENSOR_FAILOVER, (1, sequence % 256, 4))
    px4_messages.event_send(vehicle.messages, 0, 0, flags_or_event, 0, sequence, 0x44, arguments)
    [message] = MavlinkCodec(255, 190).decode(vehicle.outgoing()[0]).messages
    return message


def sequence_frame(sequence: int, flags: int = 0) -> mavlink.MAVLink_message:
    vehicle = MavlinkCodec(8, 1)
    px4_messages.current_event_sequence_send(vehicle.messages, sequence, flags)
    [message] = MavlinkCodec(255, 190).decode(vehicle.outgoing()[0]).messages
    return message


def test_the_event_after_a_reset_is_shown() -> None:
    """PX4 at boot: CURRENT_EVENT_SEQUENCE (1, reset) then EVENT 1 (the captured bytes)."""
    session = px4_session()
    session.receive(decode_one("current_event_sequence_reset"), 0.5417)
    session.receive(decode_one("event_logging"), 0.5584)
    assert list(session.status_texts) == ["logging: opening log file 2026-12-2/0_49_50.ulg"]
    session.receive(decode_one("current_event_sequence_9"), 3.5)  # events 2 … 9 missed
    assert session.replies() == [EventRequest(2, 9, 8, 1)]


def test_events_in_words_once_and_lost_ones_asked_again() -> None:
    session = px4_session()
    session.receive(sequence_frame(1), 0.5)  # joined late: event 1 was before our time
    session.receive(event_frame(2), 1.0)
    session.receive(event_frame(2), 1.1)  # a duplicate
    assert list(session.status_texts) == ["Gyroscope sensor #2 failure: Timeout"]
    assert session.replies() == []
    session.receive(event_frame(5), 2.0)  # 3 and 4 lost
    assert session.replies() == [EventRequest(3, 4, 8, 1)] and session.events_lost == 2
    session.receive(event_frame(3), 2.1)  # re-sent on request: shown once
    session.receive(event_frame(3), 2.2)
    assert [t.text for t in session.texts][-2:] == [
        "Gyroscope sensor #5 failure: Timeout",
        "Gyroscope sensor #3 failure: Timeout",
    ]
    session.receive(sequence_frame(7), 3.0)  # CURRENT_EVENT_SEQUENCE: 6 and 7 never came
    assert session.replies() == [EventRequest(6, 7, 8, 1)]
    session.receive(sequence_frame(2, px4_messages.MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET), 4.0)
    assert session.replies() == []  # a reboot: start again
    session.receive(event_frame(3), 4.1)
    assert session.replies() == [] and session.text_count == 4


def test_event_sequence_numbers_wrap() -> None:
    session = px4_session()
    session.receive(event_frame(65534), 1.0)
    session.receive(event_frame(1), 1.1)  # 65535 and 0 lost across the wrap
    assert session.replies() == [EventRequest(65535, 0, 8, 1)]


def test_statustext_chunks_are_joined() -> None:
    session = px4_session(catalog=False)
    session.receive(decode_one("statustext_chunk_0"), 1.0)
    assert not session.status_texts
    session.receive(decode_one("statustext_chunk_1"), 1.0)
    [text] = session.texts
    assert (text.text, text.source, text.level) == (
        "Arming denied: Resolve system health failures first",
        "statustext",
        2,
    )


def test_arming_checks_are_replaced_by_each_complete_report() -> None:
    session = px4_session()
    replay_arming_refusal(session)
    catalog = EventCatalog.from_json(PX4_EVENTS_EXCERPT)
    vehicle, ground = MavlinkCodec(8, 1), MavlinkCodec(255, 190)

    def send(name: str, sequence: int, values: tuple[int, ...], at_s: float) -> None:
        event_id = catalog.find(name).event_id
        arguments = encode_event_arguments(catalog, event_id, values)
        px4_messages.event_send(vehicle.messages, 0, 0, event_id, 0, sequence, 0x33, arguments)
        [message] = ground.decode(vehicle.outgoing()[0]).messages
        session.receive(message, at_s)

    send("commander_arming_check_summary", 10, (0, 0, 0, 0, 0), 10.0)  # a new report begins
    assert len(session.arming_checks) == 6  # the old one holds until the new one is complete
    send("check_modes_offboard_signal", 11, (16384, 20), 10.0)
    send("commander_health_summary", 12, (0, 0, 0, 0), 10.0)
    assert list(session.arming_checks) == [ArmingCheck("No offboard signal", 3, 16384)]
    assert session.arming_problems() == []  # not in AUTO.LOITER
    send("commander_arming_check_summary", 13, (0, 0, 0, 0, 0), 11.0)
    send("commander_health_summary", 14, (0, 0, 0, 0), 11.0)
    assert list(session.arming_checks) == []


def test_the_same_words_as_event_and_statustext_are_one_text() -> None:
    session = px4_session()
    session.receive(decode_one("event_arming_denied"), 4.0)
    session.receive(decode_one("statustext_chunk_0"), 4.001)
    session.receive(decode_one("statustext_chunk_1"), 4.002)
    [text] = session.texts
    assert (text.source, text.level, text.time_s) == ("event", 2, 4.002)
    assert session.text_count == 2  # said twice: a waiting link wakes on either


def test_random_events_never_raise() -> None:
    """Any id, sequence, level and argument bytes: a text or nothing, never an exception."""
    import random

    rng = random.Random(0)
    session = px4_session()
    known = [d.event_id for d in EventCatalog.from_json(PX4_EVENTS_EXCERPT).events.values()]
    vehicle, ground = MavlinkCodec(8, 1), MavlinkCodec(255, 190)
    for k in range(2000):
        event_id = rng.choice(known) if k % 2 else rng.randrange(2**32)
        arguments = bytes(rng.randrange(256) for _ in range(rng.randrange(41)))
        px4_messages.event_send(
            vehicle.messages, 0, 0, event_id, k, rng.randrange(65536), rng.randrange(256),
            arguments,
        )  # fmt: skip
        for message in ground.decode(vehicle.outgoing()[0]).messages:
            session.receive(message, k * 0.01)
    assert session.text_count > 0 and len(session.replies()) > 0
