"""The world's stall log (sim/stalls.py)."""

from __future__ import annotations

from sim.stalls import StallLog


def test_only_delays_beyond_the_threshold_are_stalls() -> None:
    log = StallLog(threshold_s=0.05)
    assert not log.observe(0.049, 1.0)
    assert log.view(2.0) == {"count": 0, "worst_ms": 0.0, "last_ms": 0.0, "last_age_s": None}
    assert log.observe(0.2, 3.0) and log.observe(0.08, 5.0)
    assert log.view(6.0) == {"count": 2, "worst_ms": 200.0, "last_ms": 80.0, "last_age_s": 1.0}
