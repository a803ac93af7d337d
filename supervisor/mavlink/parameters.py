"""PX4 parameters over MAVLink's parameter protocol, without I/O.

PARAM_VALUE, PARAM_SET and PARAM_REQUEST_READ carry every value in one float field. PX4
encodes integers *bytewise* (it advertises MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE):
the float's four bytes are the little-endian bytes of the integer, not its value converted
(an INT32 4 travels as the float whose bits are 0x00000004). PX4 uses only INT32
(``MAV_PARAM_TYPE_INT32`` = 6) and REAL32 (9). PX4 also copies the four bytes of a
PARAM_SET into the parameter whatever type the message claims, so a value must be sent in
the parameter's own type: the client learns it from a PARAM_VALUE first (a read).

``ParameterClient`` keeps what the vehicle said of each parameter and which names the link
waits for; the asyncio link sends the requests, retries and raises.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

MAV_PARAM_TYPE_UINT8 = 1
MAV_PARAM_TYPE_INT8 = 2
MAV_PARAM_TYPE_UINT16 = 3
MAV_PARAM_TYPE_INT16 = 4
MAV_PARAM_TYPE_UINT32 = 5
MAV_PARAM_TYPE_INT32 = 6
MAV_PARAM_TYPE_REAL32 = 9
PARAM_ID_LEN = 16

# Integer types bytewise in the float's four bytes (struct code of the integer).
_INTEGER_TYPES = {
    MAV_PARAM_TYPE_UINT8: "<B",
    MAV_PARAM_TYPE_INT8: "<b",
    MAV_PARAM_TYPE_UINT16: "<H",
    MAV_PARAM_TYPE_INT16: "<h",
    MAV_PARAM_TYPE_UINT32: "<I",
    MAV_PARAM_TYPE_INT32: "<i",
}
TYPE_NAMES = {
    MAV_PARAM_TYPE_UINT8: "UINT8",
    MAV_PARAM_TYPE_INT8: "INT8",
    MAV_PARAM_TYPE_UINT16: "UINT16",
    MAV_PARAM_TYPE_INT16: "INT16",
    MAV_PARAM_TYPE_UINT32: "UINT32",
    MAV_PARAM_TYPE_INT32: "INT32",
    MAV_PARAM_TYPE_REAL32: "REAL32",
}

ParamNumber = int | float


class ParameterError(ValueError):
    """A parameter value or name that cannot be sent, or a PARAM_VALUE that cannot be read."""


def is_integer_type(param_type: int) -> bool:
    return param_type in _INTEGER_TYPES


def encode_param_value(value: ParamNumber, param_type: int) -> float:
    """The float field that carries ``value`` as a parameter of ``param_type`` (bytewise for
    integers). Raises ``ParameterError`` for a value the type cannot hold."""
    if param_type == MAV_PARAM_TYPE_REAL32:
        number = float(value)
        if math.isfinite(number) and abs(number) > 3.4028234663852886e38:
            raise ParameterError(f"{value} does not fit a REAL32")
        return float(struct.unpack("<f", struct.pack("<f", number))[0])
    code = _INTEGER_TYPES.get(param_type)
    if code is None:
        raise ParameterError(f"parameter type {param_type} is not supported")
    if isinstance(value, float) and not value.is_integer():
        raise ParameterError(f"{value} is not an integer ({TYPE_NAMES[param_type]})")
    try:
        raw = struct.pack(code, int(value)).ljust(4, b"\x00")
    except (struct.error, OverflowError, ValueError) as error:
        raise ParameterError(f"{value} does not fit {TYPE_NAMES[param_type]}") from error
    return float(struct.unpack("<f", raw)[0])


def decode_param_value(raw: float, param_type: int) -> ParamNumber:
    """The value a PARAM_VALUE's float field carries for ``param_type`` (int for integers)."""
    if param_type == MAV_PARAM_TYPE_REAL32:
        return float(raw)
    code = _INTEGER_TYPES.get(param_type)
    if code is None:
        return float(raw)  # a type PX4 does not use: leave the float as it is
    size = struct.calcsize(code)
    value: int = struct.unpack(code, struct.pack("<f", raw)[:size])[0]
    return value


