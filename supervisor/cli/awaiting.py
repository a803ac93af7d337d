"""``--wait``: poll ``GET /api/status`` until the request's outcome is known
(``supervisor.flight.outcomes`` decides)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from supervisor.flight.outcomes import Goal, Outcome, Staleness, judge

if TYPE_CHECKING:  # parsed only once an answer comes (the client starts without pydantic)
    from supervisor.flight.status import Status

POLL_INTERVAL_S = 0.2


def await_goal(
    goal: Goal,
    fetch_status: Callable[[], Status],
    sent_at_s: float,
    timeout_s: float,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> Outcome:
    """Poll ``fetch_status`` until ``goal`` decides or ``timeout_s`` has passed since the
    request was sent (at ``sent_at_s`` on ``clock``). ``fetch_status`` raises when the
    service cannot be reached (the caller says so)."""
    staleness = Staleness()
    while True:
        status = fetch_status()
        now_s = clock()
        stale_for_s = staleness.stale_for_s(status, now_s)
        outcome = judge(goal, status, now_s - sent_at_s, stale_for_s, timeout_s)
        if outcome is not None:
            return outcome
        sleep(POLL_INTERVAL_S)
