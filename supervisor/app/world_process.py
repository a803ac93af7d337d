"""The simulated world as a service: ``uavbar-supervisor sitl`` runs it in the foreground,
``serve`` (with ``sim.embedded``) in a child process. Plant, one simulated PX4 per UAV and
the QTM server, built from the configuration, in real time until SIGINT/SIGTERM (or, as a
child, until its parent goes away). As ``serve``'s child it also answers the API process's
fault-injection and reset requests on the world channel (``handle_world_request``)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
import socket
from collections.abc import Callable, Sequence
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from controllers.formation_equilibria import hanging_mass_shares_kg
from sim.faults import FaultError, parse_fault
from sim.hil_sensors import HilSensors
from sim.motor_mixer import QuadMixer
from sim.plant import Plant
from sim.px4_control import RateGains
from sim.px4_endpoint import API_LOCAL_PORT, CATALOG_PATH, Px4Endpoint
from sim.px4_firmware import (
    AIRFRAME,
    LabParameters,
    Px4Process,
    free_instances,
    rate_gain_multipliers,
    resolve_px4_dir,
)
from sim.px4_sitl import Px4SitlVehicle
from sim.world import (
    SimulatedVehicle,
    SimulatedWorld,
    VehicleFactory,
    WorldRefusedError,
)
from supervisor.app.child_process import stop_event
from supervisor.app.config import Config
from supervisor.app.sim_assembly import (
    mocap_params_from_config,
    plant_params_from_config,
    px4_params_from_config,
)
from supervisor.flight.operator_requests import Outcome, Reply
from supervisor.ipc.channel import ChannelClosedError, ChannelServer, WorldChannel
from supervisor.ipc.world_client import serve_world_requests
from supervisor.ipc.world_messages import (
    ClearFaults,
    ListFaults,
    ResetWorld,
    StartFault,
    WorldRequest,
)
from supervisor.logs.logging_setup import configure_logging
from supervisor.runtime.cpu import raise_priority, single_threaded_blas, title_process

log = logging.getLogger(__name__)

# The world's frames and PX4's sensor samples are punctual: a late one is a real gap to
# whoever reads it. SCHED_FIFO below the flight process, whose ticks the simulated world
# must never delay.
WORLD_PRIORITY = 5


def build_world(
    config: Config, qtm_port: int, vehicle_local_ports: Sequence[int], host: str = "127.0.0.1"
) -> SimulatedWorld:
    """The world of ``config``, one vehicle per UAV; simulated vehicle i listens on
    ``vehicle_local_ports[i]`` (one per UAV; 0: a free port) and sends to the supervisor's
    ``vehicles.ports[i]`` until a client talks to it, a real PX4 to its instance's port."""
    n = config.system.n_vehicles
    if len(vehicle_local_ports) != n:
        raise ValueError(f"vehicle_local_ports: one per UAV ({n}), got {list(vehicle_local_ports)}")
    plant_params = plant_params_from_config(config)
    events = CATALOG_PATH
    if config.sim.vehicles == "px4_sitl":
        px4_dir = resolve_px4_dir(config.sim.px4_dir)
        mixer = QuadMixer.from_airframe(px4_dir / "etc" / "init.d-posix" / "airframes" / AIRFRAME)
        limits = mixer.torque_limits_nm()
        plant_params = plant_params_from_config(
            config, (mixer.thrust_max_n, (float(limits[0]), float(limits[1]), float(limits[2])))
        )
        vehicle = _px4_sitl_vehicles(config, px4_dir, mixer, host)
        events = px4_dir / "etc" / "extras" / "all_events.json.xz"
    else:

        def vehicle(plant: Plant, uav: int) -> SimulatedVehicle:
            return Px4Endpoint(
                uav - 1,
                plant.uav(uav),
                px4_params_from_config(config, uav),
                host=host,
                local_port=vehicle_local_ports[uav - 1],
                client_port=config.vehicles.ports[uav - 1] or 14540 + uav - 1,
            )

    world = SimulatedWorld(
        plant_params,
        mocap_params_from_config(config),
        vehicle,
        body_names=config.mocap.bodies,
        qtm_host=host,
        qtm_port=qtm_port,
        event_definitions=events,
        fault_seed=config.sim.seed,
    )
    return world


def _px4_sitl_vehicles(
    config: Config, px4_dir: Path, mixer: QuadMixer, host: str
) -> VehicleFactory:
    """One real PX4 per UAV, on consecutive free instance numbers, each in its own folder
    under the log folder (PX4's console output in ``px4.log`` there), booting with a lab's
    parameters."""
    instances = free_instances(config.system.n_vehicles)
    params = config.system.to_params()
    shares_kg = hanging_mass_shares_kg(params)
    unit_torque = mixer.unit_torque_nm()

    def vehicle(plant: Plant, uav: int) -> SimulatedVehicle:
        k = uav - 1
        carried_n = (params.uavs[k].mass_kg + shares_kg[k]) * params.gravity_mps2
        folder = Path(config.log.folder).resolve() / "px4" / f"uav{uav}"
        folder.mkdir(parents=True, exist_ok=True)
        for stored in folder.glob("parameters*.bson"):
            stored.unlink()  # boot from the airframe defaults and ours, not a past run's
        parameters = LabParameters(
            system_id=config.vehicles.system_ids[k],
            offboard_loss_timeout_s=config.vehicles.offboard_loss_timeout_s,
            hover_thrust=round(carried_n / mixer.thrust_max_n, 3),
            # The rate loop as fast as our simulated PX4's, which the MPC's rate
            # look-ahead is tuned for.
            rate_gain_k=rate_gain_multipliers(
                (float(unit_torque[0]), float(unit_torque[1]), float(unit_torque[2])),
                params.uavs[k].inertia_kgm2,
                RateGains().kp,
            ),
            ulog=config.sim.px4_ulog,
        )
        return Px4SitlVehicle(
            plant.uav(uav),
            Px4Process(px4_dir, instances[k], folder, parameters),
            mixer,
            HilSensors(seed=config.sim.seed * 2 + uav),
            host=host,
        )

    return vehicle


