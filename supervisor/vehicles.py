"""What the flight process needs from a vehicle link, and the sequences it runs over both
vehicles (arming the PX4 way, landing, killing).

PX4 enters offboard only after setpoints have streamed for more than a second at more than
2 Hz (protocols.md §2.3), so arming starts the idle stream first, waits out that proof of
life, then selects offboard and arms each vehicle, checking every acknowledgement. A
vehicle that refuses leaves both disarmed.
"""

from __future__ import annotations

import asyncio
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from supervisor.flight_core import UavCommand
from supervisor.telemetry import VehicleView

FloatArray = NDArray[np.float64]
PROOF_OF_LIFE_S = 1.2


class VehicleCommandError(Exception):
    """A vehicle refused a command or did not acknowledge it."""


class VehicleLink(Protocol):
    """One PX4 as the flight process drives it."""

    @property
    def connected(self) -> bool:
        """Heartbeats arrive."""
        ...

    def view(self) -> VehicleView:
        """Connection, arming, PX4 mode, battery and last status text."""
        ...

    async def arm(self) -> None:
        """Arm; raises ``VehicleCommandError`` with the vehicle's reason."""
        ...

    async def disarm(self) -> None:
        """Disarm (on the ground)."""
        ...

    async def kill(self) -> None:
        """Force-disarm, in the air too."""
        ...

    async def set_offboard(self) -> None:
        """Select offboard mode (the setpoint stream must already be running)."""
        ...

    async def set_hold(self) -> None:
        """Leave offboard for a mode that needs no stream."""
        ...

    def send_setpoint(self, command: UavCommand) -> None:
        """Send this tick's setpoint (never blocks)."""
        ...

    def send_mocap(self, position_m: FloatArray, quaternion: FloatArray, time_s: float) -> None:
        """Forward the vehicle's own mocap pose (arena frame, FLU→arena quaternion)."""
        ...


async def _each(links: tuple[VehicleLink, ...], action: str) -> list[str]:
    """Run ``action`` on every link at once; the failures, as 'vehicle i: reason'."""
    results = await asyncio.gather(
        *(getattr(link, action)() for link in links), return_exceptions=True
    )
    return [
        f"vehicle {i}: {result}"
        for i, result in enumerate(results, start=1)
        if isinstance(result, BaseException)
    ]


async def arm_for_offboard(links: tuple[VehicleLink, ...], proof_of_life_s: float) -> list[str]:
    """Offboard then arm on every vehicle; the caller already streams idle setpoints. On any
    failure both are disarmed again; returns the failures (empty: all armed)."""
    disconnected = [
        f"vehicle {i}: no link" for i, link in enumerate(links, 1) if not link.connected
    ]
    if disconnected:
        return disconnected
    await asyncio.sleep(proof_of_life_s)
    failures = await _each(links, "set_offboard")
    if not failures:
        failures = await _each(links, "arm")
    if failures:
        await _each(links, "disarm")
    return failures


async def _disarm_landed(link: VehicleLink) -> None:
    """Disarm a vehicle the motion capture shows on the ground. PX4 refuses a normal disarm
    while its own land detector still says airborne (it lags a second or two after
    touch-down); on the ground a forced disarm is safe, and waiting would leave it armed
    with motors idling next to people."""
    try:
        await link.disarm()
    except VehicleCommandError:
        await link.kill()


async def disarm_all(links: tuple[VehicleLink, ...]) -> list[str]:
    """Disarm every landed vehicle (forced if PX4 refuses) and leave offboard; returns the
    failures."""
    results = await asyncio.gather(
        *(_disarm_landed(link) for link in links), return_exceptions=True
    )
    failures = [
        f"vehicle {i}: {result}"
        for i, result in enumerate(results, start=1)
        if isinstance(result, BaseException)
    ]
    return failures + await _each(links, "set_hold")


async def kill_all(links: tuple[VehicleLink, ...]) -> list[str]:
    """Force-disarm every vehicle at once; returns the failures."""
    return await _each(links, "kill")
