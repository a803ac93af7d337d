"""The tick core's operator checks (the flights themselves: test_simulation, test_service)."""

from __future__ import annotations

import time

import numpy as np

from controllers.equilibria import Reference, bar_equilibrium
from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import Event, Mode
from tests.conftest import CONFIGS

CONFIG = load_config(CONFIGS / "sim.toml")


def test_take_off_needs_every_body_measured_and_fresh() -> None:
    x = bar_equilibrium(CONFIG.system.to_params(), Reference((0.0, 0.0, 1.0))).x
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    nan = x.copy()
    nan[12:15] = np.nan  # UAV 1 never seen
    for estimate in (Estimate(nan, 0.01, ("uav1",)), Estimate(x, 0.5, ("bar",))):
        core = flight_core_from_config(CONFIG, clock=time.perf_counter)
        core.tick(0.0, estimate)
        core.request(Event.ARM, 0.0)
        refused = core.request(Event.TAKEOFF, 0.02)
        assert not refused.accepted and "motion capture" in refused.reason
        assert core.modes.mode is Mode.ARMED
    # One dropped frame (the newest sample of a body untracked, 20 ms old) is no reason.
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.tick(0.0, Estimate(x, 0.02, ("uav2",)))
    core.request(Event.ARM, 0.0)
    assert core.request(Event.TAKEOFF, 0.02).accepted
