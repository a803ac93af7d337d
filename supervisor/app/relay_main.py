"""The mocap relay process's entry point (``serve`` starts it when it knows the vehicles'
addresses: the embedded world's, or ``vehicles.addresses``)."""

from __future__ import annotations

import asyncio
import logging
import socket
import time
from multiprocessing.connection import Connection
from typing import Any

from supervisor.app.assembly import body_names_from_config, qtm_client_from_config
from supervisor.app.child_process import stop_event
from supervisor.app.config import Config, host_port
from supervisor.logs.logging_setup import configure_logging
from supervisor.mavlink.codec import MavlinkCodec
from supervisor.mavlink.relay import MocapRelay, VisionTarget
from supervisor.mavlink.signing import SigningKey, signing_timestamp
from supervisor.mavlink.vision import VisionEncoder
from supervisor.runtime.cpu import raise_priority, title_process

log = logging.getLogger(__name__)

GROUND_STATION_SYSTEM = 255  # the system id our links speak as
VISION_COMPONENT = 197  # MAV_COMP_ID_VISUAL_INERTIAL_ODOMETRY


def relay_addresses(config: Config, world: dict[str, Any] | None) -> list[str] | None:
    """Where the relay sends each vehicle's poses, if known before any vehicle talks."""
    if world is not None:
        return list(world["vehicles"])
    return list(config.vehicles.addresses) if config.vehicles.addresses else None


def run_relay_process(
    config: Config,
    world: dict[str, Any] | None,
    sockets: tuple[socket.socket, socket.socket],
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
        vehicles = zip((names.uav1, names.uav2), addresses, sockets, system_ids, strict=True)
        for body, address, sock, system_id in vehicles:
            codec = MavlinkCodec(GROUND_STATION_SYSTEM, VISION_COMPONENT)
            if config.vehicles.signing and signing_keys is not None:
                codec.sign(SigningKey(signing_keys[system_id]), signing_timestamp(time.time()))
            encoder = VisionEncoder(codec.messages, config.vehicles.mocap_message)
            targets.append(VisionTarget(body, codec, encoder, sock, host_port(address)))
        log.info("mocap relay: %s; poses of %s to %s", raise_priority(), names, addresses)
        async with stop_event(parent) as stop, qtm_client_from_config(config, world) as mocap:
            await MocapRelay(mocap, targets).run(stop)

    asyncio.run(main())
