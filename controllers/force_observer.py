"""A disturbance-force observer: the constant external loads on the payload and each UAV.

Both MPCs regulate to the equilibrium their model computes for the reference. A load
the model leaves out — a push or wind on a body, a payload or a UAV heavier than
configured, a payload whose CoM is off its configured point — makes that equilibrium a
wrong one, and the quadratic cost then balances the missing force against a position
error (issue 33: a 1 N push on the bar held it 1.4 m off). ``ForceObserver`` estimates
the loads d = (f_b, τ_b, f_1, …, f_N) in the world frame — the force f_b [N] at the
payload's CoM, the torque τ_b [N m] on it, each UAV's force f_i [N] — so that the
equilibrium includes them (``formation_equilibrium(..., forces=)``): offset-free for
constant loads, not a reference shift.

Each estimate's velocities (v_b, ω_b, v_i) are compared with the model's prediction from
the one before: the velocities then plus h times the model's rates of change at the
midpoint of the two measured states, under the input in force then
(``DelayPredictor.input_at``) and the loads estimated so far. The attitudes come from the
measurements, not from integrating the torques sent: a PX4 flying body rates applies its
own. A load error δd changes the velocities by G δd, G = h ∂(v̇, ω̇)/∂d (the constrained
model: a force on one body moves the others through the cables). The velocity error e
updates the estimate by the least-norm δd with G δd = e, each row in its body's own
scale, taken with the gain h / (τ + h): a first-order estimate with the time constant τ
(``mpc.force_observer_s``). Forces along a cable pulling its two ends apart move nothing,
so G is singular there; the least-norm update leaves those parts at zero. Each body's
force is bounded (``max_force_n``), the payload's torque (``MAX_TORQUE_NM``), and its
upward force to half its weight (the cables must still carry it), so a wrong model cannot
ask for an unbounded or a slack equilibrium. Time is an argument; it holds no clock.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from controllers.codegen import NumericFunction
from controllers.delay import HISTORY_S, DelayPredictor
from controllers.formation_equilibria import NO_FORCES, ExternalForces
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from geometry.arrays import FloatArray
from geometry.state import V_B, W_B

# Singular values of G below this share of the largest are the cables' internal forces.
_RCOND = 0.05
# The most torque [N m] it may put on the payload: a payload's CoM 0.25 m off its configured
# point at 0.4 kg (the equilibrium moves the cables' balance point at most halfway to an
# attachment, ``formation_equilibria._balance_point``).
MAX_TORQUE_NM = 1.0
# The most of the payload's weight an upward force on it may take off its cables.
MAX_LIFT_SHARE = 0.5


def _velocity_rates(model: FormationModel, velocity_rows: list[int]) -> ca.Function:
    """``(x, u, d) -> (v̇, ∂v̇/∂d)``: the bodies' accelerations and their change per unit of
    each load (the loads enter linearly: the sensitivity holds for any u and d)."""
    x = ca.SX.sym("x", model.layout.n_states)
    u = ca.SX.sym("u", model.layout.n_inputs)
    d = ca.SX.sym("d", model.n_forces)
    rates = model.forced_dynamics(x, u, d)[velocity_rows]
    return ca.Function("force_observer_rates", [x, u, d], [rates, ca.jacobian(rates, d)])


def velocity_indices(params: FormationParams) -> list[int]:
    """Where the state keeps the bodies' velocities: the payload's v_b and ω_b, then each
    UAV's v_i."""
    layout = params.layout
    every = list(range(layout.n_states))
    rows = every[V_B] + every[W_B]
    for i in layout.vehicles:
        rows += every[layout.uav_slices(i)[1]]
    return rows


