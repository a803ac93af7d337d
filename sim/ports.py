"""What a simulated PX4 sees of its airframe inside the plant.

The plant (``sim/plant.py``) hands one ``AirframePort`` per UAV to the simulated PX4
endpoints (``sim/px4.py``). Arena frame ENU (z up), body frame FLU; SI units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from geometry.arrays import FloatArray


@dataclass(frozen=True)
class AirframeState:
    """Ground truth of one UAV: position/velocity in the arena frame, attitude as a
    (w, x, y, z) quaternion FLU body → ENU arena, body rates in FLU."""

    time_s: float
    position_m: FloatArray
    velocity_mps: FloatArray
    quaternion: FloatArray
    body_rates_radps: FloatArray
    on_ground: bool


class AirframePort(Protocol):
    """One UAV of the plant as its flight controller sees it."""

    def state(self) -> AirframeState:
        """The current ground-truth state."""
        ...

    def command(self, thrust_n: float, torque_nm: FloatArray) -> None:
        """Demand a collective thrust [N] and body torque (FLU) [N m], held until the next
        call. The plant applies its own motor lag and saturation; zero thrust and torque
        means motors stopped (disarmed)."""
        ...
