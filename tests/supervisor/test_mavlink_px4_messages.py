"""PX4's event messages (EVENT 410 … RESPONSE_EVENT_ERROR 413) in pymavlink, checked against
pymavlink's own generator and against datagrams captured from real PX4 v1.15.4."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common
from pymavlink.generator import mavparse

from px4_mavlink import px4_messages
from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.px4_messages import (
    MAVLink_current_event_sequence_message,
    MAVLink_event_message,
    MAVLink_request_event_message,
    MAVLink_response_event_error_message,
)

# Datagrams as PX4 v1.15.4 SITL (SIH quadrotor, instance 7: system 8, component 1) sent them
# on its API link on 2026-12-02, captured with a pymavlink client that sent a GCS heartbeat,
# read COM_OF_LOSS_T and COM_OBL_RC_ACT, asked to arm 4 s after a cold start (refused), then
# set COM_OBL_RC_ACT to 4. Facts, kept as bytes (hex).
PX4_CAPTURE = {
    "current_event_sequence_reset": "fd0300000708019b0100010001218c",
    "event_logging": "fd1400000808019a0100ef5b1201e31b0f000100000066ea070c020031324092",
    "timesync_request": "fd0d00000e08016f00000000000000000000a0a4f58de6f831",
    "heartbeat_loiter": "fd090000c1080100000000000403020c1d0003160d",
    "param_com_of_loss_t": (
        "fd1900003a08011600000000803f84032301434f4d5f4f465f4c4f53535f5400000009a2be"
    ),
    "param_com_obl_rc_act_0": (
        "fd1900003b08011600000000000084032101434f4d5f4f424c5f52435f4143540000069946"
    ),
    "event_arming_check_summary": (
        "fd1e00009008019a0100e093a80142230f000200000088000000100080000000802b0180802b0180efc4"
    ),
    "event_no_attitude": "fd1200009108019a01008f749f0142230f0003000000227ed07e0014b8bb",
    "event_no_local_position": "fd1200009208019a0100b91bd30142230f0004000000337c007e001428fc",
    "event_no_global_position": "fd1200009308019a010073c2980142230f0005000000333800000014b3f3",
    "event_no_mission": "fd1200009408019a0100d9c2050142230f0006000000660800000014995e",
    "event_no_offboard_signal": "fd1200009508019a0100c71d2f0142230f000700000033004000001416d4",
    "event_no_manual_control": "fd1200009608019a010029ed060142230f000800000044ffffffff07e98a",
    "event_health_summary": "fd1200009708019a010027371d0142230f00090000008800021802287fca",
    "current_mode_loiter": "fd080000a50801b401000000040300000403d4ef",
    "current_event_sequence_9": "fd0100008908019b0100099a66",
    "ack_arm_rejected": "fd0a0000e808014d00009001010000000000ffbe7535",
    "statustext_chunk_0": (
        "fd340000e90801fd00000241726d696e672064656e6965643a205265736f6c76652073797374656d20"
        "6865616c7468206661696c75726573206669727302658c"
    ),
    "statustext_chunk_1": (
        "fd360000ea0801fd0000027409000000000000000000000000000000000000000000000000000000"
        "0000000000000000000000000000000000000000000200014e9b"
    ),
    "event_arming_denied": "fd0d0000eb08019a01009d0802015f290f000a000000622b6a",
    "param_com_obl_rc_act_4": (
        "fd1900005d08011600000400000084032101434f4d5f4f424c5f52435f41435400000654fd"
    ),
    "event_sensor_failover": "fd100000c408019a01006abfc40182910f000c00000000000004c283",
}
# The order PX4 sent them in (the capture's order), for replaying a session.
ARMING_REFUSAL_REPLAY = (
    "heartbeat_loiter",
    "event_arming_check_summary",
    "event_no_attitude",
    "event_no_local_position",
    "event_no_global_position",
    "event_no_mission",
    "event_no_offboard_signal",
    "event_no_manual_control",
    "event_health_summary",
    "current_mode_loiter",
)

# The four messages as MAVLink's common.xml defines them (fields in the XML's order).
EVENTS_XML = """<?xml version="1.0"?>
<mavlink>
  <version>3</version>
  <dialect>0</dialect>
  <messages>
    <message id="410" name="EVENT">
      <description>Event message.</description>
      <field type="uint8_t" name="destination_component">Component ID</field>
      <field type="uint8_t" name="destination_system">System ID</field>
      <field type="uint32_t" name="id">Event ID (as defined in the component metadata)</field>
      <field type="uint32_t" name="event_time_boot_ms" units="ms">Timestamp.</field>
      <field type="uint16_t" name="sequence">Sequence number.</field>
      <field type="uint8_t" name="log_levels">Log levels.</field>
      <field type="uint8_t[40]" name="arguments">Arguments (depend on event ID).</field>
    </message>
    <message id="411" name="CURRENT_EVENT_SEQUENCE">
      <description>Regular broadcast for the current latest event sequence number.</description>
      <field type="uint16_t" name="sequence">Sequence number.</field>
      <field type="uint8_t" name="flags">Flag bitset.</field>
    </message>
    <message id="412" name="REQUEST_EVENT">
      <description>Request one or more events to be (re-)sent.</description>
      <field type="uint8_t" name="target_system">System ID</field>
      <field type="uint8_t" name="target_component">Component ID</field>
      <field type="uint16_t" name="first_sequence">First sequence number.</field>
      <field type="uint16_t" name="last_sequence">Last sequence number.</field>
    </message>
    <message id="413" name="RESPONSE_EVENT_ERROR">
      <description>Response to a REQUEST_EVENT in case of an error.</description>
      <field type="uint8_t" name="target_system">System ID</field>
      <field type="uint8_t" name="target_component">Component ID</field>
      <field type="uint16_t" name="sequence">Sequence number.</field>
      <field type="uint16_t" name="sequence_oldest_available">Oldest available.</field>
      <field type="uint8_t" name="reason">Error reason.</field>
    </message>
  </messages>
