"""A path's waypoints checked one by one as setpoints at rest: what can be known of a path
before the flight's state (the API process's check, so that a path no vehicle can fly never
reaches the flight process). The tick core then checks the whole timed path from where it
will start (``supervisor.flight.paths.path_problem``), as the authority.

A waypoint without a yaw or θ_l keeps those of the point before, and the first point before
is the path's start, which only the flight knows: until a waypoint names both, only what
holds at any yaw and θ_l is checked, the bar's centre inside the arena.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from controllers.formation_params import FormationParams
from supervisor.flight.feasibility import SetpointBounds
from supervisor.flight.setpoints import (
    Arena,
    Setpoint,
    SetpointError,
    point_outside,
    validate_setpoint,
)
from supervisor.flight.waypoint import Waypoint


def validate_waypoints(
    waypoints: Sequence[Waypoint], params: FormationParams, arena: Arena, bounds: SetpointBounds
) -> None:
    """Raise ``SetpointError`` naming the first waypoint (by its index) that cannot be
    flown as a setpoint at rest (outside the arena, no equilibrium the vehicles can hold);
    return quietly when none is known to be unflyable."""
    yaw_rad: float | None = None
    theta_l_rad: float | None = None
    for index, point in enumerate(waypoints):
        yaw_rad = point.bar_yaw_rad if point.bar_yaw_rad is not None else yaw_rad
        theta_l_rad = point.theta_l_rad if point.theta_l_rad is not None else theta_l_rad
        try:
            if yaw_rad is None or theta_l_rad is None:
                outside = point_outside("bar centre", np.asarray(point.bar_position_m), arena)
                if outside is not None:
                    raise SetpointError(outside)
            else:
                setpoint = Setpoint(point.bar_position_m, yaw_rad, None, theta_l_rad, hold_s=0.0)
                validate_setpoint(setpoint, params, arena, bounds)
        except SetpointError as error:
            raise SetpointError(f"waypoint {index}: {error}") from None
