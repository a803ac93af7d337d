"""Pre-arm checks of the resting pose: before the motors spin, the measured bodies must be
the system the take-off expects — each UAV standing by its own cable's attachment, the
payload lying level, the UAVs upright. After an abort that left the bar twisted and a UAV
a metre away, a take-off would start by dragging the bar. And the take-off's first
setpoint, the hover above the resting pose, must be one the setpoint queue would take.
Pure; SI units."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.formation_params import FormationParams
from geometry.arrays import FloatArray
from geometry.frames import rotation_from_euler_zyx
from geometry.state import payload_points, payload_position, payload_yaw
from supervisor.flight.feasibility import SetpointBounds
from supervisor.flight.setpoints import Arena, Setpoint, SetpointError, validate_setpoint

# Where a UAV comes to rest beyond where its landing aimed (drift in the last centimetres,
# ground contact): a landing's own result must pass the next flight's pre-arm check.
LANDED_SPREAD_M = 0.15


@dataclass(frozen=True)
class RestingLimits:
    """How far the measured pose may be from the resting pose a take-off starts from."""

    uav_from_bar_end_m: float  # horizontal, UAV centre to its cable's bar end
    bar_end_height_difference_m: float = 0.1
    uav_tilt_rad: float = math.radians(15.0)


def resting_limits(landing_clearance_m: float) -> RestingLimits:
    """The resting pose a take-off accepts: where a landing leaves the UAVs, each
    ``landing_clearance_m`` outward of its bar end, with ``LANDED_SPREAD_M`` to spare (one
    number for both, so that every landing leaves the system ready for the next flight)."""
    return RestingLimits(uav_from_bar_end_m=landing_clearance_m + LANDED_SPREAD_M)


def resting_pose_problems(
    x: FloatArray, params: FormationParams, limits: RestingLimits
) -> list[str]:
    """What is wrong with the resting pose ``x`` (the formation's state), in words; empty:
    ready."""
    problems = []
    layout = params.layout
    ends = payload_points(x, params.payload.attachments_m)
    for i in layout.vehicles:
        offset = float(np.linalg.norm((layout.uav_position(x, i) - ends[i - 1])[0:2]))
        if offset > limits.uav_from_bar_end_m:
            problems.append(
                f"UAV {i} stands {offset:.2f} m from its bar end "
                f"(at most {limits.uav_from_bar_end_m:.2f} m): stand it by its bar end"
            )
        z_axis_z = float(rotation_from_euler_zyx(*layout.uav_euler(x, i))[2, 2])
        tilt = math.acos(max(-1.0, min(1.0, z_axis_z)))
        if tilt > limits.uav_tilt_rad:
            problems.append(f"UAV {i} is tilted {math.degrees(tilt):.0f}°: set it upright")
    heights = [float(end[2]) for end in ends]
    rise = max(heights) - min(heights)
    if rise > limits.bar_end_height_difference_m:
        problems.append(
            f"the bar is not level (its ends {rise:.2f} m apart in height): lay it flat"
        )
    return problems


def takeoff_problem(
    x: FloatArray,
    params: FormationParams,
    height_m: float,
    arena: Arena,
    bounds: SetpointBounds,
) -> str | None:
    """Why the hover ``height_m`` above the resting pose ``x`` (where a take-off goes, with
    the bar's and the UAVs' yaws kept) cannot be flown, as a queued setpoint would be
    refused; None: it can."""
    p = payload_position(x)
    hover = Setpoint(
        (float(p[0]), float(p[1]), float(p[2]) + height_m),
        payload_yaw(x),
        params.layout.uav_yaws(x),
        0.0,
    )
    try:
        validate_setpoint(hover, params, arena, bounds)
    except SetpointError as error:
        return f"the take-off's hover {height_m:.2f} m above cannot be flown: {error}"
    return None
