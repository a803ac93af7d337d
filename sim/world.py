"""The simulated world in real time: the plant, one simulated PX4 per UAV (N of them) and
a simulated QTM server, on loopback, as ``uavbar-supervisor sitl`` runs it and ``serve`` starts it.

The plant follows the wall clock: every ``step_period_s`` it is advanced to "now" (whole
RK4 steps), capturing mocap frames on the measurement model's schedule; each frame is
published by the QTM server when the model delivers it (after its latency, with its noise
and dropouts); the PX4 models run their control and failsafe logic on the same clock and
command the plant through its airframe ports.

Faults (``sim.faults``, docs/faults.md) are injected at run time by ``inject`` and ended by
their time on the world's clock — the plant's time, which the vehicles step on too (checked
at every ``advance``) — or by ``clear_faults``; each start and end is logged. ``reset``
puts the world back in its resting pose. Both are for simulated PX4s
(``InjectableVehicle``); what a real PX4 SITL process cannot do is refused
(``WorldRefusedError``) with the reason.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import gc
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from geometry.frames import euler_zyx_from_quaternion
from mocap.qtm_protocol import BodyPose
from sim.faults import ActiveFault, Fault, FaultSet, LinkLost, Px4Reboot, UdpLoss
from sim.measurement import MocapFrame, MocapModel, MocapParams
from sim.plant import Plant
from sim.plant_params import PlantParams
from sim.qtm_server import QtmServer
from sim.stalls import StallLog
from sim.truth import FlightTruths, TruthStats

log = logging.getLogger(__name__)

MAX_CATCH_UP_S = 0.1
TRUTH_REPORT_PERIOD_S = 10.0


class SimulatedVehicle(Protocol):
    """A simulated flight controller on the world's clock."""

    async def start(self) -> None: ...

    async def close(self) -> None: ...

    def step(self, now_s: float) -> None:
        """Run its logic up to ``now_s`` (world seconds) and command its airframe."""
        ...

    def describe(self) -> str:
        """Its addresses, for the operator."""
        ...


@runtime_checkable
class InjectableVehicle(SimulatedVehicle, Protocol):
    """A simulated vehicle whose link and power the world's faults reach (our simulated
    PX4, ``sim.px4_endpoint.Px4Endpoint``; a real PX4 SITL process is not one)."""

    datagram_filter: Callable[[bool], bool] | None
    powered: bool

    @property
    def armed(self) -> bool: ...

    def power_off(self) -> None: ...

    def boot(self, world_s: float) -> None: ...

    def reset_model(self) -> None: ...


VehicleFactory = Callable[[Plant, int], SimulatedVehicle]


class WorldRefusedError(Exception):
    """A valid request the world cannot carry out (now, or with these vehicles)."""


NOT_THROUGH_THE_WORLD = (
    "vehicle {vehicle} is a real PX4 SITL process: its MAVLink goes straight between the "
    "supervisor and PX4 (UDP 14580+n <-> 14540+n), not through the simulated world, so the "
    'world cannot {what}; use sim.vehicles = "simulated" for this fault'
)


@dataclass(frozen=True)
class WorldAddresses:
    """Where clients find the world."""

    qtm_host: str
    qtm_port: int
    vehicles: tuple[str, ...]


def qtm_poses(frame: MocapFrame, names: Mapping[str, str]) -> dict[str, BodyPose]:
    """The frame's poses under the names QTM streams (``names``: plant body → QTM name)."""
    poses = {}
    for body, pose in frame.poses.items():
        name = names[body]
        poses[name] = (
            BodyPose.untracked(name)
            if pose is None
            else BodyPose(
                name,
                True,
                pose.position_m,
                pose.quaternion,
                euler_zyx_from_quaternion(pose.quaternion),
            )
        )
    return poses


