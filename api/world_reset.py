"""After a reset of the simulated world: wait until the flight process tracks the bodies
where the world put them, so an ``arm`` that follows the reply is judged on the new pose.

The bodies jump back to their resting pose; the mocap fusion's innovation gate refuses
the jump until a rigid body could have made it (about 0.15 s for 0.3 m), and until then
the estimate is the old pose, then a stale one: an arm in that window is refused on a pose
that no longer exists.
"""

from __future__ import annotations

import asyncio
import math
from collections.abc import Mapping, Sequence
from typing import Any

from supervisor.flight.status import FlightStatus
from supervisor.ipc.client import FlightClient, SubscriptionEndedError

TRACKED_WITHIN_M = 0.03  # the estimate at the reset pose: mocap noise is ~1 mm
SETTLE_TIMEOUT_S = 3.0


def _distance(a: Sequence[float | None], b: Sequence[float]) -> float:
    if any(v is None for v in a):
        return math.inf
    return math.dist([float(v) for v in a if v is not None], b)


def tracked_at(status: FlightStatus, positions: Mapping[str, Sequence[float]]) -> bool:
    """Whether the telemetry ``status`` has fresh motion capture with every body within
    ``TRACKED_WITHIN_M`` of ``positions`` (body name → arena position [m])."""
    if not status.mocap.healthy:
        return False
    payload = status.bar.position  # the status's "bar" is the payload of any setup
    estimated = {"bar": payload, "payload": payload} | {
        f"uav{i}": uav.position for i, uav in enumerate(status.uavs, start=1)
    }
    return all(
        _distance(estimated[name], position) <= TRACKED_WITHIN_M
        for name, position in positions.items()
    )


async def settle_after_reset(
    flight: FlightClient, positions: Mapping[str, Sequence[float]]
) -> dict[str, Any]:
    """Wait (at most ``SETTLE_TIMEOUT_S``) for telemetry that tracks the bodies at
    ``positions``; what the reset's reply adds: ``tracked`` and the pre-arm verdict then
    (``arm_blocked_by``: null when the pre-arm checks pass)."""
    subscription = flight.subscribe()  # its first message is the latest one
    status: FlightStatus | None = None
    try:
        async with asyncio.timeout(SETTLE_TIMEOUT_S):
            while status is None or not tracked_at(status, positions):
                status = await subscription.next()
    except (TimeoutError, SubscriptionEndedError):
        pass  # the reply says it is not tracked
    finally:
        flight.unsubscribe(subscription)
    tracked = status is not None and tracked_at(status, positions)
    blocked = status.arm_blocked_by if status is not None else "no telemetry"
    return {"tracked": tracked, "arm_blocked_by": blocked}
