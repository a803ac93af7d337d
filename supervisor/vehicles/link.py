"""What the flight process needs from one vehicle link (MAVLink to a PX4, or a test's fake)."""

from __future__ import annotations

from typing import Protocol

from geometry.arrays import FloatArray
from supervisor.vehicles.types import UavCommand, VehicleView


class VehicleLink(Protocol):
    """One PX4 as the flight process drives it."""

    @property
    def connected(self) -> bool:
        """The vehicle is heard (any of its autopilot's messages, not heartbeats alone)."""
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

    async def land(self) -> None:
        """Leave offboard for the vehicle's own landing (AUTO.LAND)."""
        ...

    def send_setpoint(self, command: UavCommand) -> None:
        """Send this tick's setpoint (never blocks)."""
        ...

    async def read_parameter(self, name: str) -> float | int:
        """The vehicle's value of parameter ``name`` (int for integer parameters); raises
        ``VehicleCommandError`` when the vehicle does not answer."""
        ...

    async def set_parameter(self, name: str, value: float | int) -> None:
        """Set parameter ``name`` and verify the vehicle's echo; raises
        ``VehicleCommandError`` on a different echo or silence."""
        ...

    def send_mocap(self, position_m: FloatArray, quaternion: FloatArray, time_s: float) -> None:
        """Forward the vehicle's own mocap pose (arena frame, FLU→arena quaternion), captured
        at ``time_s`` on the link's clock [s]; a frame not newer than the last is skipped."""
        ...
