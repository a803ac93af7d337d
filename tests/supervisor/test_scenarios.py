"""Scenario files: the shipped ones load, bad ones are refused naming the key."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from sim.loads import ExternalLoad
from supervisor.app.config import ConfigError, load_config
from supervisor.app.config_files import CONFIG_DIR as CONFIGS
from supervisor.app.config_files import shipped_scenarios
from supervisor.cli.main import main
from supervisor.simulate.closed_loop import run_scenario
from supervisor.simulate.scenarios import Step, check_setpoints, load_scenario, scenario_config


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
    paths = load_scenario("paths")
    loop = paths.step[2].waypoints()
    assert len(loop) == 8 and loop[-1].bar_position_m == (1.6, 0.0, 1.2)
    assert paths.step[2].speed_mps == 2.0 and paths.step[2].accel_mps2 == 2.0


def test_a_path_step_gives_each_point_its_yaw() -> None:
    step = Step(path=[[1, 0, 1], [1, 1, 1]], speed_mps=1, accel_mps2=1, bar_yaw_deg=[0, 90])
    assert [w.bar_yaw_rad for w in step.waypoints()] == pytest.approx([0.0, math.pi / 2])
    one = Step(path=[[1, 0, 1], [1, 1, 1]], speed_mps=1, accel_mps2=1, bar_yaw_deg=45)
    assert [w.bar_yaw_rad for w in one.waypoints()] == pytest.approx([math.pi / 4] * 2)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ('name = "x"\nstart = "hover"\n[[step]]\nbar_positon = [0, 0, 1]\n', "bar_positon"),
        ('name = "x"\nstart = "orbit"\n[[step]]\naction = "land"\n', "start"),
        ('name = "x"\nstart = "hover"\n[[step]]\nhold_s = 3\n', "exactly one of .* has none"),
        (
            'name = "x"\nstart = "hover"\n[[step]]\naction = "land"\nbar_position = [0, 0, 1]\n',
            "has action and bar_position",
        ),
        (
            'name = "x"\nstart = "hover"\n[[step]]\npath = [[1, 0, 1]]\nspeed_mps = 1\n',
            "needs speed_mps and accel_mps2",
        ),
        (
            'name = "x"\nstart = "hover"\n[[step]]\npath = [[1, 0, 1]]\nspeed_mps = 1\n'
            "accel_mps2 = 1\nbar_yaw_deg = [0, 90]\n",
            r"one per point of the path \(1\), got 2",
        ),
        (
            'name = "x"\nstart = "hover"\n[[step]]\nbar_position = [1, 0, 1]\nspeed_mps = 1\n',
            "belong to a 'path' step",
        ),
        ('name = "x"\nstart = "hover"\n[[step]]\npath = []\nspeed_mps = 1\n', "path"),
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


def test_the_shipped_scenarios_fit_the_shipped_setups() -> None:
    for setup in ("sim", "kth_sml"):
        config = load_config(CONFIGS / f"{setup}.toml")
        for name in shipped_scenarios():
            check_setpoints(load_scenario(name), config)


STEEP = 'name = "steep"\nstart = "hover"\n[[step]]\nbar_position = [0, 0, 1.5]\ntheta_l_deg = 86\n'


def test_a_scenario_with_a_setpoint_no_vehicle_can_hold_is_refused_before_it_flies(
    tmp_path: Path,
) -> None:
    path = tmp_path / "steep.toml"
    path.write_text(STEEP)
    config = load_config(CONFIGS / "sim.toml")
    refusal = r"step 1: .*θ_l 86\.0° exceeds the maximum 75\.0° by 11\.0°"
    with pytest.raises(ConfigError, match=refusal):
        run_scenario(config, load_scenario(str(path)))


def test_a_path_step_is_checked_at_its_own_theta_l_before_it_flies(tmp_path: Path) -> None:
    path = tmp_path / "steep_path.toml"
    path.write_text(
        'name = "steep path"\nstart = "hover"\n[[step]]\npath = [[0.5, 0, 1.2], [0.5, 0.5, 1.2]]\n'
        "speed_mps = 1\naccel_mps2 = 1\ntheta_l_deg = 86\n"
    )
    refusal = r"step 1: .*waypoint 0: θ_l 86\.0° exceeds the maximum 75\.0°"
    with pytest.raises(ConfigError, match=refusal):
        run_scenario(load_config(CONFIGS / "sim.toml"), load_scenario(str(path)))


def test_simulate_refuses_a_scenario_beyond_the_setup_s_thrust_naming_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The paper's sequence on vehicles whose thrust limit leaves no room to hover: exit 2,
    the step and the bound named, nothing flown."""
    status = main(["simulate", "--scenario", "paper", "--set", "mpc.thrust_max_n=14"])
    assert status == 2
    err = capsys.readouterr().err
    assert "scenario paper, step 1" in err
    assert "equilibrium thrust 13.3 N is above the 14.0 N limit less its 10 % margin" in err