class SimulatedWorld:
    """Plant + mocap model + QTM server + one vehicle per UAV (``vehicles(plant, uav)`` for
    UAV 1 … N of the plant), advanced on the wall clock. ``body_names``: the names QTM
    streams the payload and UAV 1 … N under, in that order (``mocap.bodies``); None: the
    plant's own names."""

    def __init__(
        self,
        plant_params: PlantParams,
        mocap_params: MocapParams,
        vehicles: VehicleFactory,
        *,
        body_names: Sequence[str] | None = None,
        qtm_host: str = "127.0.0.1",
        qtm_port: int = 22223,
        step_period_s: float = 0.002,
        clock: Callable[[], float] = time.monotonic,
        event_definitions: Path | None = None,
        fault_seed: int = 0,
    ) -> None:
        self.plant = Plant(plant_params)
        layout = self.plant.layout
        self.plant_bodies = (layout.payload_name, *layout.uav_names)
        """The plant's bodies in the order of ``body_names``: the payload, then UAV 1 … N."""
        names = self.plant_bodies if body_names is None else tuple(body_names)
        if len(names) != len(self.plant_bodies):
            raise ValueError(
                f"body_names: the payload's and one per UAV ({len(self.plant_bodies)} names), "
                f"got {list(names)}"
            )
        self.mocap = MocapModel(mocap_params)
        self.vehicles = [vehicles(self.plant, uav) for uav in range(1, layout.n_uavs + 1)]
        self.qtm = QtmServer(list(names), host=qtm_host, port=qtm_port, rate_hz=None, clock=clock)
        self._qtm_names = dict(zip(self.plant_bodies, names, strict=True))
        self._plant_names = dict(zip(names, self.plant_bodies, strict=True))
        self.faults = FaultSet(names, layout.n_uavs, fault_seed)
        """The faults in effect (``inject``, ``clear_faults``)."""
        self.qtm.packet_filter = self.faults.keep_mocap_packet
        for uav, vehicle in enumerate(self.vehicles, start=1):
            if isinstance(vehicle, InjectableVehicle):
                vehicle.datagram_filter = functools.partial(self.faults.keep_mavlink, uav)
        self._resting_state = self.plant.get_state()
        self.step_period_s = step_period_s
        self.event_definitions = event_definitions
        """The definitions of the events its vehicles send (PX4's libevents format)."""
        self._sleeper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="world-sleep")
        self._clock = clock
        self._t0 = 0.0
        self._following_the_clock = False  # run() makes world time the clock's, less _t0
        payload_rest_z_m = float(self._resting_state[layout.body_slice(layout.payload_name)][2])
        self.truth = TruthStats(payload_rest_z_m, bodies=self.plant_bodies)
        """Cable tension and slack while the payload hangs, the worst tilt (logged every
        ``TRUTH_REPORT_PERIOD_S`` and at close)."""
        self.flight_truths = FlightTruths(payload_rest_z_m, bodies=self.plant_bodies)
        """The same for each flight on its own (logged as each flight ends)."""
        self._truth_reported_s = 0.0
        self.stalls = StallLog()
        """Moments the world's own process did not run (``sim.stalls``)."""

    @property
    def now_s(self) -> float:
        """World time [s] (zero when ``run`` started)."""
        return self._clock() - self._t0

    async def start(self) -> WorldAddresses:
        """Bind every endpoint; the world does not move until ``run``."""
        # The plant's kernels compile on first use (seconds on a fresh machine, then cached):
        # here, on a throwaway plant, rather than inside the first frame of ``run``.
        Plant(self.plant.params).advance(self.plant.step_s)
        await self.qtm.start()
        for vehicle in self.vehicles:
            await vehicle.start()
        return WorldAddresses(
            self.qtm.host, self.qtm.port, tuple(v.describe() for v in self.vehicles)
        )

    async def close(self) -> None:
        log.info("%s", self.truth.describe())
        for vehicle in self.vehicles:
            with contextlib.suppress(Exception):
                await vehicle.close()
        await self.qtm.close()
        self._sleeper.shutdown(wait=False)

    @property
    def body_names(self) -> tuple[str, ...]:
        """The rigid bodies the QTM server streams."""
        return self.qtm.body_names

    def advance(self, until_s: float) -> None:
        """Step the plant to ``until_s`` (world time), capturing and publishing frames and
        running the vehicles' logic between plant chunks; faults whose time is up end."""
        ended = self.faults.expire(until_s)
        if ended:
            self._ended(ended, "expired", until_s)
        plant = self.plant
        step = plant.step_s
        while plant.time_s < until_s - 0.5 * step:
            stop = min(until_s, max(self.mocap.next_capture_time_s, plant.time_s + step))
            plant.advance(stop - plant.time_s)
            if self.mocap.due(plant.time_s):
                self.mocap.capture(plant.truth())
            self.truth.update(plant, airborne=True)
            if (flight_ended := self.flight_truths.update(plant)) is not None:
                log.info("%s", flight_ended)
            for vehicle in self.vehicles:
                vehicle.step(plant.time_s)
        if plant.time_s - self._truth_reported_s >= TRUTH_REPORT_PERIOD_S:
            self._truth_reported_s = plant.time_s
            log.debug("%s", self.truth.describe())  # said at INFO when the world closes
        # Following the clock, each frame is stamped when it reached the network (world time
        # + the world's offset to the clock): after a stall the world catches up in a burst,
        # and frames stamped as they leave would be 4 ms apart in motion but microseconds
        # apart in time (the supervisor's filter then saw metres per second that were not).
        for frame in self.mocap.poll(until_s):
            poses = self.faults.frame(qtm_poses(frame, self._qtm_names))
            at_s = self._t0 + frame.delivery_time_s if self._following_the_clock else None
            self.qtm.publish(poses, at_s=at_s)

    # ---- faults and reset ---------------------------------------------------------------------
    def _refusal(self, fault: Fault) -> str | None:
        """Why ``fault`` cannot be injected into these vehicles, or None."""
        if isinstance(fault, LinkLost | Px4Reboot):
            what = "cut its link" if isinstance(fault, LinkLost) else "reboot it faithfully"
            vehicle = self.vehicles[fault.vehicle - 1]
            if not isinstance(vehicle, InjectableVehicle):
                return NOT_THROUGH_THE_WORLD.format(vehicle=fault.vehicle, what=what)
        if isinstance(fault, UdpLoss):
            for uav, vehicle in enumerate(self.vehicles, start=1):
                if not isinstance(vehicle, InjectableVehicle):
                    return NOT_THROUGH_THE_WORLD.format(vehicle=uav, what="drop its datagrams")
        return None

    def inject(self, fault: Fault) -> ActiveFault:
        """Put ``fault`` in effect now (replacing one of its kind on the same target).
        ``FaultError`` for a body QTM does not stream or a vehicle the world does not have;
        ``WorldRefusedError`` when these vehicles cannot have it."""
        self.faults.check(fault)
        refusal = self._refusal(fault)
        if refusal is not None:
            raise WorldRefusedError(refusal)
        now_s = self.plant.time_s
        started, replaced = self.faults.start(fault, now_s)
        if replaced is not None:
            self._ended([replaced], "replaced", now_s)
        log.info("fault started at %.3f s: %s", now_s, started.describe())
        self._power_vehicles()
        self._load_plant()
        return started

    def clear_faults(self) -> list[ActiveFault]:
        """End every fault now; returns those that were in effect."""
        now_s = self.plant.time_s
        ended = self.faults.clear()
        self._ended(ended, "cleared", now_s)
        return ended

    def fault_views(self) -> list[dict[str, Any]]:
        """The faults in effect, as the API shows them."""
        return self.faults.views(self.plant.time_s)

    def _ended(self, ended: list[ActiveFault], why: str, now_s: float) -> None:
        for fault in ended:
            log.info("fault ended at %.3f s (%s): %s", now_s, why, fault.describe())
        self._power_vehicles()
        self._load_plant()

    def _load_plant(self) -> None:
        """The plant's external loads: the pushes in effect (each ends on its own time,
        within the plant's steps, even between two world steps)."""
        self.plant.clear_loads()
        for load in self.faults.loads(self._plant_names):
            self.plant.add_load(load)

    def _power_vehicles(self) -> None:
        """Power each simulated PX4 off or on as the reboot faults say."""
        for uav, vehicle in enumerate(self.vehicles, start=1):
            if not isinstance(vehicle, InjectableVehicle):
                continue
            powered = self.faults.powered(uav)
            if vehicle.powered and not powered:
                vehicle.power_off()
                log.info("PX4 %d: power off (rebooting)", uav)
            elif powered and not vehicle.powered:
                # On the clock the vehicles step on: the plant's, never ahead of it.
                vehicle.boot(self.plant.time_s)
                log.info("PX4 %d: booted", uav)

    def reset(self) -> list[ActiveFault]:
        """Back to the resting pose the world started in: the plant's initial state,
        motors stopped, every simulated PX4 disarmed in its boot mode (parameters kept),
        faults cleared (returned). ``WorldRefusedError`` while a vehicle is armed, and for
        real PX4 SITL vehicles (their state is the firmware's, not the world's to set)."""
        vehicles: list[InjectableVehicle] = []
        for uav, vehicle in enumerate(self.vehicles, start=1):
            if not isinstance(vehicle, InjectableVehicle):
                raise WorldRefusedError(
                    f"vehicle {uav} is a real PX4 SITL process: the world cannot put its "
                    "firmware back in its boot state (only restarting serve does)"
                )
            vehicles.append(vehicle)
        armed = [uav for uav, vehicle in enumerate(vehicles, start=1) if vehicle.armed]
        if armed:
            names = " and ".join(str(uav) for uav in armed)
            raise WorldRefusedError(
                f"vehicle {names} {'is' if len(armed) == 1 else 'are'} armed: land and "
                "disarm first (the reset moves the vehicles)"
            )
        cleared = self.clear_faults()
        self.plant.set_state(self._resting_state)
        for uav in range(1, len(self.vehicles) + 1):
            self.plant.command(uav, 0.0, np.zeros(3))
        for vehicle in vehicles:
            vehicle.reset_model()
        log.info("world reset at %.3f s: resting pose, PX4s in their boot mode", self.plant.time_s)
        return cleared

    async def run(self) -> None:
        """Follow the wall clock until cancelled. A stall longer than ``MAX_CATCH_UP_S`` is
        not made up: the world slows down rather than lurching."""
        self._t0 = self._clock() - self.plant.time_s
        self._following_the_clock = True
        gc.freeze()  # what exists now is never scanned again: shorter collections in a frame
        while True:
            target = self.now_s
            behind_s = target - self.plant.time_s - self.step_period_s
            if self.stalls.observe(behind_s, self.plant.time_s):
                log.warning(
                    "the world stalled %.0f ms at %.3f s (this computer was busy): its mocap "
                    "and vehicles paused with it; a gap the supervisor saw now is not the lab's",
                    behind_s * 1e3,
                    self.plant.time_s,
                )
            if target - self.plant.time_s > MAX_CATCH_UP_S:
                self._t0 += target - self.plant.time_s - MAX_CATCH_UP_S
                target = self.now_s
            self.advance(target)
            next_frame_in = self.mocap.next_delivery_time_s - self.now_s
            await self._sleep(max(0.0, min(self.step_period_s, next_frame_in)))

    async def _sleep(self, duration_s: float) -> None:
        """Sleep on a helper thread: asyncio's timers wake up to a millisecond late, and a
        real QTM's frames leave on time, so ours must too."""
        await asyncio.get_running_loop().run_in_executor(self._sleeper, time.sleep, duration_s)
