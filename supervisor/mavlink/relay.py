"""The mocap relay: each new motion-capture frame to each PX4's estimator (EKF2), in a
process of its own, so that PX4's own failsafe landing keeps a position whatever happens to
the control loop (a PX4 that loses vision lands blind and, measured on v1.15.4, escalates to
a lockdown within 6 s: tests/test_px4_sitl.py).

It sends through the very UDP socket of each vehicle's link (``serve`` binds it and hands it
to both processes; the relay never reads from it): PX4 streams its link to the first address
that talks to it and only there (measured on v1.15.4), so a relay with a socket of its own
would take the flight process's telemetry, or get its poses ignored. Poses are stamped with
their arrival time on the monotonic clock, the time base of the link's TIMESYNC answers.
With signing on, each target's codec signs with the vehicle's key (a stream of its own:
the relay's component, 197), its timestamp kept up with the wall clock.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import time
from dataclasses import dataclass

from mocap.client import MocapSource
from px4_mavlink.codec import MavlinkCodec
from px4_mavlink.signing import signing_timestamp
from px4_mavlink.transport import Address
from supervisor.mavlink.vision import VisionEncoder


@dataclass
class VisionTarget:
    """One vehicle: the rigid body that is it, and how its poses reach it."""

    body: str
    codec: MavlinkCodec
    encoder: VisionEncoder
    sock: socket.socket
    peer: Address

    def send(self) -> None:
        for frame in self.codec.outgoing():
            with contextlib.suppress(BlockingIOError, OSError):  # a full buffer drops one
                self.sock.sendto(frame, self.peer)


class MocapRelay:
    """Forwards every new frame of ``mocap`` to each target as it arrives."""

    def __init__(self, mocap: MocapSource, targets: list[VisionTarget]) -> None:
        self.mocap = mocap
        self.targets = targets

    def forward(self) -> None:
        frame = self.mocap.latest()
        if frame is None:
            return
        stamp = signing_timestamp(time.time())
        for target in self.targets:
            pose = frame.bodies.get(target.body)
            if pose is None or not pose.tracked:
                continue
            target.codec.keep_time(stamp)  # signed: a timestamp no older than the wall clock
            if target.encoder.queue(pose.position_m, pose.quaternion, frame.receive_time_s):
                target.send()

    async def run(self, stop: asyncio.Event) -> None:
        """Relay until ``stop`` is set."""
        self.mocap.on_frame(self.forward)
        try:
            await stop.wait()
        finally:
            self.mocap.on_frame(None)
