"""Scenario files: the shipped ones load, bad ones are refused naming the key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from supervisor.app.config import ConfigError
from supervisor.app.config_files import shipped_scenarios
from supervisor.simulate.scenarios import load_scenario


def test_shipped_scenarios_load() -> None:
    assert {"paper", "takeoff-land"} <= set(shipped_scenarios())
    paper = load_scenario("paper")
    assert paper.start == "hover" and len(paper.step) == 5
    second = paper.step[1].setpoint()
    assert second.bar_position_m == (1.0, 0.0, 1.0)
    assert second.uav_yaw_rad == pytest.approx((math.pi, math.pi / 2))
    assert paper.step[3].setpoint().theta_l_rad == pytest.approx(math.pi / 4)
    takeoff = load_scenario("takeoff-land")
    assert [s.action for s in takeoff.step] == ["takeoff", "hover", "land"]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('name = "x"\nstart = "hover"\n[[step]]\nbar_positon = [0, 0, 1]\n', "bar_positon"),
        ('name = "x"\nstart = "orbit"\n[[step]]\naction = "land"\n', "start"),
        ('name = "x"\nstart = "hover"\n[[step]]\nhold_s = 3\n', "either 'action'"),
        (
            'name = "x"\nstart = "hover"\n[[step]]\naction = "land"\nbar_position = [0, 0, 1]\n',
            "not both",
        ),
        ('name = "x"\nstart = "hover"\n[[step]]\naction = "takeoff"\n', "cannot take off"),
        ('name = "x"\nstart = "hover"\nstep = []\n', "step"),
        ('name = "x"\nstart = "hover"\n[[step]]\nbar_position = [0, 0]\n', "bar_position"),
        ("name = ", "not valid TOML"),
    ],
)
def test_bad_scenarios_are_refused_naming_the_problem(
    tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_scenario(str(path))
