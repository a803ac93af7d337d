"""Motion-capture poses as PX4's external vision, without I/O: one body's pose (arena ENU,
FLU body) in NED/FRD as VISION_POSITION_ESTIMATE or ODOMETRY (docs/reference/px4-offboard.md
§2.5), once per new frame. Used by the vehicle link and by the mocap relay process.
"""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np

from geometry.arrays import FloatArray
from geometry.frames import (
    enu_to_ned,
    euler_zyx_from_rotation,
    quaternion_from_rotation,
    rotation_enu_flu_to_ned_frd,
    rotation_from_quaternion,
)
from px4_mavlink.codec import mavlink

VisionMessage = Literal["vision_position_estimate", "odometry"]


class VisionEncoder:
    """Queues one body's poses on a codec's ``messages``; skips a frame not newer than the
    last one queued, since PX4 would fuse a re-sent pose as a fresh measurement."""

    def __init__(self, messages: Any, kind: VisionMessage) -> None:
        self._messages = messages
        self.kind = kind
        self.last_time_s = -math.inf
        self.sent = 0
        self.skipped = 0

    def queue(self, position_m: FloatArray, quaternion: FloatArray, time_s: float) -> bool:
        """Queue the pose captured at ``time_s`` [s] (``usec`` = that in µs: the caller's
        clock, the time base of its TIMESYNC answers); False when skipped (not finite, or
        not newer than the last)."""
        finite = np.all(np.isfinite(position_m)) and np.all(np.isfinite(quaternion))
        if not (finite and math.isfinite(time_s)):
            return False
        if time_s <= self.last_time_s:
            self.skipped += 1
            return False
        self.last_time_s = time_s
        north, east, down = enu_to_ned(position_m)
        R = rotation_enu_flu_to_ned_frd(rotation_from_quaternion(quaternion))
        usec = round(time_s * 1e6)
        if self.kind == "vision_position_estimate":
            roll, pitch, yaw = euler_zyx_from_rotation(R)
            self._messages.vision_position_estimate_send(usec, north, east, down, roll, pitch, yaw)
        else:
            q = [float(v) for v in quaternion_from_rotation(R)]
            nan21 = [math.nan] * 21
            self._messages.odometry_send(
                usec, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                north, east, down, q, math.nan, math.nan, math.nan,
                math.nan, math.nan, math.nan, nan21, nan21,
            )  # fmt: skip
        self.sent += 1
        return True
