"""MAVLink 2 message signing without I/O: who may speak on a signed link.

A signed frame carries a link id, a 48-bit timestamp (10 µs since 2015-01-01 GMT) and the
first 6 bytes of SHA-256(key ‖ frame up to the timestamp) (mavlink.io, "Message
signing"). pymavlink signs what we send (``MAVLink.signing``); incoming frames are checked
here, in the C library's order (``mavlink_signature_check`` in ``mavlink_helpers.h``, what
PX4 runs): the signature first, then the timestamp against the sender's stream (link id,
system, component) — a stream's timestamp must grow, and a new stream is accepted only
if it is at most one minute behind our own timestamp. Only a frame that passes both moves
any state. pymavlink 2.4.50's ``check_signature`` records a stream's timestamp *before* it
checks the signature, so one forged frame with a future timestamp would make every true
frame of that stream look replayed: we do not use it (docs/reference/mavlink-signing.md).
"""

from __future__ import annotations

import hashlib
import hmac
from dataclasses import dataclass, field
from enum import Enum

KEY_BYTES = 32
SIGNATURE_BYTES = 13  # link id (1), timestamp (6), signature (6)
SIGNED_FLAG = 0x01  # MAVLINK_IFLAG_SIGNED in a MAVLink 2 header's incompat_flags
MAVLINK2_MAGIC = 0xFD
EPOCH_UNIX_S = 1420070400  # 2015-01-01 00:00:00 GMT
TICKS_PER_S = 100_000  # the timestamp counts 10 µs
NEW_STREAM_SLACK = 60 * TICKS_PER_S  # a new stream at most one minute behind us


def signing_timestamp(unix_time_s: float) -> int:
    """A signing timestamp for the Unix time ``unix_time_s`` [s] (10 µs since 2015)."""
    return max(0, int((unix_time_s - EPOCH_UNIX_S) * TICKS_PER_S))


class Verdict(Enum):
    """What the signature check made of one frame."""

    ACCEPTED = "accepted"
    UNSIGNED = "unsigned"  # no signature (or MAVLink 1), and not on the allow-list
    BAD_SIGNATURE = "bad_signature"  # signed, but not with our key
    REPLAYED = "replayed"  # signed with our key, timestamp not newer than its stream's


@dataclass(frozen=True)
class SigningKey:
    """One link's secret: ``secret`` 32 bytes; ``link_id`` the id our frames carry;
    ``accept_unsigned`` the message ids taken without a signature (PX4's allow-list; the
    supervisor takes none)."""

    secret: bytes = field(repr=False)
    link_id: int = 0
    accept_unsigned: frozenset[int] = frozenset()

    def __post_init__(self) -> None:
        if len(self.secret) != KEY_BYTES:
            raise ValueError(f"a MAVLink signing key is {KEY_BYTES} bytes, not {len(self.secret)}")
        if not 0 <= self.link_id <= 255:
            raise ValueError(f"link id {self.link_id} is not a byte")

    @property
    def blank(self) -> bool:
        """All zeros: SETUP_SIGNING's way of saying "stop signing"."""
        return not any(self.secret)


def is_signed(frame: bytes) -> bool:
    """Whether ``frame`` (one whole MAVLink frame) carries a signature."""
    return len(frame) > 2 and frame[0] == MAVLINK2_MAGIC and bool(frame[2] & SIGNED_FLAG)


class SignatureCheck:
    """The receiving half of signing with ``key``: the streams heard and our timestamp
    (``timestamp``: the one we sign with next, never behind a frame we accepted)."""

    def __init__(self, key: SigningKey, timestamp: int) -> None:
        self.key = key
        self.timestamp = timestamp
        self._streams: dict[tuple[int, int, int], int] = {}

    def check(self, frame: bytes, message_id: int, system: int, component: int) -> Verdict:
        """The verdict on one whole frame from ``system``/``component``; only an accepted
        signed frame advances its stream (and our timestamp)."""
        if not is_signed(frame) or len(frame) < SIGNATURE_BYTES + 12:
            return Verdict.ACCEPTED if message_id in self.key.accept_unsigned else Verdict.UNSIGNED
        signed_part, signature = frame[:-6], frame[-6:]
        expected = hashlib.sha256(self.key.secret + signed_part).digest()[:6]
        if not hmac.compare_digest(expected, signature):
            # The C library lets a badly signed allow-listed message through too.
            if message_id in self.key.accept_unsigned:
                return Verdict.ACCEPTED
            return Verdict.BAD_SIGNATURE
        link_id = frame[-SIGNATURE_BYTES]
        stamp = int.from_bytes(frame[-12:-6], "little")
        stream = (link_id, system, component)
        last = self._streams.get(stream)
        if last is None:
            if stamp + NEW_STREAM_SLACK < self.timestamp:
                return Verdict.REPLAYED
        elif stamp <= last:
            return Verdict.REPLAYED
        self._streams[stream] = stamp
        self.timestamp = max(self.timestamp, stamp)
        return Verdict.ACCEPTED
