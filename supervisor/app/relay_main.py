"""The mocap relay process's entry point (``serve`` starts it when it knows the vehicles'
addresses: the embedded world's, or ``vehicles.addresses``). What it relays has passed the
client's filters and the fusion's innovation gate (``PlausibleSource``): a jump no rigid body
can make never reaches a PX4's estimator either."""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from collections.abc import Callable
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from mocap.client import MocapSource, MocapStats
from mocap.fusion import MocapFusion
from mocap.qtm_protocol import MocapFrame
from px4_mavlink.codec import MavlinkCodec
from px4_mavlink.signing import SigningKey, signing_timestamp
from supervisor.app.assembly import (
    body_names_from_config,
    fusion_from_config,
    qtm_client_from_config,
)
from supervisor.app.child_process import stop_event
from supervisor.app.config import Config, host_port
from supervisor.logs.logging_setup import configure_logging
from supervisor.mavlink.relay import MocapRelay, VisionTarget
from supervisor.mavlink.vision import VisionEncoder
from supervisor.runtime.cpu import raise_priority, title_process

log = logging.getLogger(__name__)

GROUND_STATION_SYSTEM = 255  # the system id our links speak as
VISION_COMPONENT = 197  # MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY
MAX_KEPT_FRAMES = 256  # as the client's own store


class PlausibleSource:
    """A ``MocapSource`` whose frames went through ``fusion``'s gate: a refused pose is
    passed on as untracked. Repeats are not refused here (the relay does not know whether
    the bodies fly: the flight process does, and hands the vehicles over)."""

    def __init__(self, source: MocapSource, fusion: MocapFusion) -> None:
        self.source = source
        self.fusion = fusion
        self._latest: MocapFrame | None = None
        self._frames: list[MocapFrame] = []

    def latest(self) -> MocapFrame | None:
        """The newest frame, gated."""
        self._take()
        return self._latest

    def drain(self) -> list[MocapFrame]:
        """The gated frames since the last call (at most ``MAX_KEPT_FRAMES``)."""
        self._take()
        frames, self._frames = self._frames, []
        return frames

    def stats(self) -> MocapStats:
        """The source's counters."""
        return self.source.stats()

    def on_frame(self, listener: Callable[[], None] | None) -> None:
        """Call ``listener`` whenever the source accepts a frame."""
        self.source.on_frame(listener)

    def record(self, path: Path | None) -> dict[str, Any] | None:
        """Record the source's stream."""
        return self.source.record(path)

    def recording_failure(self) -> OSError | None:
        """The write error that ended the source's recording, else None."""
        return self.source.recording_failure()

    def _take(self) -> None:
        for frame in self.source.drain():
            self._latest = self.fusion.plausible(frame)
            self._frames.append(self._latest)
            del self._frames[:-MAX_KEPT_FRAMES]


def relay_addresses(config: Config, world: dict[str, Any] | None) -> list[str] | None:
    """Where the relay sends each vehicle's poses, if known before any vehicle talks."""
    if world is not None:
        return list(world["vehicles"])
    return list(config.vehicles.addresses) if config.vehicles.addresses else None


def run_relay_process(
    config: Config,
    world: dict[str, Any] | None,
    sockets: tuple[socket.socket, ...],
    parent: Connection,
    signing_keys: dict[int, bytes] | None = None,
) -> None:
    """Child-process entry: relay through the links' ``sockets`` until SIGTERM or until
    ``parent`` closes; with ``vehicles.signing``, each vehicle's poses are signed with its
    key (``signing_keys`` by system id)."""
    configure_logging()
    title_process("relay")
    addresses = relay_addresses(config, world)
    assert addresses is not None, "serve starts the relay only with known addresses"
    names = body_names_from_config(config)

    async def main() -> None:
        targets = []
        system_ids = config.vehicles.system_ids
        vehicles = zip(names.uavs, addresses, sockets, system_ids, strict=True)
        for body, address, sock, system_id in vehicles:
            codec = MavlinkCodec(GROUND_STATION_SYSTEM, VISION_COMPONENT)
            if config.vehicles.signing and signing_keys is not None:
                codec.sign(SigningKey(signing_keys[system_id]), signing_timestamp(time.time()))
            encoder = VisionEncoder(codec.messages, config.vehicles.mocap_message)
            targets.append(VisionTarget(body, codec, encoder, sock, host_port(address)))
        log.info("mocap relay: %s; poses of %s to %s", raise_priority(), names, addresses)
        async with stop_event(parent) as stop, qtm_client_from_config(config, world) as mocap:
            await MocapRelay(PlausibleSource(mocap, fusion_from_config(config)), targets).run(stop)

    asyncio.run(main())
