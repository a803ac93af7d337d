"""The MAVLink dialect of the project, with PX4's event messages, which pymavlink lacks.

PX4 v1.15 reports arming refusals, failsafes and health as EVENT messages (MAVLink
``common.xml`` ids 410–413, the events protocol of libevents), not as STATUSTEXT alone
(docs/reference/px4-offboard.md §5 item 5). pymavlink 2.4.50 generates none of the four in
any dialect, so they come out as ``UNKNOWN_410`` … This module defines them the way
pymavlink's generator would (``pymavlink/generator/mavparse.py``): fields in the XML's order,
sent sorted by type size (stable), CRC_EXTRA the X.25 CRC of ``"NAME "`` and ``"type name "``
of every field in wire order (plus the length byte of arrays), folded to one byte, and
registers them in the dialect's ``mavlink_map`` so that pymavlink's parser decodes them.

The dialect is ``development`` (a superset of ``common``; PX4 v1.15 sends CURRENT_MODE, id
436, which only it has). ``mavlink`` below is the one place the project imports the dialect
from (re-exported by ``px4_mavlink.codec``); its constants equal ``common``'s.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from pymavlink.dialects.v20 import development as mavlink
from pymavlink.generator.mavcrc import x25crc

__all__ = [
    "MAVLINK_MSG_ID_CURRENT_EVENT_SEQUENCE",
    "MAVLINK_MSG_ID_EVENT",
    "MAVLINK_MSG_ID_REQUEST_EVENT",
    "MAVLINK_MSG_ID_RESPONSE_EVENT_ERROR",
    "MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET",
    "MAV_EVENT_ERROR_REASON_UNAVAILABLE",
    "Field",
    "MAVLink_current_event_sequence_message",
    "MAVLink_event_message",
    "MAVLink_request_event_message",
    "MAVLink_response_event_error_message",
    "crc_extra",
    "current_event_sequence_send",
    "event_send",
    "mavlink",
    "request_event_send",
    "response_event_error_send",
    "wire_order",
]

MAVLINK_MSG_ID_EVENT = 410
MAVLINK_MSG_ID_CURRENT_EVENT_SEQUENCE = 411
MAVLINK_MSG_ID_REQUEST_EVENT = 412
MAVLINK_MSG_ID_RESPONSE_EVENT_ERROR = 413
MAV_EVENT_CURRENT_SEQUENCE_FLAGS_RESET = 1  # a sequence reset happened (e.g. reboot)
MAV_EVENT_ERROR_REASON_UNAVAILABLE = 0  # the requested event is not available (anymore)
EVENT_ARGUMENTS_LEN = 40

# struct codes and sizes of MAVLink's base types (pymavlink's mavparse and mavgen_python).
_TYPES = {
    "uint8_t": ("B", 1),
    "int8_t": ("b", 1),
    "uint16_t": ("H", 2),
    "int16_t": ("h", 2),
    "uint32_t": ("I", 4),
    "int32_t": ("i", 4),
    "float": ("f", 4),
    "uint64_t": ("Q", 8),
    "int64_t": ("q", 8),
    "double": ("d", 8),
}


@dataclass(frozen=True)
class Field:
    """One field of a message definition: MAVLink base type, name, array length (0: scalar)."""

    type: str
    name: str
    array_length: int = 0


def wire_order(fields: Sequence[Field]) -> list[Field]:
    """The order on the wire: by type size, largest first, stable (no extensions here)."""
    return sorted(fields, key=lambda f: _TYPES[f.type][1], reverse=True)


def crc_extra(name: str, fields: Sequence[Field]) -> int:
    """CRC_EXTRA of a message, as pymavlink's generator computes it (``message_checksum``):
    X.25 over ``"NAME "`` then, per field in wire order, ``"type "``, ``"name "`` and for an
    array its length as one byte; the 16-bit CRC's two bytes XORed together."""
    crc = x25crc()
    crc.accumulate_str(name + " ")
    for field in wire_order(fields):
        crc.accumulate_str(field.type + " ")
        crc.accumulate_str(field.name + " ")
        if field.array_length:
            crc.accumulate([field.array_length])
    return int((crc.crc & 0xFF) ^ (crc.crc >> 8))


