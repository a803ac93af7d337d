"""A model-based filter of the UAVs' body-rate estimates: less torque noise on the MPC.

The mocap fusion differentiates attitude to get the body rates, with white angular
acceleration as its only model: with nominal noise the rates carry enough noise that the
MPC's torques move 0.1 N m from tick to tick, white-like (issue 19). The fusion cannot
know the torques; the supervisor does. ``RateFilter`` carries its last filtered state one
tick on with the controllers' model under the inputs sent (``DelayPredictor.advance``) and
blends that prediction's UAV body rates with the measured ones: ω = w·ω_model +
(1 − w)·ω_measured. The torque-driven part of the motion comes through without the lag a
plain low-pass adds; what the model misses (a wrong inertia, a disturbance torque) enters
through the measured share, a first-order lag of about h·w/(1 − w) (h: the tick).
Only the UAVs' rates are filtered; every other entry stays as measured.

``RateCrossover`` removes another error of the fused rates, a slow one the model-based
blend passes at full gain: it takes the rates' low-frequency part from the attitude's
change over each tick (``mpc.rate_crossover_s``).
"""

from __future__ import annotations

import math

import numpy as np

from controllers.delay import HISTORY_S, DelayPredictor
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.frames import (
    quaternion_from_rotation,
    rotation_from_euler_zyx,
    rotation_vector_from_quaternion,
)


class RateFilter:
    """The estimate with the UAVs' body rates blended towards the model's prediction by
    ``model_weight`` in [0, 1); 0 passes the estimate through."""

    def __init__(self, predictor: DelayPredictor, model_weight: float) -> None:
        if not (math.isfinite(model_weight) and 0.0 <= model_weight < 1.0):
            raise ValueError(
                f"the rate filter's model weight must be in [0, 1), got {model_weight}"
            )
        self.model_weight = model_weight
        self._predictor = predictor
        self._rates = predictor.layout.uav_rate_indices
        self._last: tuple[float, FloatArray] | None = None

    def reset(self) -> None:
        """Start anew from the next estimate."""
        self._last = None

    def filtered(self, x: FloatArray, t_s: float) -> FloatArray:
        """``x`` (12 + 12N,), the estimate of the state at ``t_s`` [s], with its UAV body rates
        filtered. The first estimate, one after a gap of more than ``HISTORY_S``, and a
        non-finite one pass through (and restart the filter)."""
        out = np.array(x, dtype=float)
        if self.model_weight == 0.0:
            return out
        last, self._last = self._last, None
        if not np.all(np.isfinite(out)):
            return out
        if last is not None and 0.0 < t_s - last[0] <= HISTORY_S:
            prior = self._predictor.advance(last[1], last[0], t_s)
            w = self.model_weight
            rates = self._rates
            out[rates] = w * prior[rates] + (1.0 - w) * out[rates]
        self._last = (t_s, out.copy())
        return out


class RateCrossover:
    """The UAVs' body rates with their slow part taken from the attitude estimate.

    The fusion's rates come from a 100 Hz filter whose rate noise reaches up to the frame
    rate; sampled once per 20 ms tick, that noise folds down to every frequency, and the
    rates the MPC sees carry a low-frequency error (about 0.01 rad/s/√Hz, issue 19) that
    the attitude estimate does not: the attitude's change over a tick gives the mean body
    rate across it with twenty times less error below 1 Hz. ``RateCrossover`` is a
    complementary filter with the crossover time constant ``time_constant_s`` (T): the
    fused rates pass as they are above 1/(2π T), and below it the discrepancy between the
    attitude's mean rate over the last tick and the fused rates' mean over it (a
    first-order low-pass with T) is added back. A rate held steady passes unchanged.
    Only the UAVs' rates are changed; every other entry stays as it came.
    """

    def __init__(self, layout: FormationLayout, time_constant_s: float) -> None:
        if not (math.isfinite(time_constant_s) and time_constant_s >= 0.0):
            raise ValueError(
                f"the rate crossover's time constant must be ≥ 0 s, got {time_constant_s}"
            )
        self.time_constant_s = time_constant_s
        self._layout = layout
        self._rates = layout.uav_rate_indices
        self._last: tuple[float, FloatArray] | None = None
        self._correction = np.zeros(len(self._rates))

    def reset(self) -> None:
        """Start anew from the next estimate."""
        self._last = None
        self._correction[:] = 0.0

    def corrected(self, x: FloatArray, t_s: float) -> FloatArray:
        """``x`` (12 + 12N,), the estimate at ``t_s`` [s], with its UAV body rates corrected. The
        first estimate after a reset, one more than ``HISTORY_S`` after the last and a
        non-finite one restart the filter; ``time_constant_s`` 0 passes ``x`` through."""
        out = np.array(x, dtype=float)
        if self.time_constant_s == 0.0:
            return out
        last, self._last = self._last, None
        if not np.all(np.isfinite(out)):
            self._correction[:] = 0.0
            return out
        self._last = (t_s, np.array(x, dtype=float))
        if last is None or not 0.0 < t_s - last[0] <= HISTORY_S:
            self._correction[:] = 0.0
            return out
        h, before = t_s - last[0], last[1]
        discrepancy = np.concatenate(
            [
                mean_body_rate(before[angles], out[angles], h) - 0.5 * (before[rates] + out[rates])
                for angles, rates in (self._layout.uav_slices(i)[2:] for i in self._layout.vehicles)
            ]
        )
        blend = h / (self.time_constant_s + h)
        self._correction += blend * (discrepancy - self._correction)
        out[self._rates] += self._correction
        return out


def mean_body_rate(euler_before: FloatArray, euler_after: FloatArray, h_s: float) -> FloatArray:
    """The constant body rate [rad/s] (FLU) that turns the Z-Y-X attitude ``euler_before``
    into ``euler_after`` in ``h_s`` seconds."""
    turn = rotation_from_euler_zyx(*euler_before).T @ rotation_from_euler_zyx(*euler_after)
    rotation_vector: FloatArray = rotation_vector_from_quaternion(quaternion_from_rotation(turn))
    return rotation_vector / h_s
