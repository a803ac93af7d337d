"""Integral action on the reference: offset-free tracking of the bar and the UAVs' yaws.

Both MPCs regulate to the equilibrium their model computes for the reference. When the
plant differs from the model — a bar heavier than configured, a steady push on a body — the
equilibrium input is wrong, and the quadratic cost balances the missing force against a
position error: a bar 50 % heavier than configured hangs 12–17 cm low for as long as the
reference is held (issue 19). ``ReferenceIntegrator`` integrates the error between the
held reference and the estimate (bar position, bar yaw, each UAV's yaw) and moves the
reference the MPC regulates to by that integral times a gain, so a steady error cannot
remain: the equilibrium the MPC is given then asks for the missing force.

It integrates only while the reference is held (no velocity, no turn or θ_l rate, the same
as the tick before): the lag of a moving reference is no offset, and integrating it would wind
up. The integral is kept through moves and bounded (``IntegralLimits``), so a wrong model
can shift the reference by at most that much. Time is an argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controllers.equilibria import Reference
from geometry.arrays import FloatArray
from geometry.state import bar_position, bar_yaw, uav_yaws


@dataclass(frozen=True)
class IntegralLimits:
    """The most the integral may move the reference: bar position [m], yaws [rad]."""

    position_m: float = 0.3
    yaw_rad: float = math.radians(15.0)


class ReferenceIntegrator:
    """Moves the MPC's reference by ``gain_per_s`` × the integral of the held reference's
    error (bar position, bar yaw, UAV yaws); a gain of 0 leaves it as it is."""

    def __init__(self, gain_per_s: float, limits: IntegralLimits = IntegralLimits()) -> None:
        if not (math.isfinite(gain_per_s) and gain_per_s >= 0.0):
            raise ValueError(f"the integral gain must be finite and >= 0, got {gain_per_s}")
        self.gain_per_s = gain_per_s
        self.limits = limits
        self._position_m = np.zeros(3)  # the reference's shift: gain × ∫ error dt
        self._yaws_rad = np.zeros(3)  # bar, UAV 1, UAV 2
        self._last: tuple[float, Reference] | None = None

    @property
    def shift(self) -> tuple[FloatArray, FloatArray]:
        """The present shift: bar position (3,) [m], yaws (bar, UAV 1, UAV 2) (3,) [rad]."""
        return self._position_m.copy(), self._yaws_rad.copy()

    def reset(self) -> None:
        """Start from no shift (a new flight)."""
        self._position_m[:] = 0.0
        self._yaws_rad[:] = 0.0
        self._last = None

    def shifted(self, reference: Reference, x: FloatArray, now_s: float) -> Reference:
        """``reference`` moved by the integral, after integrating the error of ``x`` (36,)
        since the last call when ``reference`` is held. A non-finite ``x`` integrates
        nothing."""
        if self.gain_per_s == 0.0:
            return reference
        last, self._last = self._last, (now_s, reference)
        held = (
            last is not None
            and last[1] == reference
            and not any(reference.velocity_mps)
            and not any(reference.yaw_rates_radps)
            and not reference.theta_l_rate_radps
        )
        if held and last is not None and np.all(np.isfinite(x)):
            dt = max(0.0, now_s - last[0])
            position_error = np.asarray(reference.bar_position_m) - bar_position(x)
            measured_yaws = (bar_yaw(x), *uav_yaws(x))
            wanted_yaws = (reference.bar_yaw_rad, *reference.uav_yaw_rad)
            yaw_errors = np.array(
                [
                    math.remainder(w - m, 2.0 * math.pi)
                    for w, m in zip(wanted_yaws, measured_yaws, strict=True)
                ]
            )
            k = self.gain_per_s * dt
            p_max, yaw_max = self.limits.position_m, self.limits.yaw_rad
            self._position_m = np.clip(self._position_m + k * position_error, -p_max, p_max)
            self._yaws_rad = np.clip(self._yaws_rad + k * yaw_errors, -yaw_max, yaw_max)
        p = np.asarray(reference.bar_position_m) + self._position_m
        return replace(
            reference,
            bar_position_m=(float(p[0]), float(p[1]), float(p[2])),
            bar_yaw_rad=reference.bar_yaw_rad + float(self._yaws_rad[0]),
            uav_yaw_rad=(
                reference.uav_yaw_rad[0] + float(self._yaws_rad[1]),
                reference.uav_yaw_rad[1] + float(self._yaws_rad[2]),
            ),
        )