class _Px4Message(mavlink.MAVLink_message):  # type: ignore[misc]  # pymavlink is untyped
    """A message defined here rather than generated: the class attributes pymavlink's parser
    reads (``orders``, ``lengths``, ``unpacker``, ``crc_extra`` …) are derived from
    ``definition`` by ``_complete``; ``pack`` writes the fields in wire order."""

    definition: ClassVar[tuple[Field, ...]] = ()

    def __init__(self, **values: Any) -> None:
        mavlink.MAVLink_message.__init__(self, type(self).id, type(self).msgname)
        self._fieldnames = type(self).fieldnames
        self._instance_field = None
        self._instance_offset = -1
        for name, value in values.items():
            setattr(self, name, value)

    def pack(self, mav: Any, force_mavlink1: bool = False) -> bytes:
        flat: list[Any] = []
        for field in wire_order(self.definition):
            value = getattr(self, field.name)
            if field.array_length:
                items = list(value)[: field.array_length]
                flat.extend(items + [0] * (field.array_length - len(items)))
            else:
                flat.append(value)
        payload = self.unpacker.pack(*flat)
        return bytes(self._pack(mav, self.crc_extra, payload, force_mavlink1=force_mavlink1))


def _complete(cls: type[_Px4Message]) -> type[_Px4Message]:
    """Fill in the generated-code attributes of ``cls`` from its ``definition``."""
    fields = cls.definition
    ordered = wire_order(fields)
    cls.fieldnames = [f.name for f in fields]
    cls.ordered_fieldnames = [f.name for f in ordered]
    cls.fieldtypes = [f.type for f in fields]
    cls.fielddisplays_by_name = {}
    cls.fieldenums_by_name = {}
    cls.fieldunits_by_name = {}
    cls.orders = [ordered.index(f) for f in fields]
    cls.lengths = [f.array_length or 1 for f in ordered]
    cls.array_lengths = [f.array_length for f in ordered]
    cls.native_format = bytearray("<" + "".join(_TYPES[f.type][0] for f in ordered), "ascii")
    cls.unpacker = struct.Struct(
        "<" + "".join(f"{f.array_length or ''}{_TYPES[f.type][0]}" for f in ordered)
    )
    cls.crc_extra = crc_extra(cls.msgname, fields)
    cls.instance_field = None
    cls.instance_offset = -1
    return cls


class MAVLink_event_message(_Px4Message):  # noqa: N801  (pymavlink's class names)
    """EVENT (410): one event of a component; ``id`` = component id << 24 | sub id (the
    libevents definitions), ``arguments`` its packed little-endian arguments, ``log_levels``
    internal level in the high nibble, external (what a GCS shows) in the low one."""

    id = MAVLINK_MSG_ID_EVENT
    msgname = "EVENT"
    definition = (
        Field("uint8_t", "destination_component"),
        Field("uint8_t", "destination_system"),
        Field("uint32_t", "id"),
        Field("uint32_t", "event_time_boot_ms"),
        Field("uint16_t", "sequence"),
        Field("uint8_t", "log_levels"),
        Field("uint8_t", "arguments", EVENT_ARGUMENTS_LEN),
    )

    def __init__(
        self,
        destination_component: int,
        destination_system: int,
        id: int,  # the XML's field name (pymavlink names STATUSTEXT's "id" the same way)
        event_time_boot_ms: int,
        sequence: int,
        log_levels: int,
        arguments: Sequence[int],
    ) -> None:
        super().__init__(
            destination_component=destination_component,
            destination_system=destination_system,
            id=id,
            event_time_boot_ms=event_time_boot_ms,
            sequence=sequence,
            log_levels=log_levels,
            arguments=list(arguments),
        )


class MAVLink_current_event_sequence_message(_Px4Message):  # noqa: N801
    """CURRENT_EVENT_SEQUENCE (411): the latest event sequence number, sent periodically
    (PX4: every ~3 s) so that a receiver notices lost events; ``flags`` bit 0: reset."""

    id = MAVLINK_MSG_ID_CURRENT_EVENT_SEQUENCE
    msgname = "CURRENT_EVENT_SEQUENCE"
    definition = (Field("uint16_t", "sequence"), Field("uint8_t", "flags"))

    def __init__(self, sequence: int, flags: int) -> None:
        super().__init__(sequence=sequence, flags=flags)