class ForceObserver:
    """The external forces on the payload and each UAV, estimated with the time constant
    ``time_constant_s`` (0: off, the forces stay zero) and bounded to ``max_force_n`` per
    body. It reads the inputs sent from ``predictor`` and sets the loads it carries, so
    that the delay compensation includes them."""

    def __init__(
        self,
        params: FormationParams,
        predictor: DelayPredictor,
        time_constant_s: float,
        max_force_n: float,
    ) -> None:
        if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
            raise ValueError(
                f"the force observer's time constant must be finite and >= 0, got {time_constant_s}"
            )
        if not (math.isfinite(max_force_n) and max_force_n > 0.0):
            raise ValueError(
                f"the force observer's bound must be finite and > 0, got {max_force_n}"
            )
        self.time_constant_s = time_constant_s
        self.max_force_n = max_force_n
        self._n_vehicles = params.n_vehicles
        self._largest_lift_n = MAX_LIFT_SHARE * params.payload.mass_kg * params.gravity_mps2
        self._predictor = predictor
        self._rows = velocity_indices(params)
        self._yaws = list(params.layout.yaw_indices)
        self._rates = NumericFunction(_velocity_rates(FormationModel(params), self._rows))
        self._d = np.zeros(6 + 3 * params.n_vehicles)
        self._last: tuple[float, FloatArray] | None = None

    @property
    def forces(self) -> ExternalForces:
        """The forces estimated so far."""
        if not np.any(self._d):
            return NO_FORCES
        return ExternalForces.from_vector(self._d)

    def at_bound(self) -> list[str]:
        """The bodies whose load the bound holds ("bar", "bar torque", "uav1", …): the model
        is further off than the observer may make up for."""
        names = ["bar", "bar torque", *(f"uav{i}" for i in range(1, self._n_vehicles + 1))]
        return [
            name
            for k, name in zip(range(0, self._d.size, 3), names, strict=True)
            if np.linalg.norm(self._d[k : k + 3]) >= self._largest(k) * (1.0 - 1e-9)
        ]

    def reset(self) -> None:
        """Start from no forces (a new flight)."""
        self._d[:] = 0.0
        self._predictor.forces = self._d.copy()
        self._last = None

    def pause(self) -> None:
        """Keep the forces, but compare the next estimate with none (the model did not
        describe what happened in between: on the ground, a UAV left to its PX4)."""
        self._last = None

    def update(self, x: FloatArray, t_s: float, slower: float = 1.0) -> ExternalForces:
        """Fold in the estimate ``x`` (12 + 12N,) of the state at ``t_s`` [s]: its velocities
        against the model's prediction from the last estimate, learnt with the time
        constant ``slower`` × ``time_constant_s``. The first estimate, one more than
        ``HISTORY_S`` after the last and a non-finite one only restart the comparison."""
        if self.time_constant_s == 0.0:
            return NO_FORCES
        state = np.array(x, dtype=float)
        last, self._last = self._last, None
        if not np.all(np.isfinite(state)):
            return self.forces
        self._last = (t_s, state)
        if last is None or not 0.0 < t_s - last[0] <= HISTORY_S:
            return self.forces
        h = t_s - last[0]
        u = self._predictor.input_at(last[0] + h / 2)
        if u is None:
            return self.forces
        change = state - last[1]
        change[self._yaws] = np.remainder(change[self._yaws] + np.pi, 2 * np.pi) - np.pi
        rates, sensitivity = self._rates(last[1] + change / 2, u, self._d)
        error = change[self._rows] - h * rates.ravel()
        sensitivity = h * sensitivity
        # Each row in its body's own scale (the bar's small inertia would otherwise make
        # the UAVs' columns look singular beside its turn rate's).
        scale = np.abs(sensitivity).max(axis=1)
        scale[scale == 0.0] = 1.0
        step = np.linalg.lstsq(sensitivity / scale[:, None], error / scale, rcond=_RCOND)[0]
        self._d += h / (slower * self.time_constant_s + h) * step
        self._bound()
        self._predictor.forces = self._d.copy()
        return self.forces

    def _largest(self, k: int) -> float:
        return MAX_TORQUE_NM if k == 3 else self.max_force_n

    def _bound(self) -> None:
        for k in range(0, self._d.size, 3):
            largest = self._largest(k)
            size = float(np.linalg.norm(self._d[k : k + 3]))
            if size > largest:
                self._d[k : k + 3] *= largest / size
        self._d[2] = min(self._d[2], self._largest_lift_n)
