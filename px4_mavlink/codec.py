"""MAVLink 2 frames without I/O (sans-IO, as h11): datagrams in, messages out; messages in,
frames out.

pymavlink's ``MAVLink`` object both builds messages and writes them to a file; here its
file is an in-memory queue, so ``messages.heartbeat_send(...)`` only queues the encoded frame
(sequence numbers and all, as pymavlink keeps them) and the adapter takes the frames with
``outgoing()`` and sends them however it moves bytes. The supervisor's link and the
simulated PX4 both use this codec over ``px4_mavlink.transport``.

Signing (``sign``): every frame we queue is signed (pymavlink's ``MAVLink.signing``) and every
frame received is checked by ``px4_mavlink.signing`` — frames refused there are
counted by why (unsigned, bad signature, replayed), never decoded into messages.

``mavlink`` here is the project's one MAVLink dialect (``development``, a superset of
``common``, with PX4's EVENT messages added: ``px4_mavlink.px4_messages``); import it
from here. ``codec.messages.send(msg)`` queues any message, the added ones included.
"""

from __future__ import annotations

from dataclasses import dataclass

from px4_mavlink.px4_messages import mavlink
from px4_mavlink.signing import SignatureCheck, SigningKey, Verdict

__all__ = ["PARSE_ERRORS", "Decoded", "MavlinkCodec", "Refused", "mavlink"]

# What pymavlink raises on bytes it cannot make sense of (a fuzzer found each of them).
PARSE_ERRORS = (mavlink.MAVError, ValueError, IndexError, TypeError, OverflowError)


class _FrameQueue:
    """The file pymavlink writes to: one ``write`` per encoded frame."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


@dataclass(frozen=True)
class Refused:
    """A valid frame the signature check refused: why, and who it claims to be from."""

    verdict: Verdict
    system: int
    component: int
    message_type: str


@dataclass(frozen=True)
class Decoded:
    """One datagram's valid messages, how many pieces of it were not a valid frame, and
    the frames signing refused."""

    messages: list[mavlink.MAVLink_message]
    bad_data: int
    refused: tuple[Refused, ...] = ()


class MavlinkCodec:
    """Encoder and decoder for one MAVLink endpoint (``system``/``component``: our ids)."""

    def __init__(self, system: int, component: int) -> None:
        self._queue = _FrameQueue()
        self.messages = mavlink.MAVLink(self._queue, srcSystem=system, srcComponent=component)
        """Build and queue messages with its ``*_send`` methods (pymavlink's names)."""
        self.messages.robust_parsing = True
        # Parsed by a MAVLink object of its own, which never checks signatures (its
        # signing has no key): the check is ours (``px4_mavlink.signing``).
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self._check: SignatureCheck | None = None

    def sign(self, key: SigningKey | None, timestamp: int = 0) -> None:
        """Sign everything queued from now on with ``key`` and refuse what it does not
        sign, starting at ``timestamp`` (10 µs since 2015: ``signing.signing_timestamp``)
        or later; None: neither sign nor check (what a PX4 without a key does)."""
        signing = self.messages.signing
        if key is None:
            signing.secret_key, signing.sign_outgoing, self._check = None, False, None
            return
        signing.secret_key = key.secret
        signing.link_id = key.link_id
        signing.sign_outgoing = True
        signing.timestamp = max(signing.timestamp, timestamp)
        self._check = SignatureCheck(key, signing.timestamp)

    @property
    def signing_key(self) -> SigningKey | None:
        """The key we sign and check with (None: unsigned)."""
        return self._check.key if self._check is not None else None

    @property
    def signing_timestamp(self) -> int:
        """The timestamp our next signed frame carries."""
        return int(self.messages.signing.timestamp)

    def keep_time(self, timestamp: int) -> None:
        """Move our signing timestamp up to ``timestamp`` (the wall clock's) when it lags:
        it only counts frames otherwise, and a receiver that restarts takes a stream at
        most one minute behind its own time."""
        signing = self.messages.signing
        signing.timestamp = max(signing.timestamp, timestamp)

    def outgoing(self) -> list[bytes]:
        """The frames queued since the last call, oldest first."""
        frames, self._queue.frames = self._queue.frames, []
        return frames

    def decode(self, datagram: bytes) -> Decoded:
        """Every valid message in ``datagram`` that signing lets through; never raises on
        bad bytes."""
        parser = self._parser
        try:
            parsed = parser.parse_buffer(datagram) or []
        except PARSE_ERRORS:
            return Decoded([], 1)
        finally:
            # A datagram holds whole frames: what is left is garbage, not the start of the
            # next datagram's frame (pymavlink's parser would prepend it).
            parser.buf, parser.buf_index = bytearray(), 0
            parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        valid = [m for m in parsed if m.get_type() != "BAD_DATA"]
        bad_data = len(parsed) - len(valid)
        if self._check is None:
            return Decoded(valid, bad_data)
        return self._checked(valid, bad_data)

    def _checked(self, messages: list[mavlink.MAVLink_message], bad_data: int) -> Decoded:
        check = self._check
        assert check is not None
        signing = self.messages.signing
        check.timestamp = max(check.timestamp, signing.timestamp)
        accepted, refused = [], []
        for message in messages:
            system, component = message.get_srcSystem(), message.get_srcComponent()
            frame = bytes(message.get_msgbuf())
            verdict = check.check(frame, message.get_msgId(), system, component)
            if verdict is Verdict.ACCEPTED:
                accepted.append(message)
            else:
                refused.append(Refused(verdict, system, component, message.get_type()))
        # What we sign next is never behind what we accepted (mavlink_signature_check).
        signing.timestamp = max(signing.timestamp, check.timestamp)
        return Decoded(accepted, bad_data, tuple(refused))
