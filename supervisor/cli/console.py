"""Terminal output of long commands: a progress bar on stderr and plain-text summaries."""

from __future__ import annotations

import sys
from collections.abc import Mapping
from types import TracebackType
from typing import Any

from tqdm import tqdm


class SimulationProgress:
    """A progress bar in simulated seconds, shown only when stderr is a terminal."""

    def __init__(self, expected_s: float, enabled: bool = True) -> None:
        self._bar: tqdm[Any] | None = None
        if enabled and sys.stderr.isatty():
            self._bar = tqdm(
                total=round(expected_s), unit="sim s", desc="simulating", file=sys.stderr
            )
        self._shown_s = 0

    def update(self, sim_time_s: float) -> None:
        """Report that the simulation has reached ``sim_time_s``."""
        if self._bar is None:
            return
        whole = int(sim_time_s)
        if whole > self._shown_s:
            if whole > (self._bar.total or 0):
                self._bar.total = whole
            self._bar.update(whole - self._shown_s)
            self._shown_s = whole

    def __enter__(self) -> SimulationProgress:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if self._bar is not None:
            self._bar.close()


def _format_value(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, Mapping):
        return ", ".join(f"{k} {_format_value(v)}" for k, v in value.items())
    if isinstance(value, list):
        return "; ".join(str(v) for v in value) or "-"
    return str(value)


def format_summary(summary: Mapping[str, Any]) -> str:
    """One ``key: value`` line per entry, aligned."""
    width = max(len(key) for key in summary)
    return "\n".join(f"{key:<{width}}  {_format_value(value)}" for key, value in summary.items())