def same_value(a: ParamNumber, b: ParamNumber, param_type: int) -> bool:
    """Whether two values are the same parameter value: equal integers, or equal as REAL32
    (what PX4 stores; 0.1 sent comes back as the float32 nearest to 0.1)."""
    if is_integer_type(param_type):
        return float(a) == float(b)
    return bool(struct.pack("<f", float(a)) == struct.pack("<f", float(b)))


def param_id_bytes(name: str) -> bytes:
    """A parameter name as PARAM_*'s 16-byte ``param_id`` (no terminator when 16 long)."""
    try:
        raw = name.encode("ascii")
    except UnicodeEncodeError as error:
        raise ParameterError(f"parameter name {name!r} is not ASCII") from error
    if not raw or len(raw) > PARAM_ID_LEN:
        raise ParameterError(f"parameter name {name!r} must have 1–{PARAM_ID_LEN} characters")
    return raw


@dataclass(frozen=True)
class ParamValue:
    """What a PARAM_VALUE said: the parameter's name, value (int for integer types), type,
    and its index among ``count`` parameters."""

    name: str
    value: ParamNumber
    param_type: int
    index: int = -1
    count: int = 0

    def show(self) -> str:
        """The value as a person reads it: ``4``, ``1.0``, ``0.5``."""
        return format_value(self.value)


def format_value(value: ParamNumber) -> str:
    if isinstance(value, int):
        return str(value)
    return f"{value:.7g}" if not float(value).is_integer() else f"{value:.1f}"


def parse_param_value(message: Any) -> ParamValue:
    """A decoded PARAM_VALUE message as a ``ParamValue``."""
    raw_id = message.param_id
    name = (
        raw_id.decode("ascii", errors="replace")
        if isinstance(raw_id, bytes | bytearray)
        else str(raw_id)
    ).rstrip("\x00")
    param_type = int(message.param_type)
    return ParamValue(
        name=name,
        value=decode_param_value(float(message.param_value), param_type),
        param_type=param_type,
        index=int(message.param_index),
        count=int(message.param_count),
    )


@dataclass(frozen=True)
class SetRequest:
    """A PARAM_SET to send: ``raw`` is the float field (bytewise for integers)."""

    name: str
    value: ParamNumber
    param_type: int
    raw: float


class ParameterClient:
    """What one vehicle said of its parameters, and which names a caller waits for."""

    def __init__(self) -> None:
        self.known: dict[str, ParamValue] = {}
        """The last PARAM_VALUE of each parameter heard."""
        self._awaited: set[str] = set()

    def await_value(self, name: str) -> None:
        """A request about ``name`` went out: its next PARAM_VALUE is wanted."""
        self._awaited.add(name)

    def forget(self, name: str) -> None:
        self._awaited.discard(name)

    def receive(self, message: Any) -> ParamValue | None:
        """Apply a PARAM_VALUE; returns it when a caller waits for that name."""
        try:
            value = parse_param_value(message)
        except (AttributeError, TypeError, ValueError, struct.error):
            return None
        self.known[value.name] = value
        return value if value.name in self._awaited else None

    def set_request(self, name: str, value: ParamNumber) -> SetRequest:
        """The PARAM_SET for ``value``, in the type the vehicle reported for ``name`` (read
        it first). Raises ``ParameterError``."""
        param_id_bytes(name)
        known = self.known.get(name)
        if known is None:
            raise ParameterError(f"{name}: type unknown (read the parameter first)")
        raw = encode_param_value(value, known.param_type)
        # A REAL32 is sent (and stored) as the float32 nearest to ``value``: that is ``raw``.
        typed: ParamNumber = int(value) if is_integer_type(known.param_type) else raw
        return SetRequest(name, typed, known.param_type, raw)

    @staticmethod
    def mismatch(request: SetRequest, echoed: ParamValue) -> str | None:
        """Why the vehicle's echo does not confirm ``request`` (None: it does)."""
        if echoed.param_type != request.param_type:
            said, sent = (
                TYPE_NAMES.get(t, str(t)) for t in (echoed.param_type, request.param_type)
            )
            return f"{request.name}: vehicle answered type {said}, sent {sent}"
        if not same_value(echoed.value, request.value, request.param_type):
            return (
                f"{request.name}: set to {format_value(request.value)}, "
                f"vehicle says {echoed.show()}"
            )
        return None
