"""PX4 parameter values on the wire (bytewise integers in the float field) and the client's
bookkeeping, on bytes captured from real PX4 v1.15.4."""

from __future__ import annotations

import math
import struct

import pytest

from px4_mavlink.codec import MavlinkCodec
from supervisor.mavlink.parameters import (
    MAV_PARAM_TYPE_INT8,
    MAV_PARAM_TYPE_INT32,
    MAV_PARAM_TYPE_REAL32,
    MAV_PARAM_TYPE_UINT16,
    ParameterClient,
    ParameterError,
    ParamValue,
    decode_param_value,
    encode_param_value,
    param_id_bytes,
    parse_param_value,
    same_value,
)
from tests.supervisor.test_mavlink_px4_messages import decode_one


def float_bytes(value: float) -> bytes:
    return struct.pack("<f", value)


def test_real_px4_parameter_values_decode() -> None:
    loss = parse_param_value(decode_one("param_com_of_loss_t"))
    assert loss == ParamValue("COM_OF_LOSS_T", 1.0, MAV_PARAM_TYPE_REAL32, 291, 900)
    action = parse_param_value(decode_one("param_com_obl_rc_act_0"))
    assert action == ParamValue("COM_OBL_RC_ACT", 0, MAV_PARAM_TYPE_INT32, 289, 900)
    echoed = parse_param_value(decode_one("param_com_obl_rc_act_4"))
    assert echoed.value == 4 and isinstance(echoed.value, int)
    # Bytewise: PX4's float field holds the int's bytes (a denormal, not 4.0).
    assert float_bytes(decode_one("param_com_obl_rc_act_4").param_value) == b"\x04\x00\x00\x00"


@pytest.mark.parametrize("value", [0, 1, 4, -1, 2**31 - 1, -(2**31), 1082130432, 0x00400000])
def test_int32_round_trips_bytewise(value: int) -> None:
    raw = encode_param_value(value, MAV_PARAM_TYPE_INT32)
    assert float_bytes(raw) == struct.pack("<i", value)
    assert decode_param_value(raw, MAV_PARAM_TYPE_INT32) == value


def test_int32_is_not_converted_as_a_number() -> None:
    assert encode_param_value(4, MAV_PARAM_TYPE_INT32) != 4.0
    assert decode_param_value(4.0, MAV_PARAM_TYPE_INT32) == 0x40800000  # 4.0f's bits


def test_smaller_integer_types_use_the_low_bytes() -> None:
    assert float_bytes(encode_param_value(-2, MAV_PARAM_TYPE_INT8)) == b"\xfe\x00\x00\x00"
    assert (
        decode_param_value(encode_param_value(-2, MAV_PARAM_TYPE_INT8), MAV_PARAM_TYPE_INT8) == -2
    )
    assert decode_param_value(encode_param_value(513, MAV_PARAM_TYPE_UINT16), 3) == 513


def test_real32_is_the_nearest_float32() -> None:
    raw = encode_param_value(0.1, MAV_PARAM_TYPE_REAL32)
    assert raw != 0.1 and raw == struct.unpack("<f", struct.pack("<f", 0.1))[0]
    assert decode_param_value(raw, MAV_PARAM_TYPE_REAL32) == raw
    assert same_value(0.1, raw, MAV_PARAM_TYPE_REAL32)
    assert not same_value(0.1, 0.1000001, MAV_PARAM_TYPE_REAL32)
    assert same_value(4, 4.0, MAV_PARAM_TYPE_INT32) and not same_value(4, 5, MAV_PARAM_TYPE_INT32)


@pytest.mark.parametrize(
    ("value", "param_type", "match"),
    [
        (0.5, MAV_PARAM_TYPE_INT32, "not an integer"),
        (2**31, MAV_PARAM_TYPE_INT32, "does not fit INT32"),
        (300, MAV_PARAM_TYPE_INT8, "does not fit INT8"),
        (math.inf, MAV_PARAM_TYPE_INT32, "not an integer"),
        (math.nan, MAV_PARAM_TYPE_INT32, "not an integer"),
        (1e39, MAV_PARAM_TYPE_REAL32, "REAL32"),
        (1, 11, "type 11 is not supported"),
    ],
)
def test_values_a_type_cannot_hold_are_refused(value: float, param_type: int, match: str) -> None:
    with pytest.raises(ParameterError, match=match):
        encode_param_value(value, param_type)


@pytest.mark.parametrize("name", ["", "A_NAME_LONGER_THAN_16", "CAFÉ"])
def test_bad_names_are_refused(name: str) -> None:
    with pytest.raises(ParameterError):
        param_id_bytes(name)


def test_the_client_sets_in_the_type_it_read_and_checks_the_echo() -> None:
    client = ParameterClient()
    with pytest.raises(ParameterError, match="read the parameter first"):
        client.set_request("COM_OBL_RC_ACT", 4)
    assert client.receive(decode_one("param_com_obl_rc_act_0")) is None  # nobody waits
    assert client.known["COM_OBL_RC_ACT"].value == 0
    request = client.set_request("COM_OBL_RC_ACT", 4.0)  # a float that is an integer
    assert request.param_type == MAV_PARAM_TYPE_INT32 and request.value == 4
    assert float_bytes(request.raw) == b"\x04\x00\x00\x00"
    client.await_value("COM_OBL_RC_ACT")
    echoed = client.receive(decode_one("param_com_obl_rc_act_4"))
    assert echoed is not None and client.mismatch(request, echoed) is None
    stale = client.receive(decode_one("param_com_obl_rc_act_0"))
    assert stale is not None
    assert client.mismatch(request, stale) == "COM_OBL_RC_ACT: set to 4, vehicle says 0"
    client.forget("COM_OBL_RC_ACT")
    assert client.receive(decode_one("param_com_obl_rc_act_4")) is None


def test_the_client_sends_reals_as_float32_and_names_a_type_mismatch() -> None:
    client = ParameterClient()
    client.receive(decode_one("param_com_of_loss_t"))
    request = client.set_request("COM_OF_LOSS_T", 0.7)
    assert request.param_type == MAV_PARAM_TYPE_REAL32
    assert request.value == struct.unpack("<f", struct.pack("<f", 0.7))[0]
    other = ParamValue("COM_OF_LOSS_T", 0, MAV_PARAM_TYPE_INT32)
    assert client.mismatch(request, other) == (
        "COM_OF_LOSS_T: vehicle answered type INT32, sent REAL32"
    )


def test_a_param_set_frame_carries_the_bytewise_value() -> None:
    """What the link sends for COM_OBL_RC_ACT = 4, decoded as PX4 would."""
    client = ParameterClient()
    client.receive(decode_one("param_com_obl_rc_act_0"))
    request = client.set_request("COM_OBL_RC_ACT", 4)
    ground, vehicle = MavlinkCodec(255, 190), MavlinkCodec(8, 1)
    ground.messages.param_set_send(
        8, 1, param_id_bytes(request.name), request.raw, request.param_type
    )
    [message] = vehicle.decode(ground.outgoing()[0]).messages
    assert message.param_id == "COM_OBL_RC_ACT" and message.param_type == MAV_PARAM_TYPE_INT32
    assert struct.unpack("<i", float_bytes(message.param_value))[0] == 4