class MAVLink_request_event_message(_Px4Message):  # noqa: N801
    """REQUEST_EVENT (412): re-send the events ``first_sequence`` … ``last_sequence``."""

    id = MAVLINK_MSG_ID_REQUEST_EVENT
    msgname = "REQUEST_EVENT"
    definition = (
        Field("uint8_t", "target_system"),
        Field("uint8_t", "target_component"),
        Field("uint16_t", "first_sequence"),
        Field("uint16_t", "last_sequence"),
    )

    def __init__(
        self, target_system: int, target_component: int, first_sequence: int, last_sequence: int
    ) -> None:
        super().__init__(
            target_system=target_system,
            target_component=target_component,
            first_sequence=first_sequence,
            last_sequence=last_sequence,
        )


class MAVLink_response_event_error_message(_Px4Message):  # noqa: N801
    """RESPONSE_EVENT_ERROR (413): a requested event is gone; ``sequence_oldest_available``
    the oldest one still held."""

    id = MAVLINK_MSG_ID_RESPONSE_EVENT_ERROR
    msgname = "RESPONSE_EVENT_ERROR"
    definition = (
        Field("uint8_t", "target_system"),
        Field("uint8_t", "target_component"),
        Field("uint16_t", "sequence"),
        Field("uint16_t", "sequence_oldest_available"),
        Field("uint8_t", "reason"),
    )

    def __init__(
        self,
        target_system: int,
        target_component: int,
        sequence: int,
        sequence_oldest_available: int,
        reason: int,
    ) -> None:
        super().__init__(
            target_system=target_system,
            target_component=target_component,
            sequence=sequence,
            sequence_oldest_available=sequence_oldest_available,
            reason=reason,
        )


PX4_MESSAGES: tuple[type[_Px4Message], ...] = tuple(
    _complete(cls)
    for cls in (
        MAVLink_event_message,
        MAVLink_current_event_sequence_message,
        MAVLink_request_event_message,
        MAVLink_response_event_error_message,
    )
)
# pymavlink's parser looks message types up in the dialect module's ``mavlink_map``: adding
# ours there (idempotent; nothing else of ours mutates pymavlink) is what makes it decode them.
for _cls in PX4_MESSAGES:
    mavlink.mavlink_map[_cls.id] = _cls


# ---- senders, named like pymavlink's ``*_send`` (``mav`` is a pymavlink ``MAVLink``) ----------
def event_send(
    mav: Any,
    destination_component: int,
    destination_system: int,
    event_id: int,
    event_time_boot_ms: int,
    sequence: int,
    log_levels: int,
    arguments: bytes,
) -> None:
    """Queue an EVENT; ``arguments`` up to 40 bytes (zero-padded)."""
    if len(arguments) > EVENT_ARGUMENTS_LEN:
        raise ValueError(f"event arguments take {EVENT_ARGUMENTS_LEN} bytes, not {len(arguments)}")
    mav.send(
        MAVLink_event_message(
            destination_component, destination_system, event_id, event_time_boot_ms,
            sequence, log_levels, list(arguments),
        )
    )  # fmt: skip


def current_event_sequence_send(mav: Any, sequence: int, flags: int = 0) -> None:
    """Queue a CURRENT_EVENT_SEQUENCE."""
    mav.send(MAVLink_current_event_sequence_message(sequence, flags))


def request_event_send(
    mav: Any, target_system: int, target_component: int, first_sequence: int, last_sequence: int
) -> None:
    """Queue a REQUEST_EVENT for the events ``first_sequence`` … ``last_sequence``."""
    mav.send(
        MAVLink_request_event_message(
            target_system, target_component, first_sequence, last_sequence
        )
    )


def response_event_error_send(
    mav: Any,
    target_system: int,
    target_component: int,
    sequence: int,
    sequence_oldest_available: int,
    reason: int = MAV_EVENT_ERROR_REASON_UNAVAILABLE,
) -> None:
    """Queue a RESPONSE_EVENT_ERROR."""
    mav.send(
        MAVLink_response_event_error_message(
            target_system, target_component, sequence, sequence_oldest_available, reason
        )
    )
