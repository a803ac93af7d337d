"""Landing and abort never free-fall: every phase bounds the descent (sim/truth.py counts
the fastest descent of any body above 0.2 m, on the plant's own velocities)."""

from __future__ import annotations

import pytest

from supervisor.app.config import Config, load_config
from supervisor.simulate.closed_loop import run_scenario
from supervisor.simulate.scenarios import Scenario, Step
from tests.conftest import CONFIGS

MAX_DESCENT_MPS = 0.5


@pytest.fixture(scope="module")
def sim_config() -> Config:
    return load_config(CONFIGS / "sim.toml")


@pytest.mark.slow
@pytest.mark.parametrize("ending", ["land", "abort"])
@pytest.mark.parametrize("height_m", [1.0, 1.6])
def test_a_landing_or_abort_from_a_hover_descends_at_most_half_a_metre_per_second(
    sim_config: Config, ending: str, height_m: float
) -> None:
    steps = [Step(action="takeoff"), Step(action="hover", hold_s=1.0)]
    if height_m != 1.0:
        steps.append(Step(bar_position=[0.0, 0.0, height_m], hold_s=0.5))
    steps.append(Step(action=ending))  # type: ignore[arg-type]
    scenario = Scenario(name=f"{ending}-from-{height_m}", start="ground", step=steps)
    result = run_scenario(sim_config, scenario, seed=3)
    assert result.completed and result.final_mode == "disarmed", result.messages
    assert result.truth.max_descent_mps <= MAX_DESCENT_MPS, result.truth
    assert result.truth.max_tilt_deg < 30.0
