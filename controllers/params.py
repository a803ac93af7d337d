"""Plain, frozen parameter objects for the controllers (SI units; no config files here)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

# Seconds from an arbitrary origin, read to time a computation. Injected, never read from
# the system here: the service passes the wall clock, the fast simulator the thread's CPU
# time (a solve is late by what it computes, not by what the machine's other load adds).
Clock = Callable[[], float]


@dataclass(frozen=True)
class UavParams:
    """One quadrotor: mass [kg] and principal moments of inertia diag(J) [kg m²]."""

    mass_kg: float
    inertia_kgm2: tuple[float, float, float]


@dataclass(frozen=True)
class MpcWeights:
    """Diagonal weights of (MPC): Q, R_MPC and Q_N = terminal_scale * Q."""

    q_diag: tuple[float, ...]
    r_diag: tuple[float, ...]
    terminal_scale: float


@dataclass(frozen=True)
class InputLimits:
    """The input set U of (MPC): thrust_min ≤ F_i ≤ thrust_max, |τ_i|∞ ≤ torque_max."""

    thrust_min_n: float
    thrust_max_n: float
    torque_max_nm: float


@dataclass(frozen=True)
class StateBound:
    """One entry of the state set X (or X_N): ``lower ≤ x[index] ≤ upper`` in absolute
    state coordinates (e.g. index 2, the payload's height)."""

    index: int
    lower: float
    upper: float


@dataclass(frozen=True)
class ReferenceLead:
    """Beyond the paper, for the decentralized MPC only: the setpoint every agent regulates
    to is moved along the payload's measured motion, its position by ``position_s`` times
    the payload's velocity error and its yaw by ``yaw_s`` times its yaw-rate error. Each
    agent's model, cost and constraints stay those of Section V; what the agents share is
    the payload's velocity and yaw rate. Zero (the default) is Section V as published."""

    position_s: float = 0.0
    yaw_s: float = 0.0


RECOMMENDED_LEAD = ReferenceLead(position_s=0.6, yaw_s=0.2)
"""The lead the analysis and the simulations support (README; configs/kth_sml.toml)."""


@dataclass(frozen=True)
class MpcSettings:
    """Everything an MPC needs besides the model: (MPC)'s N, h, weights, U, X, X_N, and
    the time budget after which a finished solve is treated as late."""

    horizon: int
    dt_s: float
    weights: MpcWeights
    limits: InputLimits
    state_bounds: tuple[StateBound, ...] = ()
    terminal_bounds: tuple[StateBound, ...] = ()
    qp_backend: str = "hpipm"
    late_after_s: float = 0.015
    prepared_yaw_tolerance_rad: float = 0.0
    """How far the measured yaws may be from those a ``prepare`` linearized at for its
    linearization to be used [rad]; 0 keeps only an exact match."""
    reference_lead: ReferenceLead = ReferenceLead()
    """The decentralized MPC's setpoint lead (``ReferenceLead``); unused by the
    centralized MPC."""
    delay_s: float = 0.0
    """The mocap-to-command delay [s] the state is predicted across before the MPC plans
    (``controllers.delay``); 0 plans from the estimate as it comes, as the paper does."""
    rate_filter_weight: float = 0.0
    """The model's weight in the UAVs' body-rate estimates, in [0, 1)
    (``controllers.rate_filter``); 0 takes the fused rates as they come."""
    rate_crossover_s: float = 0.0
    """The time constant [s] below which the UAVs' body rates come from the attitude
    estimate's change over each tick, not the fused rates (``RateCrossover``); 0 takes
    the fused rates as they come."""
    integral_gain_per_s: float = 0.0
    """The gain of the integral action on the held reference's error [1/s]
    (``controllers.integral_action``); 0 is the paper's MPC, which leaves model errors as
    steady offsets."""
    force_observer_s: float = 0.0
    """The time constant [s] of the disturbance-force observer
    (``controllers.force_observer``); 0 leaves the forces out, as the paper does."""
    force_observer_max_n: float = 5.0
    """The most force [N] the observer may put on any one body."""
