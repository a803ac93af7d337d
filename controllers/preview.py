"""The reference over the horizon: per-stage targets for the QP from the references at the
stages ahead (a path's or a shaped move's preview).

The QP is posed in Δx = x − x_eq(t) around the tick's reference equilibrium, whose model
drops the affine term: Δx = 0 is the formation carried on at the reference's own motion —
each body's position moved by its velocity and by the reference's acceleration a, its
velocity by a, each yaw by its rate:

    x_eq(t) = x_eq + (v t + a t²/2 on positions, a t on velocities, ψ̇ t on yaws).

A stage ahead whose reference differs from that (the move slows down, turns, stops)
becomes the target x̄_k = x_eq,k − x_eq(k h), ū_k = u_eq,k − u_eq: the QP then tracks the
references ahead instead of the one of this tick carried on.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from controllers.formation_equilibria import FormationReference
from geometry.arrays import FloatArray

Preview = Mapping[int, FormationReference]
"""The reference at some of the stages k = 1 … N ahead (``sampled_stages``), N among them."""

# The equilibrium of every fifth stage: their departure from the reference carried on is
# smooth over a few stages (100 ms), and a tick need not compute thirty equilibria. Every
# stage's (stride 1) and every fifth's flew the paper's sequence and the benchmarks' paths
# alike (docs/results.md).
STAGE_STRIDE = 5


@dataclass(frozen=True)
class Kinematics:
    """Where a state vector keeps its bodies' motion: (position, velocity) slice pairs,
    and the yaw indices with the index of each one's rate in the reference's rates
    (0: the payload's, i: UAV i's)."""

    moving: tuple[tuple[slice, slice], ...]
    yaws: tuple[tuple[int, int], ...]


def carried_on(
    x_eq: FloatArray, reference: FormationReference, kinematics: Kinematics, times_s: FloatArray
) -> FloatArray:
    """x_eq(t) at each of ``times_s`` (T,), shape (T, nx): ``x_eq`` carried on at its
    reference's motion (the module's docstring)."""
    t = times_s[:, None]
    x = np.tile(x_eq, (len(times_s), 1))
    a = np.asarray(reference.acceleration_mps2, dtype=float)
    for position, velocity in kinematics.moving:
        x[:, position] += t * x_eq[velocity] + 0.5 * t * t * a
        x[:, velocity] += t * a
    rates = (reference.payload_yaw_rate_radps, *reference.uav_yaw_rates_radps)
    for index, rate in kinematics.yaws:
        x[:, index] += rates[rate] * times_s
    return x


def sampled_stages(horizon: int) -> tuple[int, ...]:
    """The stages whose equilibrium is computed (every ``STAGE_STRIDE``-th, and the last);
    ``stage_targets`` interpolates between them."""
    return tuple(sorted({*range(STAGE_STRIDE, horizon + 1, STAGE_STRIDE), horizon}))


def stage_targets(
    x_eq: FloatArray,
    u_eq: FloatArray,
    reference: FormationReference,
    sampled: Mapping[int, tuple[FloatArray, FloatArray]],
    horizon: int,
    kinematics: Kinematics,
    dt_s: float,
) -> tuple[FloatArray, FloatArray]:
    """(x̄ (N + 1, nx), ū (N, nu)) around this tick's (``x_eq``, ``u_eq``) at
    ``reference``, from the equilibria (x_eq,k, u_eq,k) of the references at the stages
    ``sampled`` (``sampled_stages``): between them, the departure from x_eq(t) is
    interpolated linearly (it is smooth; x_eq(t) itself is carried exactly). Yaw
    differences are taken the short way round; velocities are made to agree with the
    positions (``_consistent_velocities``)."""
    known = [0, *sorted(sampled)]
    stages: FloatArray = np.arange(horizon + 1, dtype=np.float64)
    carried = carried_on(x_eq, reference, kinematics, dt_s * stages)
    departures = np.array([carried[0] - x_eq] + [sampled[k][0] - carried[k] for k in known[1:]])
    for index, _ in kinematics.yaws:
        departures[:, index] = np.remainder(departures[:, index] + math.pi, 2.0 * math.pi) - math.pi
    inputs = np.array([u_eq] + [sampled[k][1] for k in known[1:]])
    states = _consistent_velocities(
        carried + _interpolated(known, departures, stages), kinematics, dt_s
    )
    x_target: FloatArray = states - carried
    x_target[0] = 0.0
    u_target: FloatArray = _interpolated(known, inputs, stages)[:horizon] - u_eq
    u_target[0] = 0.0
    return x_target, u_target


def _interpolated(known: Sequence[int], values: FloatArray, stages: FloatArray) -> FloatArray:
    """``values`` (one row per stage in ``known``) interpolated linearly at ``stages``."""
    weights: FloatArray = _interpolation(tuple(known), tuple(stages.tolist()))
    return weights @ values


@lru_cache(maxsize=8)
def _interpolation(known: tuple[int, ...], stages: tuple[float, ...]) -> FloatArray:
    """The matrix (len(stages), len(known)) of linear interpolation from ``known`` to
    ``stages`` (a tick's horizon asks for the same one every time)."""
    identity = np.eye(len(known))
    columns = [np.interp(stages, known, identity[:, j]) for j in range(len(known))]
    weights = np.stack(columns, axis=1)
    weights.setflags(write=False)
    return weights


def _consistent_velocities(states: FloatArray, kinematics: Kinematics, dt_s: float) -> FloatArray:
    """``states`` (stage 0 … N, one per row) with each body's velocity at stages 1 … N
    replaced by the rate of its positions across the stages (central differences, a
    second-order backward one at N: both exact for positions quadratic in time). Each
    stage's equilibrium gives the velocity of a formation moving steadily at that stage's
    acceleration; where the acceleration turns or changes (a bend, the end of a move) the
    UAVs also move about their cable ends, and positions and velocities that disagree
    would be tracked as a compromise between them (on a 1.6 m circle at 2 m/s², the
    decentralized bar drifted 13 cm outward)."""
    out = states.copy()
    for position, velocity in kinematics.moving:
        p = states[:, position]
        out[1:-1, velocity] = (p[2:] - p[:-2]) / (2.0 * dt_s)
        out[-1, velocity] = (3.0 * p[-1] - 4.0 * p[-2] + p[-3]) / (2.0 * dt_s)
    return out


def moved_like(preview: Preview, before: FormationReference, after: FormationReference) -> Preview:
    """``preview`` moved as ``before`` was to give ``after`` (the integral's or the
    reference lead's shift of position and payload yaw)."""
    offset = np.subtract(after.payload_position_m, before.payload_position_m)
    turn = after.payload_yaw_rad - before.payload_yaw_rad
    if not offset.any() and turn == 0.0:
        return preview
    moved = {}
    for k, stage in preview.items():
        x, y, z = np.add(stage.payload_position_m, offset)
        moved[k] = replace(
            stage,
            payload_position_m=(float(x), float(y), float(z)),
            payload_yaw_rad=stage.payload_yaw_rad + turn,
        )
    return moved