def _link_ports(world: SimulatedWorld) -> list[int] | None:
    """The UDP ports the supervisor must listen on when the vehicles fix them: a real PX4
    sends its offboard link to 14540 + its instance (ours answer whoever talks to them)."""
    ports = [v.client_port for v in world.vehicles if isinstance(v, Px4SitlVehicle)]
    return ports or None


def handle_world_request(world: SimulatedWorld, request: WorldRequest) -> Reply:
    """Carry out one request of the API process: a fault that is not valid is ``invalid``
    (422), one the world cannot have or a reset while armed ``refused`` (409)."""
    data: dict[str, Any] = {}
    try:
        if isinstance(request, StartFault):
            fault = parse_fault(request.fault.model_dump(), world.body_names, len(world.vehicles))
            data["fault"] = world.inject(fault).view(world.plant.time_s)
        elif isinstance(request, ClearFaults):
            data["cleared"] = [ended.view(world.plant.time_s) for ended in world.clear_faults()]
        elif isinstance(request, ResetWorld):
            data["cleared"] = [ended.view(world.plant.time_s) for ended in world.reset()]
            data["reset"] = True
            data["resting_positions"] = {
                name: world.plant.body(name).position_m.tolist() for name in world.plant_bodies
            }
        else:
            assert isinstance(request, ListFaults)
    except FaultError as error:
        return Reply(outcome=Outcome.INVALID, reason=str(error))
    except WorldRefusedError as error:
        return Reply(outcome=Outcome.REFUSED, reason=str(error))
    data["faults"] = world.fault_views()
    data["world_time_s"] = world.plant.time_s
    data["stalls"] = world.stalls.view(world.plant.time_s)
    return Reply(outcome=Outcome.OK, data=data)


async def _answer_connection(world: SimulatedWorld, channel: WorldChannel) -> None:
    """One connection of the world channel until its API process closes it (the world
    runs on, and a restarted API process connects again)."""
    try:
        await serve_world_requests(channel, lambda request: handle_world_request(world, request))
    except ChannelClosedError:
        log.info("world channel closed: no more fault requests on it")


async def run_world(
    config: Config,
    qtm_port: int,
    vehicle_local_ports: Sequence[int],
    on_ready: Callable[[dict[str, Any]], None],
    stop: asyncio.Event,
    listener: socket.socket | None = None,
    priority: int | None = None,
) -> None:
    """Start the world, report its addresses, run it until ``stop`` is set (answering every
    connection of the world channel to ``listener``, when given, meanwhile). With
    ``priority``, the process takes that real-time priority once the world has started:
    its start (the plant's compilation, PX4's boot) takes seconds of CPU that must not hold
    a core from another ``serve``'s punctual processes."""
    world = build_world(config, qtm_port, vehicle_local_ports, config.sim.host)
    addresses = await world.start()
    if priority is not None:
        log.info("world process: %s", raise_priority(priority))
    try:
        on_ready(
            {
                "qtm": f"{addresses.qtm_host}:{addresses.qtm_port}",
                "vehicles": list(addresses.vehicles),
                "link_ports": _link_ports(world),
                "px4_events": str(world.event_definitions),
            }
        )
        runner = asyncio.create_task(world.run(), name="world")
        server = ChannelServer()
        if listener is not None:  # after the runner: faults start on its clock
            await server.start(
                listener, WorldChannel, lambda channel: _answer_connection(world, channel)
            )
        await stop.wait()
        await server.close()
        runner.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await runner
    finally:
        await world.close()


def run_world_process(
    config: Config, ready: Connection, listener: socket.socket | None = None
) -> None:
    """Child-process entry of ``serve``: free ports, report them on ``ready``, answer the
    world channel's connections to ``listener``, run until SIGTERM or until the parent
    closes its end of ``ready``."""
    configure_logging()
    single_threaded_blas()
    title_process("world")

    async def main() -> None:
        async with stop_event(ready) as stop:
            try:
                free_ports = (0,) * config.system.n_vehicles
                await run_world(config, 0, free_ports, ready.send, stop, listener, WORLD_PRIORITY)
            except Exception as error:
                ready.send({"error": repr(error)})
                raise

    asyncio.run(main())


def run_sitl(config: Config) -> int:
    """``uavbar-supervisor sitl``: the world on the conventional ports, in the foreground."""

    def show(addresses: dict[str, Any]) -> None:
        bodies = ", ".join(config.mocap.bodies)
        log.info("QTM RT server   tcp %s (bodies: %s)", addresses["qtm"], bodies)
        link_ports = addresses.get("link_ports") or config.vehicles.ports
        for i, vehicle in enumerate(addresses["vehicles"]):
            port = link_ports[i] or 14540 + i
            log.info(
                "PX4 vehicle %d   udp %s -> 127.0.0.1:%d (system id %d)",
                i + 1,
                vehicle,
                port,
                config.vehicles.system_ids[i],
            )
        log.info("running in real time; Ctrl-C stops")

    async def main() -> None:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop.set)
        ports = tuple(API_LOCAL_PORT + k for k in range(config.system.n_vehicles))
        # As punctual as the embedded world: a supervisor (or an agent) beside it at
        # real-time priority would otherwise take the CPU from its frames.
        await run_world(config, config.mocap.port, ports, show, stop, priority=WORLD_PRIORITY)

    asyncio.run(main())
    return 0