def test_a_scenario_s_control_table_is_set_over_the_setup_s(tmp_path: Path) -> None:
    path = tmp_path / "slow.toml"
    path.write_text(
        'name = "slow"\nstart = "hover"\n[control.flight_rates]\nposition_mps = 0.1\n'
        "[[step]]\nbar_position = [0.2, 0, 1]\n"
    )
    config = load_config(CONFIGS / "sim.toml", ["control.flight_rates.yaw_deg_s=15"])
    flown = scenario_config(config, load_scenario(str(path)))
    assert flown.control.flight_rates.position_mps == 0.1  # the scenario's
    assert flown.control.flight_rates.yaw_deg_s == 15.0  # the setup's, kept
    assert flown.control.takeoff_rates == config.control.takeoff_rates
    assert flown.mpc == config.mpc and flown.system == config.system


def test_a_scenario_s_control_keys_are_validated(tmp_path: Path) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(
        'name = "x"\nstart = "hover"\n[control]\nrate_lookahed = 2\n[[step]]\naction = "land"\n'
    )
    with pytest.raises(ConfigError, match=r"control\.rate_lookahed: Extra inputs"):
        load_scenario(str(path))
    path.write_text(
        'name = "x"\nstart = "hover"\n[control]\ntilt_margin_deg = 50\n[[step]]\naction = "land"\n'
    )
    with pytest.raises(ConfigError, match=r"below safety\.max_tilt_deg"):
        scenario_config(load_config(CONFIGS / "sim.toml"), load_scenario(str(path)))


def test_a_scenario_s_loads_are_external_loads_on_the_plant(tmp_path: Path) -> None:
    path = tmp_path / "gusty.toml"
    path.write_text(
        'name = "gusty"\nstart = "hover"\n'
        '[[load]]\nbody = "bar"\nforce_n = [1, 0, 0]\nstart_s = 2\n'
        '[[load]]\nbody = "uav2"\nforce_n = [0, 3, 0]\ntorque_nm = [0, 0, 0.1]\nstart_s = 1\n'
        'duration_s = 0.5\nprofile = "gust"\n'
        '[[step]]\naction = "hover"\nhold_s = 3\n'
    )
    loads = [load.external_load() for load in load_scenario(str(path)).load]
    assert loads == [
        ExternalLoad("bar", (1.0, 0.0, 0.0), (0.0, 0.0, 0.0), 2.0, None, "steady"),
        ExternalLoad("uav2", (0.0, 3.0, 0.0), (0.0, 0.0, 0.1), 1.0, 0.5, "gust"),
    ]


@pytest.mark.parametrize(
    ("load", "message"),
    [
        ('body = "uav9"\nforce_n = [1, 0, 0]', "load.0.body"),
        ('body = "bar"\nforce_n = [1, 0]', "load.0.force_n"),
        ('body = "bar"\nforce_n = [1, 0, 0]\nprofile = "gust"', "a gust needs a duration_s"),
        ('body = "bar"\nforce_n = [1, 0, 0]\nduration_s = 0', "load.0.duration_s"),
    ],
)
def test_bad_loads_are_refused_naming_the_key(tmp_path: Path, load: str, message: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(f'name = "x"\nstart = "hover"\n[[load]]\n{load}\n[[step]]\naction = "land"\n')
    with pytest.raises(ConfigError, match=message):
        load_scenario(str(path))


def test_a_load_on_a_body_the_setup_has_not_is_refused_before_it_flies(tmp_path: Path) -> None:
    """A scenario may name any UAV; flown on a setup without it, it is refused naming the
    load and the setup's bodies."""
    path = tmp_path / "third.toml"
    path.write_text(
        'name = "third"\nstart = "hover"\n[[load]]\nbody = "uav3"\nforce_n = [1, 0, 0]\n'
        '[[step]]\naction = "land"\n'
    )
    scenario = load_scenario(str(path))
    check_setpoints(scenario, load_config(CONFIGS / "sim_tri.toml"))  # it has a UAV 3
    with pytest.raises(ConfigError, match=r"load 1: setup sim has no body 'uav3' \(its bodies"):
        check_setpoints(scenario, load_config(CONFIGS / "sim.toml"))
