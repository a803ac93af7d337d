"""The simulated world in real time: the plant, two simulated PX4s and a simulated QTM
server, on loopback, as ``uavbar-supervisor sitl`` runs it and ``serve`` starts it.

The plant follows the wall clock: every ``step_period_s`` it is advanced to "now" (whole
RK4 steps), capturing mocap frames on the measurement model's schedule; each frame is
published by the QTM server when the model delivers it (after its latency, with its noise
and dropouts); the PX4 models run their control and failsafe logic on the same clock and
command the plant through its airframe ports.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

from geometry.frames import euler_zyx_from_quaternion
from mocap.qtm_protocol import BodyPose
from sim.measurement import MocapFrame, MocapModel, MocapParams
from sim.plant import Plant, body_slice, resting_state
from sim.plant_params import PlantParams
from sim.qtm_server import QtmServer
from sim.truth import TruthStats

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


VehicleFactory = Callable[[Plant, int], SimulatedVehicle]


@dataclass(frozen=True)
class WorldAddresses:
    """Where clients find the world."""

    qtm_host: str
    qtm_port: int
    vehicles: tuple[str, ...]


def _poses(frame: MocapFrame) -> dict[str, BodyPose]:
    return {
        name: BodyPose.untracked(name)
        if pose is None
        else BodyPose(
            name, True, pose.position_m, pose.quaternion, euler_zyx_from_quaternion(pose.quaternion)
        )
        for name, pose in frame.poses.items()
    }


class SimulatedWorld:
    """Plant + mocap model + QTM server + vehicles, advanced on the wall clock."""

    def __init__(
        self,
        plant_params: PlantParams,
        mocap_params: MocapParams,
        vehicles: VehicleFactory,
        *,
        body_names: Sequence[str] = ("bar", "uav1", "uav2"),
        qtm_host: str = "127.0.0.1",
        qtm_port: int = 22223,
        step_period_s: float = 0.002,
        clock: Callable[[], float] = time.monotonic,
        event_definitions: Path | None = None,
    ) -> None:
        self.plant = Plant(plant_params)
        self.mocap = MocapModel(mocap_params)
        self.vehicles = [vehicles(self.plant, i) for i in (1, 2)]
        self.qtm = QtmServer(list(body_names), host=qtm_host, port=qtm_port, rate_hz=None)
        self.step_period_s = step_period_s
        self.event_definitions = event_definitions
        """The definitions of the events its vehicles send (PX4's libevents format)."""
        self._sleeper = ThreadPoolExecutor(max_workers=1, thread_name_prefix="world-sleep")
        self._clock = clock
        self._t0 = 0.0
        bar_rest_z_m = float(resting_state(plant_params)[body_slice("bar")][2])
        self.truth = TruthStats(bar_rest_z_m)
        """Cable tension and slack while the bar hangs, the worst tilt (logged every
        ``TRUTH_REPORT_PERIOD_S`` and at close)."""
        self._truth_reported_s = 0.0

    @property
    def now_s(self) -> float:
        """World time [s] (zero when ``run`` started)."""
        return self._clock() - self._t0

    async def start(self) -> WorldAddresses:
        """Bind every endpoint; the world does not move until ``run``."""
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

    def advance(self, until_s: float) -> None:
        """Step the plant to ``until_s`` (world time), capturing and publishing frames and
        running the vehicles' logic between plant chunks."""
        plant = self.plant
        step = plant.step_s
        while plant.time_s < until_s - 0.5 * step:
            stop = min(until_s, max(self.mocap.next_capture_time_s, plant.time_s + step))
            plant.advance(stop - plant.time_s)
            self.mocap.capture(plant.truth())
            self.truth.update(plant, airborne=True)
            for vehicle in self.vehicles:
                vehicle.step(plant.time_s)
        if plant.time_s - self._truth_reported_s >= TRUTH_REPORT_PERIOD_S:
            self._truth_reported_s = plant.time_s
            log.info("%s", self.truth.describe())
        for frame in self.mocap.poll(until_s):
            self.qtm.publish(_poses(frame))

    async def run(self) -> None:
        """Follow the wall clock until cancelled. A stall longer than ``MAX_CATCH_UP_S`` is
        not made up: the world slows down rather than lurching."""
        self._t0 = self._clock() - self.plant.time_s
        while True:
            target = self.now_s
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
