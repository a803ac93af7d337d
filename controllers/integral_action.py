"""Integral action on the reference: offset-free tracking of the payload and the UAVs' yaws.

Both MPCs regulate to the equilibrium their model computes for the reference. When the
plant differs from the model — a payload heavier than configured, a steady push on a
body — the equilibrium input is wrong, and the quadratic cost balances the missing force
against a position error: a bar 50 % heavier than configured hangs 12–17 cm low for as long
as the reference is held (issue 19). ``ReferenceIntegrator`` integrates the error between
the held reference and the estimate (payload position, payload yaw, each UAV's yaw) and
moves the reference the MPC regulates to by that integral times a gain, so a steady error
cannot remain: the equilibrium the MPC is given then asks for the missing force.

It integrates only while the reference is held (no velocity, no turn or cone-angle rate,
the same as the tick before): the lag of a moving reference is no offset, and integrating
it would wind up. The integral is kept through moves and bounded (``IntegralLimits``), so
a wrong model can shift the reference by at most that much. Time is an argument.

Both this and the disturbance-force observer (``controllers.force_observer``) run by
default. The observer makes constant forces offset-free through the equilibrium, so the
integral sees little; what it still takes out is what the observer's estimate cannot: a
load split between the bodies is not unique (a couple on the payload against opposite
forces on the UAVs moves nothing at one geometry, yet asks for another equilibrium at the
next), and a torque about the vertical has no level equilibrium in closed form (issue
33: the bar's CoM 5 cm off left 39 mm of mean error on the paper's sequence with the
observer alone, 8 mm with both).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controllers.formation_equilibria import FormationReference
from geometry.arrays import FloatArray
from geometry.formation import FormationLayout
from geometry.state import payload_position, payload_yaw


@dataclass(frozen=True)
class IntegralLimits:
    """The most the integral may move the reference: payload position [m], yaws [rad]."""

    position_m: float = 0.3
    yaw_rad: float = math.radians(15.0)


class ReferenceIntegrator:
    """Moves the MPC's reference by ``gain_per_s`` × the integral of the held reference's
    error (payload position, payload yaw, UAV yaws); a gain of 0 leaves it as it is."""

    def __init__(
        self,
        layout: FormationLayout,
        gain_per_s: float,
        limits: IntegralLimits = IntegralLimits(),
    ) -> None:
        if not (math.isfinite(gain_per_s) and gain_per_s >= 0.0):
            raise ValueError(f"the integral gain must be finite and >= 0, got {gain_per_s}")
        self.gain_per_s = gain_per_s
        self.limits = limits
        self._layout = layout
        self._position_m = np.zeros(3)  # the reference's shift: gain × ∫ error dt
        self._yaws_rad = np.zeros(1 + layout.n_vehicles)  # payload, UAV 1, …, UAV N
        self._last: tuple[float, FormationReference] | None = None

    @property
    def shift(self) -> tuple[FloatArray, FloatArray]:
        """The present shift: payload position (3,) [m], yaws (payload, UAV 1, …, UAV N)
        (1 + N,) [rad]."""
        return self._position_m.copy(), self._yaws_rad.copy()

    def reset(self) -> None:
        """Start from no shift (a new flight)."""
        self._position_m[:] = 0.0
        self._yaws_rad[:] = 0.0
        self._last = None

    def shifted(
        self,
        reference: FormationReference,
        x: FloatArray,
        now_s: float,
        integrating: bool = True,
    ) -> FormationReference:
        """``reference`` moved by the integral, after integrating the error of ``x`` (12 + 12N,)
        since the last call when ``reference`` is held. A non-finite ``x``, or
        ``integrating`` false (an error that is no offset), integrates nothing."""
        if self.gain_per_s == 0.0:
            return reference
        last, self._last = self._last, (now_s, reference)
        held = (
            integrating
            and last is not None
            and last[1] == reference
            and not any(reference.velocity_mps)
            and not reference.payload_yaw_rate_radps
            and not any(reference.uav_yaw_rates_radps)
            and not reference.cone_angle_rate_radps
        )
        if held and last is not None and np.all(np.isfinite(x)):
            dt = max(0.0, now_s - last[0])
            position_error = np.asarray(reference.payload_position_m) - payload_position(x)
            measured_yaws = (payload_yaw(x), *self._layout.uav_yaws(x))
            wanted_yaws = (reference.payload_yaw_rad, *reference.uav_yaw_rad)
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
        p = np.asarray(reference.payload_position_m) + self._position_m
        return replace(
            reference,
            payload_position_m=(float(p[0]), float(p[1]), float(p[2])),
            payload_yaw_rad=reference.payload_yaw_rad + float(self._yaws_rad[0]),
            uav_yaw_rad=tuple(
                yaw + float(shift)
                for yaw, shift in zip(reference.uav_yaw_rad, self._yaws_rad[1:], strict=True)
            ),
        )
