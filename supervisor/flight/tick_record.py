"""What one control tick did, as the flight log keeps it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class TickRecord:
    """What one control tick did. ``state`` and ``state_ref`` are formation states in the
    paper's order (``geometry.formation``; ``state_ref`` the equilibrium being regulated
    to, i.e. the dashed references of the paper's figures); ``inputs`` (F1, τ1, …, FN, τN)
    [N, N m]; times in ms."""

    t_s: float
    mode: str
    controller: str
    state: list[float]
    state_ref: list[float]
    inputs: list[float]
    plan_status: str
    solve_ms: float
    compute_ms: float
    lateness_ms: float
    mocap_age_ms: float
    extra: dict[str, Any] = field(default_factory=dict)
