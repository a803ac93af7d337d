"""The simulated world as a service: ``uavbar-supervisor sitl`` runs it in the foreground,
``serve`` (with ``sim.embedded``) in a child process. Plant, two simulated PX4s and the
QTM server, built from the configuration, in real time until SIGINT/SIGTERM (or, as a
child, until its parent goes away)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
from collections.abc import Callable
from multiprocessing.connection import Connection
from typing import Any

from sim.plant import Plant
from sim.px4_endpoint import API_LOCAL_PORT, Px4Endpoint
from sim.world import SimulatedVehicle, SimulatedWorld
from supervisor.app.assembly import (
    mocap_params_from_config,
    plant_params_from_config,
    px4_params_from_config,
)
from supervisor.app.config import Config
from supervisor.logs.logging_setup import configure_logging
from supervisor.runtime.cpu import single_threaded_blas

log = logging.getLogger(__name__)


def build_world(
    config: Config, qtm_port: int, vehicle_local_ports: tuple[int, int], host: str = "127.0.0.1"
) -> SimulatedWorld:
    """The world of ``config``; vehicle i sends to the supervisor's ``vehicles.ports[i]``
    until a client talks to it."""

    def vehicle(plant: Plant, uav: int) -> SimulatedVehicle:
        return Px4Endpoint(
            uav - 1,
            plant.uav(uav),
            px4_params_from_config(config, uav),
            host=host,
            local_port=vehicle_local_ports[uav - 1],
            client_port=config.vehicles.ports[uav - 1] or 14540 + uav - 1,
        )

    return SimulatedWorld(
        plant_params_from_config(config),
        mocap_params_from_config(config),
        vehicle,
        body_names=config.mocap.bodies,
        qtm_host=host,
        qtm_port=qtm_port,
    )


async def run_world(
    config: Config,
    qtm_port: int,
    vehicle_local_ports: tuple[int, int],
    on_ready: Callable[[dict[str, Any]], None],
    stop: asyncio.Event,
) -> None:
    """Start the world, report its addresses, run it until ``stop`` is set."""
    world = build_world(config, qtm_port, vehicle_local_ports)
    addresses = await world.start()
    try:
        on_ready(
            {
                "qtm": f"{addresses.qtm_host}:{addresses.qtm_port}",
                "vehicles": list(addresses.vehicles),
            }
        )
        runner = asyncio.create_task(world.run())
        await stop.wait()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner
    finally:
        await world.close()


def run_world_process(config: Config, ready: Connection) -> None:
    """Child-process entry of ``serve``: free ports, report them on ``ready``, run until
    SIGTERM or until the parent closes its end of ``ready``."""
    configure_logging()
    single_threaded_blas()

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        loop.add_signal_handler(signal.SIGTERM, stop.set)
        loop.add_signal_handler(signal.SIGINT, lambda: None)  # the parent decides
        loop.add_reader(ready.fileno(), stop.set)  # readable at EOF: the parent is gone
        try:
            await run_world(config, 0, (0, 0), ready.send, stop)
        except Exception as error:
            ready.send({"error": repr(error)})
            raise
        finally:
            loop.remove_reader(ready.fileno())

    asyncio.run(main())


def run_sitl(config: Config) -> int:
    """``uavbar-supervisor sitl``: the world on the conventional ports, in the foreground."""

    def show(addresses: dict[str, Any]) -> None:
        bodies = ", ".join(config.mocap.bodies)
        log.info("QTM RT server   tcp %s (bodies: %s)", addresses["qtm"], bodies)
        for i, vehicle in enumerate(addresses["vehicles"]):
            port = config.vehicles.ports[i] or 14540 + i
            log.info(
                "PX4 vehicle %d   udp %s -> 127.0.0.1:%d (system id %d)",
                i + 1,
                vehicle,
                port,
                i + 1,
            )
        log.info("running in real time; Ctrl-C stops")

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        ports = (API_LOCAL_PORT, API_LOCAL_PORT + 1)
        await run_world(config, config.mocap.port, ports, show, stop)

    asyncio.run(main())
    return 0
