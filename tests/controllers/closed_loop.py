"""A fixed-step closed loop on the controllers' nonlinear model (in-process, no I/O)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controllers.formation_equilibria import FormationReference
from controllers.formation_model import FormationModel
from controllers.mpc import CentralizedMpc, DecentralizedMpc, Plan


@dataclass(frozen=True)
class Run:
    times_s: np.ndarray
    states: np.ndarray  # (ticks + 1, 12 + 12N)
    plans: list[Plan]


def hold(
    model: FormationModel, x: np.ndarray, u: np.ndarray, h: float, substeps: int
) -> np.ndarray:
    """``x`` after ``substeps`` RK4 steps of ``h`` [s] with the input ``u`` held."""
    f = model.dynamics
    for _ in range(substeps):
        k1 = np.asarray(f(x, u)).ravel()
        k2 = np.asarray(f(x + h / 2 * k1, u)).ravel()
        k3 = np.asarray(f(x + h / 2 * k2, u)).ravel()
        k4 = np.asarray(f(x + h * k3, u)).ravel()
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return x


def fly(
    controller: CentralizedMpc | DecentralizedMpc,
    model: FormationModel,
    x0: np.ndarray,
    reference: FormationReference,
    duration_s: float,
    substeps: int = 4,
) -> Run:
    """Zero-order hold of each plan's u for one tick, RK4 with ``substeps`` per tick."""
    h_tick = controller.settings.dt_s
    h = h_tick / substeps
    x = x0.copy()
    states, plans = [x.copy()], []
    ticks = round(duration_s / h_tick)
    for k in range(ticks):
        plan = controller.step(x, reference, k * h_tick)
        plans.append(plan)
        x = hold(model, x, plan.u, h, substeps)
        states.append(x.copy())
    return Run(np.arange(ticks + 1) * h_tick, np.array(states), plans)
