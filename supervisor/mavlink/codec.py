"""MAVLink 2 frames without I/O (sans-IO, as h11): datagrams in, messages out; messages in,
frames out.

pymavlink's ``MAVLink`` object both builds messages and writes them to a file; here its
file is an in-memory queue, so ``messages.heartbeat_send(...)`` only queues the encoded frame
(sequence numbers and all, as pymavlink keeps them) and the adapter takes the frames with
``outgoing()`` and sends them however it moves bytes. The supervisor's link and the
simulated PX4 both use this codec over ``supervisor.mavlink.transport``.

``mavlink`` here is the project's one MAVLink dialect (``development``, a superset of
``common``, with PX4's EVENT messages added: ``supervisor.mavlink.px4_messages``); import it
from here. ``codec.messages.send(msg)`` queues any message, the added ones included.
"""

from __future__ import annotations

from dataclasses import dataclass

from supervisor.mavlink.px4_messages import mavlink

__all__ = ["PARSE_ERRORS", "Decoded", "MavlinkCodec", "mavlink"]

# What pymavlink raises on bytes it cannot make sense of (a fuzzer found each of them).
PARSE_ERRORS = (mavlink.MAVError, ValueError, IndexError, TypeError, OverflowError)


class _FrameQueue:
    """The file pymavlink writes to: one ``write`` per encoded frame."""

    def __init__(self) -> None:
        self.frames: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data))


@dataclass(frozen=True)
class Decoded:
    """One datagram's valid messages, and how many pieces of it were not a valid frame."""

    messages: list[mavlink.MAVLink_message]
    bad_data: int


class MavlinkCodec:
    """Encoder and decoder for one MAVLink endpoint (``system``/``component``: our ids)."""

    def __init__(self, system: int, component: int) -> None:
        self._queue = _FrameQueue()
        self.messages = mavlink.MAVLink(self._queue, srcSystem=system, srcComponent=component)
        """Build and queue messages with its ``*_send`` methods (pymavlink's names)."""
        self.messages.robust_parsing = True

    def outgoing(self) -> list[bytes]:
        """The frames queued since the last call, oldest first."""
        frames, self._queue.frames = self._queue.frames, []
        return frames

    def decode(self, datagram: bytes) -> Decoded:
        """Every valid message in ``datagram``; never raises on bad bytes."""
        parser = self.messages
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
        return Decoded(valid, len(parsed) - len(valid))
