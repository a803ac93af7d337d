"""The simulated world's own stalls: moments its process did not run (a busy computer),
during which its mocap frames and its vehicles paused with it. A mocap gap the supervisor
sees at such a moment is this computer's, not the lab's; the operator is told so."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

STALL_S = 0.05  # five mocap frames late: more than scheduling jitter


@dataclass
class StallLog:
    """Stalls counted from how far behind the wall clock the world found itself."""

    threshold_s: float = STALL_S
    count: int = 0
    worst_s: float = 0.0
    last_at_s: float | None = None  # world time of the newest stall
    last_s: float = 0.0

    def observe(self, behind_s: float, at_s: float) -> bool:
        """The world is ``behind_s`` behind at world time ``at_s``; True when that is a
        stall (counted)."""
        if behind_s < self.threshold_s:
            return False
        self.count += 1
        self.worst_s = max(self.worst_s, behind_s)
        self.last_at_s, self.last_s = at_s, behind_s
        return True

    def view(self, now_s: float) -> dict[str, Any]:
        """For the API: how many, the worst and the newest (its length and how long ago)."""
        ago = None if self.last_at_s is None else round(now_s - self.last_at_s, 3)
        return {
            "count": self.count,
            "worst_ms": round(self.worst_s * 1e3, 1),
            "last_ms": round(self.last_s * 1e3, 1),
            "last_age_s": ago,
        }
