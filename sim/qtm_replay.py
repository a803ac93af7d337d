"""A QTM RT server that serves a recording (``mocap.recording``) with its recorded timing.

It is the simulator's ``QtmServer`` (the same TCP commands: greeting, ``Version``,
``GetParameters 6D`` with the recording's body names, ``StreamFrames`` over UDP or TCP, …)
whose frames are the recorded packets instead of poses from a source: packet k goes out at
the recorded arrival time of packet k after the first client asked for frames, byte for
byte when the client asked for the recorded component (else its poses re-encoded in the
component asked for, frame number and timestamp kept). With ``loop`` the recording starts
over at its end, frame numbers and timestamps carrying on from the last pass (one frame
period later), so that a client sees one continuous stream rather than a restart.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import statistics
import struct
from typing import Any

from mocap.qtm_protocol import (
    DATA_HEADER,
    HEADER,
    DataPacket,
    Packet,
    PacketType,
    decode_datagram,
    encode_packet,
    frame_from_packet,
    packet_from_poses,
)
from mocap.recording import Recording
from sim.qtm_server import QtmServer, _Connection


def _frame_period_us(recording: Recording) -> int:
    """The recording's median timestamp step [µs] (one frame at its rate)."""
    stamps = [p.timestamp_us for _, p in recording.decoded() if isinstance(p, DataPacket)]
    steps = [b - a for a, b in itertools.pairwise(stamps) if b > a]
    return round(statistics.median(steps)) if steps else 10_000


class QtmReplayServer(QtmServer):
    """Serves ``recording`` on ``host:port``; ``passes`` counts the passes finished."""

    def __init__(self, recording: Recording, *, loop: bool = False, **server: Any) -> None:
        if not recording.packets:
            raise ValueError("the recording holds no packet")
        super().__init__(recording.body_names, rate_hz=None, **server)
        self.recording = recording
        self.loop = loop
        self.passes = 0
        self.finished = asyncio.Event()
        """Set when the last packet of a recording played once (``loop`` off) went out."""
        self._streaming = asyncio.Event()
        self._player: asyncio.Task[None] | None = None

    async def start(self) -> None:
        await super().start()
        self._player = asyncio.create_task(self._play(), name="qtm-replay")

    async def close(self) -> None:
        if self._player is not None:
            self._player.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._player
            self._player = None
        await super().close()

    def _stream_frames(self, connection: _Connection, arguments: str) -> Packet | None:
        reply = super()._stream_frames(connection, arguments)
        if connection.stream is not None:
            self._streaming.set()  # the recording's clock starts with the first stream
        return reply

    async def _play(self) -> None:
        await self._streaming.wait()
        loop = asyncio.get_running_loop()
        packets = self.recording.packets
        first_frame, first_stamp = _first_data(self.recording)
        period_us = _frame_period_us(self.recording)
        frame_shift = stamp_shift = 0
        while True:
            start = loop.time()
            last = (first_frame, first_stamp)
            for packet in packets:
                await asyncio.sleep(
                    max(0.0, start + packet.arrival_s - packets[0].arrival_s - loop.time())
                )
                data = _shifted(packet.data, frame_shift, stamp_shift)
                last = self._emit_recorded(data) or last
            self.passes += 1
            if not self.loop:
                self.finished.set()
                return
            frame_shift = last[0] + 1 - first_frame
            stamp_shift = last[1] + period_us - first_stamp

    def _emit_recorded(self, data: bytes) -> tuple[int, int] | None:
        """Send one recorded packet to every streaming client; the frame number and
        timestamp it carried, for a data packet."""
        decoded = decode_datagram(data)
        streaming = [c for c in self._connections if c.stream is not None]
        if isinstance(decoded, DataPacket):
            self.frame_number = decoded.frame_number
        for connection in streaming:
            stream = connection.stream
            assert stream is not None
            if not self._passes(connection):
                continue
            out = data
            if isinstance(decoded, DataPacket) and stream.components != (self.recording.component,):
                out = self._reencoded(decoded, stream.components)
            self._send(connection, out)
            self.frames_sent += 1
        if isinstance(decoded, DataPacket):
            return decoded.frame_number, decoded.timestamp_us
        return None

    def _reencoded(self, packet: DataPacket, components: tuple[Any, ...]) -> bytes:
        frame = frame_from_packet(packet, self.body_names, preferred=self.recording.component)
        return encode_packet(
            packet_from_poses(
                packet.frame_number,
                packet.timestamp_us,
                self.body_names,
                frame.bodies,
                components,
                self.residual_mm,
            )
        )


def _first_data(recording: Recording) -> tuple[int, int]:
    """The frame number and timestamp of the recording's first data packet."""
    for _, packet in recording.decoded():
        if isinstance(packet, DataPacket):
            return packet.frame_number, packet.timestamp_us
    return 0, 0


def _shifted(data: bytes, frame_shift: int, stamp_shift_us: int) -> bytes:
    """A data packet with its frame number and timestamp moved on (a looped pass)."""
    if not (frame_shift or stamp_shift_us) or HEADER.unpack_from(data)[1] != PacketType.DATA:
        return data
    stamp, frame, count = DATA_HEADER.unpack_from(data, HEADER.size)
    out = bytearray(data)
    struct.pack_into(
        DATA_HEADER.format,
        out,
        HEADER.size,
        stamp + stamp_shift_us,
        (frame + frame_shift) & 0xFFFFFFFF,
        count,
    )
    return bytes(out)
