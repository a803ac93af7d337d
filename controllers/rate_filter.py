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
"""

from __future__ import annotations

import math

import numpy as np

from controllers.delay import HISTORY_S, DelayPredictor
from geometry.arrays import FloatArray
from geometry.state import uav_slices

RATES = [index for i in (1, 2) for index in range(36)[uav_slices(i)[3]]]


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
        self._last: tuple[float, FloatArray] | None = None

    def reset(self) -> None:
        """Start anew from the next estimate."""
        self._last = None

    def filtered(self, x: FloatArray, t_s: float) -> FloatArray:
        """``x`` (36,), the estimate of the state at ``t_s`` [s], with its UAV body rates
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
            out[RATES] = w * prior[RATES] + (1.0 - w) * out[RATES]
        self._last = (t_s, out.copy())
        return out
