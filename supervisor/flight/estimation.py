"""Estimation: fused rigid-body states → the formation's state vector (12 + 12N; the
paper's 36-state for the bar and two UAVs).

Rigid bodies (QTM names, configurable): the payload (origin at its CoM; the bar's body x
axis from cable 1's end to cable 2's end), ``uav1`` … ``uavN`` (origin at the CoM, FLU). The
bar's roll about its own axis has no dynamics in the model (5) (n_b·ω_b = 0): it is set to
0, and the bar's angular velocity keeps only its part perpendicular to the bar. Any other
rigid payload keeps its whole attitude and angular velocity.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.frames import rotation_from_euler_zyx
from geometry.state import P_B, TH_B, V_B, W_B
from mocap.fusion import BodyState


@dataclass(frozen=True)
class BodyNames:
    """QTM rigid-body names of the payload and the UAVs (UAV 1's first); ``is_bar``: the
    payload is a bar, whose roll about its axis the model leaves out."""

    payload: str = "bar"
    uavs: tuple[str, ...] = ("uav1", "uav2")
    is_bar: bool = True

    def all(self) -> tuple[str, ...]:
        return (self.payload, *self.uavs)


@dataclass(frozen=True)
class Refusals:
    """A body whose newest poses the fusion refused: how many in a row, and why the last."""

    body: str
    in_a_row: int
    why: str


@dataclass(frozen=True)
class Estimate:
    """The state at a tick: ``x`` (12 + 12N,) in the paper's order, the oldest body's age [s],
    which bodies are not healthy (empty when all are), and the bodies whose newest poses
    were refused (``mocap.fusion``'s gate or repeats; empty when none)."""

    x: FloatArray
    age_s: float
    unhealthy: tuple[str, ...]
    refused: tuple[Refusals, ...] = ()

    @property
    def healthy(self) -> bool:
        return not self.unhealthy


def _missing(name: str) -> BodyState:
    nan3 = np.full(3, np.nan)
    return BodyState(
        name, np.nan, nan3, nan3, np.full(4, np.nan), nan3, nan3, nan3, np.inf, False, False, np.nan
    )


def estimate_state(bodies: Mapping[str, BodyState], names: BodyNames = BodyNames()) -> Estimate:
    """Assemble x ∈ R^(12 + 12N) from the fused bodies (NaN where a body was never
    measured)."""
    layout = FormationLayout(len(names.uavs))
    payload = bodies.get(names.payload) or _missing(names.payload)
    x = np.empty(layout.n_states)
    x[P_B] = payload.position_m
    x[V_B] = payload.velocity_mps
    omega = payload.angular_velocity_world_radps
    if names.is_bar:
        x[TH_B] = (0.0, payload.euler_zyx_rad[1], payload.euler_zyx_rad[2])
        n_b = rotation_from_euler_zyx(*x[TH_B])[:, 0]
        x[W_B] = omega - (omega @ n_b) * n_b
    else:
        x[TH_B] = payload.euler_zyx_rad
        x[W_B] = omega
    for i, name in zip(layout.vehicles, names.uavs, strict=True):
        uav = bodies.get(name) or _missing(name)
        position, velocity, euler, rates = layout.uav_slices(i)
        x[position] = uav.position_m
        x[velocity] = uav.velocity_mps
        x[euler] = uav.euler_zyx_rad
        x[rates] = uav.body_rates_radps
    states = [bodies.get(n) for n in names.all()]
    unhealthy = tuple(
        n for n, s in zip(names.all(), states, strict=True) if s is None or not s.healthy
    )
    age = max((s.age_s if s is not None else np.inf) for s in states)
    refused = tuple(
        Refusals(s.name, s.refused_in_a_row, s.refusal)
        for s in states
        if s is not None and s.refused_in_a_row > 0
    )
    return Estimate(x, float(age), unhealthy, refused)
