"""Delay compensation: the estimate predicted across the mocap-to-command delay.

A mocap frame reaches the tick ``delay_s`` after it was captured (QTM → network → fusion;
the fusion's capture clock takes the smallest offset seen as zero, so this latency is
invisible to it), and the tick's input acts from then on. An MPC that starts its
prediction from the delayed state answers motions that are ``delay_s`` old: from about
25 ms the centralized roll loop rings in a limit cycle at the torque bound (issue 19).

``DelayPredictor`` keeps the inputs sent and their times, and integrates the controllers'
nonlinear model (``controllers.formation_model``; (5)–(8) for the bar) from the estimate,
taken as the state ``delay_s`` ago, across the delay with the inputs that were in force
then (zero-order hold, RK4), under the external forces ``forces`` (zero until the
disturbance-force observer sets them, ``controllers.force_observer``). Time is an
argument; it holds no clock.
"""

from __future__ import annotations

import math
from collections import deque

import casadi as ca
import numpy as np

from controllers.codegen import NumericFunction
from controllers.formation_model import FormationModel
from controllers.formation_params import FormationParams
from geometry.arrays import FloatArray

# RK4 steps of at most this: the fastest modes the prediction carries (the UAVs' attitude
# under the torque bound) change over tens of ms; 5 ms keeps the RK4 error at 45 ms far
# below the mocap noise (tests/controllers/test_delay.py).
MAX_STEP_S = 0.005


def _rk4_step(model: FormationModel) -> ca.Function:
    """``(x, u, d, h) -> x(t + h)``: one classical RK4 step of the formation's model under
    the external forces d."""
    x = ca.SX.sym("x", model.layout.n_states)
    u = ca.SX.sym("u", model.layout.n_inputs)
    d = ca.SX.sym("d", model.n_forces)
    h = ca.SX.sym("h")
    f = model.forced_dynamics
    k1 = f(x, u, d)
    k2 = f(x + h / 2 * k1, u, d)
    k3 = f(x + h / 2 * k2, u, d)
    k4 = f(x + h * k3, u, d)
    return ca.Function(
        "formation_rk4_forced", [x, u, d, h], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)]
    )


# How long inputs are kept beyond the delay: what ``advance`` may integrate over behind
# the delay window (the rate filter's step from one tick to the next, with slack for a
# late tick; controllers/rate_filter.py).
HISTORY_S = 0.1


class DelayPredictor:
    """The state ``delay_s`` [s] ahead of an estimate, with the inputs already sent.

    ``sent(t_s, u)`` records the input (4N,) [N, N m] applied from ``t_s`` on; ``predict``
    integrates across the delay, ``advance`` between any two times of the last
    ``HISTORY_S`` + ``delay_s``. Older inputs are forgotten.
    """

    def __init__(self, params: FormationParams, delay_s: float) -> None:
        if not (math.isfinite(delay_s) and delay_s >= 0.0):
            raise ValueError(f"the delay to predict across must be finite and >= 0, got {delay_s}")
        self.delay_s = delay_s
        self.layout = params.layout
        model = FormationModel(params)
        self._step = NumericFunction(_rk4_step(model))
        self.forces: FloatArray = np.zeros(model.n_forces)
        """d = (f_b, τ_b, f_1, …, f_N): the external loads the model carries."""
        self._sent: deque[tuple[float, FloatArray]] = deque()

    def reset(self) -> None:
        """Forget the inputs sent (e.g. on the ground, where none acted)."""
        self._sent.clear()

    def sent(self, t_s: float, u: FloatArray) -> None:
        """The input ``u`` (4N,) is in force from ``t_s`` [s] until the next one."""
        if self._sent and t_s < self._sent[-1][0]:
            self._sent.clear()  # time went backwards: a new flight, the old inputs are void
        self._sent.append((t_s, np.array(u, dtype=float)))
        # Keep the last input older than the window: it is in force at its start.
        oldest = t_s - self.delay_s - HISTORY_S
        while len(self._sent) > 1 and self._sent[1][0] <= oldest:
            self._sent.popleft()

    def input_at(self, t_s: float) -> FloatArray | None:
        """The input (4N,) in force at ``t_s`` [s] (the oldest kept stands for any time
        before it); None when none was sent."""
        if not self._sent:
            return None
        in_force = self._sent[0][1]
        for t_k, u in self._sent:
            if t_k > t_s:
                break
            in_force = u
        return in_force.copy()

    def predict(self, x: FloatArray, now_s: float) -> FloatArray:
        """``x`` (12 + 12N,), the estimate at ``now_s`` taken as the state ``delay_s`` earlier,
        carried to ``now_s`` by the model under the inputs sent. Unchanged (a copy) when
        there is no delay, no input was sent yet, or ``x`` is not finite: the MPC then
        reports what is wrong with it as before."""
        if self.delay_s == 0.0:
            return np.array(x, dtype=float)
        return self.advance(x, now_s - self.delay_s, now_s)

    def advance(self, x: FloatArray, from_s: float, to_s: float) -> FloatArray:
        """``x`` (12 + 12N,), the state at ``from_s``, carried to ``to_s`` [s] by the model under
        the inputs in force in between (the oldest input kept stands for any time before
        it). A copy of ``x`` when no input was sent, ``to_s`` is not after ``from_s``, or
        ``x`` (or the result) is not finite."""
        state = np.array(x, dtype=float)
        if not self._sent or to_s <= from_s or not np.all(np.isfinite(state)):
            return state
        times = [t for t, _ in self._sent]
        t = from_s
        for k, (t_k, u) in enumerate(self._sent):
            end = min(times[k + 1] if k + 1 < len(times) else to_s, to_s)
            begin = max(t, t_k) if k > 0 else t
            span = end - begin
            if span <= 0.0:
                continue
            substeps = max(1, math.ceil(span / MAX_STEP_S - 1e-9))
            h = span / substeps
            for _ in range(substeps):
                state = self._step(state, u, self.forces, np.array([h]))[0].ravel().copy()
            t = end
        if not np.all(np.isfinite(state)):
            return np.array(x, dtype=float)
        return state