</mavlink>
"""
CLASSES: dict[str, Any] = {
    "EVENT": MAVLink_event_message,
    "CURRENT_EVENT_SEQUENCE": MAVLink_current_event_sequence_message,
    "REQUEST_EVENT": MAVLink_request_event_message,
    "RESPONSE_EVENT_ERROR": MAVLink_response_event_error_message,
}


def frame(name: str) -> bytes:
    return bytes.fromhex(PX4_CAPTURE[name])


def decode_one(name: str) -> mavlink.MAVLink_message:
    decoded = MavlinkCodec(255, 190).decode(frame(name))
    assert decoded.bad_data == 0
    [message] = decoded.messages
    return message


def test_crc_extra_and_wire_order_are_those_of_pymavlinks_generator(tmp_path: Path) -> None:
    path = tmp_path / "events.xml"
    path.write_text(EVENTS_XML)
    generated = {m.name: m for m in mavparse.MAVXML(str(path), mavparse.PROTOCOL_2_0).message}
    assert set(generated) == set(CLASSES)
    for name, cls in CLASSES.items():
        assert cls.crc_extra == generated[name].crc_extra, name
        assert cls.fieldnames == generated[name].fieldnames
        assert cls.ordered_fieldnames == [f.name for f in generated[name].ordered_fields]
        assert cls.unpacker.size == generated[name].wire_length
    # The figures (also those of MAVLink's generated C headers: MAVLINK_MSG_ID_410_CRC …).
    assert [cls.crc_extra for cls in CLASSES.values()] == [160, 106, 33, 77]


def test_real_px4_event_frames_pass_the_crc_and_decode() -> None:
    denied = decode_one("event_arming_denied")
    assert denied.get_type() == "EVENT"
    assert (denied.get_srcSystem(), denied.get_srcComponent()) == (8, 1)
    assert denied.id == 0x0102089D  # component 1 (px4), sub id 133277
    assert (denied.sequence, denied.log_levels, denied.event_time_boot_ms) == (10, 0x62, 993631)
    assert (denied.destination_system, denied.destination_component) == (0, 0)  # broadcast
    assert bytes(denied.arguments) == bytes(40)  # PX4 trims the zero tail: decode pads it
    check = decode_one("event_no_attitude")
    assert bytes(check.arguments)[:5] == bytes.fromhex("7ed07e0014")
    sequence = decode_one("current_event_sequence_reset")
    assert sequence.get_type() == "CURRENT_EVENT_SEQUENCE"
    assert (sequence.sequence, sequence.flags) == (
        1,
        px4_messages.MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET,
    )


def test_a_corrupted_event_is_bad_data() -> None:
    corrupt = bytearray(frame("event_arming_denied"))
    corrupt[12] ^= 0x01  # one bit of the event id: the CRC no longer matches
    decoded = MavlinkCodec(255, 190).decode(bytes(corrupt))
    assert decoded.messages == [] and decoded.bad_data == 1


def test_byte_at_a_time_parsing_gives_the_same_message() -> None:
    parser = mavlink.MAVLink(None)
    messages = [parser.parse_char(bytes([b])) for b in frame("event_sensor_failover")]
    [message] = [m for m in messages if m is not None]
    assert message.get_type() == "EVENT" and bytes(message.arguments)[:4] == b"\x00\x00\x04\x00"


@pytest.mark.parametrize(
    ("send", "expected"),
    [
        (
            lambda mav: px4_messages.event_send(
                mav, 0, 0, 0x01C4BF6A, 1234, 65535, 0x00, b"\x01\x02\x04"
            ),
            {"id": 0x01C4BF6A, "event_time_boot_ms": 1234, "sequence": 65535, "log_levels": 0},
        ),
        (
            lambda mav: px4_messages.current_event_sequence_send(mav, 300, 1),
            {"sequence": 300, "flags": 1},
        ),
        (
            lambda mav: px4_messages.request_event_send(mav, 8, 1, 65534, 2),
            {
                "target_system": 8,
                "target_component": 1,
                "first_sequence": 65534,
                "last_sequence": 2,
            },
        ),
        (
            lambda mav: px4_messages.response_event_error_send(mav, 255, 190, 7, 9),
            {"target_system": 255, "sequence": 7, "sequence_oldest_available": 9, "reason": 0},
        ),
    ],
)
def test_each_message_round_trips_through_the_codec(send: object, expected: dict[str, int]) -> None:
    sender, receiver = MavlinkCodec(8, 1), MavlinkCodec(255, 190)
    send(sender.messages)  # type: ignore[operator]
    [datagram] = sender.outgoing()
    [message] = receiver.decode(datagram).messages
    assert {key: getattr(message, key) for key in expected} == expected
    if message.get_type() == "EVENT":
        assert bytes(message.arguments) == b"\x01\x02\x04".ljust(40, b"\x00")


def test_our_encoding_of_a_captured_event_is_byte_identical() -> None:
    """Re-encoding PX4's frame with its own header fields gives PX4's very bytes."""
    original = frame("event_no_attitude")
    message = decode_one("event_no_attitude")
    encoder = mavlink.MAVLink(None, srcSystem=8, srcComponent=1)
    encoder.seq = original[4]
    assert message.pack(encoder) == original


def test_too_many_argument_bytes_are_refused() -> None:
    with pytest.raises(ValueError, match="40 bytes"):
        px4_messages.event_send(MavlinkCodec(8, 1).messages, 0, 0, 1, 0, 0, 0, bytes(41))


def test_the_dialect_keeps_every_constant_of_common() -> None:
    """The simulated PX4 imports ``common`` for constants; the codec speaks ``development``."""
    names = [
        n
        for n in dir(common)
        if n.startswith(("MAV_", "MAVLINK_MSG_ID_")) and n.isupper() and not n.endswith("ENUM_END")
    ]  # *_ENUM_END: one past an enum's last entry (development adds MAV_CMD entries)
    assert len(names) > 500
    assert all(getattr(mavlink, n) == getattr(common, n) for n in names)
    assert mavlink.MAVLINK_MSG_ID_CURRENT_MODE == 436
