"""The state layout of N UAVs carrying one rigid payload, named once.

x = (p_b, v_b, Θ_b, ω_b, then for each UAV i = 1..N: p_i, v_i, Θ_i, ω_i) ∈ R^(12 + 12N),
u = (F_1, τ_1, …, F_N, τ_N) ∈ R^(4N). Units and frames as in ``geometry.state``: the
payload's ω_b is inertial, each UAV's ω_i is in its body frame. The payload's block
(``P_B``, ``V_B``, ``TH_B``, ``W_B``) is ``geometry.state``'s; for N = 2 this is the
paper's UAV–bar 36-state and 8-input layout.

Accessors work on numpy arrays and on CasADi symbols alike where they only slice.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from geometry.arrays import FloatArray
from geometry.state import PAYLOAD_YAW, W_B

MIN_VEHICLES = 2
MAX_VEHICLES = 8

_BLOCK_SIZE = W_B.stop  # (p, v, Θ, ω): the payload's block is every rigid body's template
_UAV_INPUTS = 4  # (F_i, τ_i)


@dataclass(frozen=True)
class FormationLayout:
    """Indices into the state and input vectors of ``n_vehicles`` UAVs (2 to 8).

    UAVs are numbered 1..N, as in the paper.
    """

    n_vehicles: int

    def __post_init__(self) -> None:
        if not MIN_VEHICLES <= self.n_vehicles <= MAX_VEHICLES:
            raise ValueError(
                f"a formation has {MIN_VEHICLES} to {MAX_VEHICLES} UAVs, not {self.n_vehicles}"
            )

    @property
    def n_states(self) -> int:
        """12 + 12N."""
        return _BLOCK_SIZE * (1 + self.n_vehicles)

    @property
    def n_inputs(self) -> int:
        """4N."""
        return _UAV_INPUTS * self.n_vehicles

    @property
    def vehicles(self) -> range:
        """The UAV numbers 1..N."""
        return range(1, self.n_vehicles + 1)

    def _check_vehicle(self, i: int) -> None:
        if i not in self.vehicles:
            raise IndexError(f"UAV {i} is not in a formation of {self.n_vehicles}")

    def _uav_offset(self, i: int) -> int:
        self._check_vehicle(i)
        return _BLOCK_SIZE * i

    def uav_block(self, i: int) -> slice:
        """UAV ``i``'s whole (p_i, v_i, Θ_i, ω_i) block."""
        start = self._uav_offset(i)
        return slice(start, start + _BLOCK_SIZE)

    def uav_slices(self, i: int) -> tuple[slice, slice, slice, slice]:
        """(p_i, v_i, Θ_i, ω_i) slices of UAV ``i``."""
        o = self._uav_offset(i)
        return slice(o, o + 3), slice(o + 3, o + 6), slice(o + 6, o + 9), slice(o + 9, o + 12)

    def uav_yaw_index(self, i: int) -> int:
        """Index of ψ_i."""
        return self._uav_offset(i) + PAYLOAD_YAW

    @property
    def yaw_indices(self) -> tuple[int, ...]:
        """(ψ_b, ψ_1, …, ψ_N)."""
        return (PAYLOAD_YAW, *(self.uav_yaw_index(i) for i in self.vehicles))

    def thrust_index(self, i: int) -> int:
        """Index of F_i in u."""
        self._check_vehicle(i)
        return _UAV_INPUTS * (i - 1)

    def torque_slice(self, i: int) -> slice:
        """τ_i's slice in u."""
        start = self.thrust_index(i) + 1
        return slice(start, start + 3)

    def uav_input_slice(self, i: int) -> slice:
        """(F_i, τ_i) in u."""
        start = self.thrust_index(i)
        return slice(start, start + _UAV_INPUTS)

    # ---- readings of a state ------------------------------------------------------------
    def uav_position(self, x: Any, i: int) -> Any:
        """p_i [m] (a view)."""
        return x[self.uav_slices(i)[0]]

    def uav_velocity(self, x: Any, i: int) -> Any:
        """v_i [m/s] (a view)."""
        return x[self.uav_slices(i)[1]]

    def uav_euler(self, x: Any, i: int) -> Any:
        """Θ_i = (φ_i, θ_i, ψ_i) [rad] (a view)."""
        return x[self.uav_slices(i)[2]]

    def uav_yaws(self, x: FloatArray) -> tuple[float, ...]:
        """(ψ_1, …, ψ_N) [rad]."""
        return tuple(float(x[self.uav_yaw_index(i)]) for i in self.vehicles)

    @property
    def uav_rate_indices(self) -> list[int]:
        """The indices of every UAV's body rates ω_i, UAV 1's first."""
        return [k for i in self.vehicles for k in range(self.n_states)[self.uav_slices(i)[3]]]
