"""What a vehicle link takes (a command per tick) and gives (a plain view of the vehicle)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from geometry.arrays import FloatArray
from supervisor.errors import RemoteError


@dataclass(frozen=True)
class UavCommand:
    """What one UAV is told this tick: thrust [N], body torque [N m] (FLU), the body rates
    [rad/s] (FLU) a rate-controlled PX4 should follow, and whether motors may spin."""

    thrust_n: float
    torque_nm: FloatArray
    body_rates_radps: FloatArray
    motors_on: bool

    @staticmethod
    def off() -> UavCommand:
        return UavCommand(0.0, np.zeros(3), np.zeros(3), False)


@dataclass(frozen=True)
class VehicleView:
    """One vehicle as its link sees it."""

    connected: bool
    armed: bool
    px4_mode: str
    battery_v: float = math.nan
    status_text: str = ""
    refused: Mapping[str, int] = field(default_factory=dict)
    """What the link refused, by why (impostor address, unsigned, bad signature, replayed)."""


class VehicleCommandError(RemoteError):
    """A vehicle refused a command or did not acknowledge it."""
