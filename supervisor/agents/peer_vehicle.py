"""A peer's vehicle as an agent's flight process sees it: a ``VehicleLink`` made of what
the peer's agent says of its own vehicle each tick (``AgentTick.own``).

An agent never commands another's vehicle. Every agent gets the same operator request
and acts on its own vehicle; here an action only waits until the peer shows its vehicle
done (armed, in offboard, ...), so that the sequences of ``supervisor.vehicles.sequences``
read the same on every agent. A peer silent longer than ``timeout_s``, or whose liveliness
token is gone, is a lost link: its vehicle is then the one the set-down leaves behind."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable

import numpy as np

from geometry.arrays import FloatArray
from supervisor.agents.messages import AgentTick
from supervisor.vehicles.types import UavCommand, VehicleCommandError, VehicleView

POLL_S = 0.02


class PeerVehicle:
    """Vehicle ``vehicle`` as its agent reports it; ``action_timeout_s`` bounds the wait for
    the peer to show an action done."""

    def __init__(
        self,
        vehicle: int,
        timeout_s: float,
        action_timeout_s: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.vehicle = vehicle
        self.timeout_s = timeout_s
        self.action_timeout_s = action_timeout_s
        self._clock = clock
        self._last: tuple[AgentTick, float] | None = None  # one assignment: thread-safe
        self._gone = False
        self.latency_ms = math.nan

    # ---- fed by the agent's Zenoh subscribers (any thread) ---------------------------------
    def observe(self, tick: AgentTick) -> None:
        """The peer's latest tick, as it arrives."""
        self._last = (tick, self._clock())
        self._gone = False
        self.latency_ms = (time.time() - tick.sent_s) * 1e3

    def new_latency_ms(self) -> float:
        """The one-way latency of the peer's newest tick [ms] (by the wall clocks: only
        where they agree, as on one computer), once; nan when no tick came since."""
        latency, self.latency_ms = self.latency_ms, math.nan
        return latency

    def token_lost(self) -> None:
        """The peer's liveliness token is gone (its session, or every link to it, ended)."""
        self._gone = True

    def latest(self) -> AgentTick | None:
        """The peer's newest tick while it is alive (None: lost, or never heard)."""
        last = self._last
        if last is None or self._gone or self._clock() - last[1] > self.timeout_s:
            return None
        return last[0]

    def age_s(self) -> float:
        """Since the peer's last tick [s] (inf: never heard)."""
        last = self._last
        return math.inf if last is None else self._clock() - last[1]

    # ---- VehicleLink ----------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        tick = self.latest()
        return tick is not None and tick.own.connected

    def view(self) -> VehicleView:
        tick = self.latest()
        if tick is None:
            return VehicleView(False, False, "unknown", status_text="its agent is not heard")
        own = tick.own
        battery = math.nan if own.battery_v is None else own.battery_v
        return VehicleView(own.connected, own.armed, own.px4_mode, battery, own.status_text)

    async def _shown(self, done: Callable[[VehicleView], bool], what: str) -> None:
        deadline = self._clock() + self.action_timeout_s
        while not done(self.view()):
            if self._clock() > deadline:
                raise VehicleCommandError(f"its agent did not show it {what}")
            await asyncio.sleep(POLL_S)

    async def arm(self) -> None:
        await self._shown(lambda v: v.armed, "armed")

    async def disarm(self) -> None:
        await self._shown(lambda v: not v.armed, "disarmed")

    async def kill(self) -> None:
        await self._shown(lambda v: not v.armed, "disarmed")

    async def set_offboard(self) -> None:
        await self._shown(lambda v: v.px4_mode == "OFFBOARD", "in offboard")

    async def set_hold(self) -> None:
        await self._shown(lambda v: v.px4_mode != "OFFBOARD", "out of offboard")

    async def land(self) -> None:
        await self._shown(lambda v: v.px4_mode != "OFFBOARD", "landing")

    def send_setpoint(self, command: UavCommand) -> None:
        """Nothing: the peer's agent commands its own vehicle."""

    def send_mocap(self, position_m: FloatArray, quaternion: FloatArray, time_s: float) -> None:
        """Nothing: the peer's agent forwards its own vehicle's mocap."""

    async def read_parameter(self, name: str) -> float | int:
        raise VehicleCommandError(f"{name}: vehicle {self.vehicle}'s agent checks its own")

    async def set_parameter(self, name: str, value: float | int) -> None:
        raise VehicleCommandError(f"{name}: vehicle {self.vehicle}'s agent sets its own")


class PeerPlans:
    """The peers' planned inputs as an agent's MPC predicts their vehicles with them
    (``controllers.mpc.PeerInputs``): each peer's last plan, shifted by the ticks since it
    came; None when plans are not shared or the peer is not heard."""

    def __init__(self, peers: dict[int, PeerVehicle], shared: bool) -> None:
        self._peers = peers
        self._shared = shared

    def __call__(self, i: int, now_s: float) -> FloatArray | None:
        peer = self._peers.get(i)
        tick = peer.latest() if peer is not None else None
        if peer is None or tick is None or not self._shared or not tick.plan_u:
            return None
        shift = max(0, round(peer.age_s() / tick.plan_dt_s))
        rows = np.asarray(tick.plan_u, dtype=float)
        return rows[shift:] if shift < len(rows) else None
