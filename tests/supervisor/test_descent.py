"""Landing and abort never free-fall: every phase bounds the descent (sim/truth.py counts
the fastest descent of any body above 0.2 m, on the plant's own velocities)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from geometry.formation import FormationLayout
from geometry.state import payload_position
from sim.truth import TruthStats
from supervisor.app.config import Config, load_config
from supervisor.flight.core import TickResult
from supervisor.flight.modes import Event, Mode
from supervisor.simulate.closed_loop import TICK_S, ClosedLoop, run_scenario
from supervisor.simulate.scenarios import Scenario, Step
from tests.conftest import CONFIGS

MAX_DESCENT_MPS = 0.5


@pytest.fixture(scope="module")
def sim_config() -> Config:
    return load_config(CONFIGS / "sim.toml")


# From the take-off's 1 m hover both endings are flown by test_simulation.py's
# flights-in-a-row, with the same bound; here from higher up.
@pytest.mark.slow
@pytest.mark.parametrize("ending", ["land", "abort"])
def test_a_landing_or_abort_from_a_hover_descends_at_most_half_a_metre_per_second(
    sim_config: Config, ending: str
) -> None:
    steps = [
        Step(action="takeoff"),
        Step(action="hover", hold_s=1.0),
        Step(bar_position=[0.0, 0.0, 1.6], hold_s=0.5),
        Step(action=ending),  # type: ignore[arg-type]
    ]
    scenario = Scenario(name=f"{ending}-from-1.6", start="ground", step=steps)
    result = run_scenario(sim_config, scenario, seed=3)
    assert result.completed and result.final_mode == "disarmed", result.messages
    assert result.truth.max_descent_mps <= MAX_DESCENT_MPS, result.truth
    assert result.truth.max_tilt_deg < 30.0


def flown_until_disarmed(
    config: Config, interrupt: Callable[[TickResult], Event | None], limit_s: float = 90.0
) -> tuple[TruthStats, str]:
    """Arm and take off from the resting pose on the closed-loop simulator, and land once
    hovering; on the first tick for which ``interrupt`` names an event, request it. Until
    disarmed after that: the truth and the phases flown."""
    loop = ClosedLoop(config, seed=3)
    loop.plant.place_resting()
    truth = TruthStats(loop.resting_heights()[0])
    loop.advance_plant(0.2)  # the filters converge on a still system first
    core = loop.core
    interrupted, phases = False, ["ground"]
    while loop.now_s < limit_s:
        result = loop.decide()
        loop.apply(result)
        loop.driver.finish(result)
        truth.update(loop.plant, core.modes.mode.airborne)
        if phases[-1] != result.phase.value:
            phases.append(result.phase.value)
        if core.modes.mode is Mode.DISARMED and not interrupted:
            for request in (Event.ARM, Event.TAKEOFF):
                assert core.request(request, loop.now_s).accepted
        elif not interrupted and (event := interrupt(result)) is not None:
            assert core.request(event, loop.now_s).accepted
            interrupted = True
        elif core.modes.mode is Mode.HOVER:
            assert core.request(Event.LAND, loop.now_s).accepted
        if interrupted and core.modes.mode is Mode.DISARMED:
            return truth, " ".join(phases)
        loop.advance_plant(loop.now_s + TICK_S)
    raise AssertionError(f"not disarmed within {limit_s} s: {' '.join(phases)}")


def heights(result: TickResult) -> tuple[float, float]:
    """The estimated bar's height and the lower UAV's [m]."""
    x = np.asarray(result.record.state)
    layout = FormationLayout(len(result.commands))
    lowest = min(float(layout.uav_position(x, i)[2]) for i in layout.vehicles)
    return float(payload_position(x)[2]), lowest


@pytest.mark.slow
@pytest.mark.parametrize(
    ("when", "phase", "above_m"),
    [("climbing", "climb", 0.3), ("lifting", "lift", 0.5), ("landing", "lower", 0.6)],
)
def test_an_abort_in_a_take_off_or_a_landing_descends_at_most_half_a_metre_per_second(
    sim_config: Config, when: str, phase: str, above_m: float
) -> None:
    """An abort while the UAVs climb to tension the cables, while they lift the bar, and
    while a landing lowers it: each ends on the ground, disarmed, never descending faster
    than 0.5 m/s above 0.2 m, nothing tilted beyond 30°."""

    def abort_then(result: TickResult) -> Event | None:
        bar_z, uav_z = heights(result)
        height = uav_z if phase == "climb" else bar_z
        right_time = result.phase.value == phase and height > above_m
        return Event.ABORT if right_time else None

    truth, phases = flown_until_disarmed(sim_config, abort_then)
    assert phase in phases.split(), phases
    assert truth.max_descent_mps <= MAX_DESCENT_MPS, (truth, phases)
    assert truth.max_tilt_deg < 30.0, (truth, phases)
