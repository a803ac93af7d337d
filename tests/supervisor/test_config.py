"""Configuration: validated, frozen, every error names its key; CLI exit status 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from pydantic import ValidationError

from supervisor.app.config import ConfigError, load_config
from supervisor.app.config_files import parse_override, read_setup
from supervisor.cli.main import main
from tests.conftest import CONFIGS

KTH = CONFIGS / "kth_sml.toml"


def test_lab_config_holds_the_papers_values() -> None:
    config = load_config(KTH)
    params = config.system.to_params()
    assert params.uavs[0].mass_kg == params.uavs[1].mass_kg == 1.15
    assert params.uavs[0].inertia_kgm2 == (0.0348, 0.0459, 0.0977)
    assert (params.payload.mass_kg, params.bar_arms_m) == (0.39, (0.705, 0.765))
    assert params.payload.perpendicular_inertia_kgm2 == 0.0706
    assert config.mpc.horizon == 30 and config.mpc.dt_s == 0.02
    assert config.mpc.torque_max_nm == 1.0 and config.mpc.thrust_min_n > 0.0
    weights = config.mpc.centralized.to_weights(2)
    assert len(weights.q_diag) == params.layout.n_states
    assert len(weights.r_diag) == params.layout.n_inputs
    assert weights.q_diag[:12] == (50, 50, 50, 50, 50, 50, 10, 10, 10, 1, 1, 5)
    assert weights.terminal_scale == 100
    decentralized = config.mpc.decentralized.to_weights()
    assert len(decentralized.q_diag) == 18 and decentralized.terminal_scale == 50
    assert [hi - lo for lo, hi in zip(config.arena.min_m, config.arena.max_m, strict=True)] == [
        6,
        6,
        3,
    ]


def test_sim_config_extends_the_lab() -> None:
    assert load_config(CONFIGS / "sim.toml").system == load_config(KTH).system


def test_config_is_frozen() -> None:
    config = load_config(KTH)
    with pytest.raises(ValidationError):
        config.system.bar_mass = 1.0


def test_overrides_are_toml_literals() -> None:
    config = load_config(KTH, ["system.cable_length=[0.9, 1.1]", "mpc.horizon=20", "name='x'"])
    assert config.system.to_params().cable_lengths_m == (0.9, 1.1)
    assert config.mpc.horizon == 20 and config.name == "x"
    assert parse_override("a.b = true") == (["a", "b"], True)


@pytest.mark.parametrize(
    ("override", "key", "reason"),
    [
        ("system.bar_mas=1.0", "system.bar_mas", "unknown key"),
        ("system.bar_mass=-0.3", "system.bar_mass", "greater than 0"),
        ("system.uav_mass='heavy'", "system.uav_mass", "valid number"),
        ("system.bar_d1=0.0;system.bar_d2=0.0", "system", "bar_d1 + bar_d2"),
        ("system.bar_d2=-0.1", "system.bar_d2", "greater than or equal to 0"),
        ("system.uav_inertia=[1.0, 2.0]", "system.uav_inertia", "at least 3"),
        ("system.cable_length=[1.0, 1.0, 1.0]", "system", "one value or 2 (one per UAV)"),
        ("system.uav_inertia=[[1, 1, 1]]", "system.uav_inertia", "at least 2"),
        (
            "system.payload={mass=1, inertia=[1, 1, 1], attachments=[[1, 0, 0], [-1, 0, 0]]}",
            "system",
            "the bar (bar_mass, bar_d1, bar_d2, bar_inertia) or [system.payload], not both",
        ),
        ("mpc.thrust_min_n=30.0", "mpc", "thrust_min_n"),
        ("system.gravity=nan", "system.gravity", "finite"),
        ("arena.min_m=[0, 0, 5]", "arena", "below"),
        ("sim.mocap.rate_hz=0", "sim.mocap.rate_hz", "greater than 0"),
        ("sim.mocap.burst_frames=[9, 3]", "sim.mocap", "min <= max"),
        ("sim.uav_mass_scale=[1.0]", "sim.uav_mass_scale", "at least 2"),
        ("mocap.bodies=['bar', 'bar', 'uav2']", "mocap", "distinct"),
        ("mocap.port=70000", "mocap.port", "less than or equal"),
        ("control.max_theta_l_deg=90", "control.max_theta_l_deg", "less than 90"),
        ("control.thrust_margin=0.5", "control.thrust_margin", "less than 0.5"),
        ("control.max_thetal_deg=80", "control.max_thetal_deg", "unknown key"),
        ("control.tilt_margin_deg=50", "(top level)", "below safety.max_tilt_deg"),
        ("safety.max_tilt_deg=0", "safety.max_tilt_deg", "greater than 0"),
        ("safety.slack_in_window_s=20", "safety", "must not exceed slack_window_s"),
        ("control.flight_rates.speed_mps=1", "control.flight_rates.speed_mps", "unknown key"),
        ("control.abort_rates.yaw_deg_s=0", "control.abort_rates.yaw_deg_s", "greater than 0"),
        ("control.rate_lookahead_steps=31", "(top level)", "must not exceed mpc.horizon"),
        ("control.pd.kp=-1", "control.pd.kp", "greater than 0"),
        ("agents.ground_endpoint='127.0.0.1:7447'", "agents.ground_endpoint", "match pattern"),
        ("agents.spawn=false", "agents", "name its port"),
        ("agents.agent_endpoints=['tcp/127.0.0.1:7448']", "(top level)", "one per UAV (2)"),
        ("agents.fleet='a b'", "agents.fleet", "match pattern"),
        ("agents.ground_endpoint='tcp/10.0.0.2:7447'", "agents", "beyond loopback"),
        ("agents.ground_endpoint='tcp/drone-1.lab:7447'", "agents", "beyond loopback"),
        ("agents.ground_endpoint='tls/10.0.0.2:7447'", "agents", "need agents.tls_folder"),
        ("agents.tls_folder='fleet'", "agents", "every endpoint is tls/"),
    ],
)
def test_bad_values_name_their_key(override: str, key: str, reason: str) -> None:
    with pytest.raises(ConfigError) as caught:
        load_config(KTH, override.split(";"))
    message = str(caught.value)
    assert key in message and reason in message


@pytest.mark.parametrize("assignment", ["nokey", "=1", "a..b=1", "a.b=not toml"])
def test_malformed_overrides(assignment: str) -> None:
    with pytest.raises(ConfigError, match="--set"):
        parse_override(assignment)


PLATE = """
extends = "{base}"
[system]
uav_mass = [1.15, 1.2, 1.1]
[system.payload]
mass = 0.6
inertia = [0.042, 0.042, 0.085]
attachments = [[0.75, 0.0, 0.0], [-0.375, 0.65, 0.0], [-0.375, -0.65, 0.0]]
"""


def test_a_plate_on_three_uavs_replaces_the_bar_it_extends(tmp_path: Path) -> None:
    setup = tmp_path / "plate.toml"
    setup.write_text(PLATE.format(base=CONFIGS / "sim.toml"))
    config = load_config(setup)
    params = config.system.to_params()
    assert params.n_vehicles == config.system.n_vehicles == 3
    assert [uav.mass_kg for uav in params.uavs] == [1.15, 1.2, 1.1]
    assert params.cable_lengths_m == (1.0, 1.0, 1.0)  # the lab's one length, for each
    assert params.payload.attachments_m[1] == (-0.375, 0.65, 0.0)
    assert not params.payload.is_bar and config.system.bar_mass is None
    assert config.mpc.horizon == load_config(KTH).mpc.horizon  # the rest of the lab kept
    shown = read_setup(setup).sources
    assert "system.bar_mass" not in shown and shown["system.payload.mass"] == str(setup)


def test_a_bar_extending_a_plate_replaces_the_plate(tmp_path: Path) -> None:
    plate = tmp_path / "plate.toml"
    plate.write_text(PLATE.format(base=CONFIGS / "sim.toml").replace("[1.15, 1.2, 1.1]", "1.15"))
    bar = tmp_path / "bar.toml"
    bar.write_text(
        f'extends = "{plate}"\n[system]\nbar_mass = 0.5\nbar_d1 = 0.5\nbar_d2 = 0.5\n'
        "bar_inertia = 0.04\n"
    )
    params = load_config(bar).system.to_params()
    assert params.n_vehicles == 2 and params.bar_arms_m == (0.5, 0.5)


@pytest.mark.parametrize(
    ("override", "reason"),
    [
        ("system.uav_mass=[1.0, 1.0]", "uav_mass takes one value or 3"),
        ("system.cable_length=[1, 1, 1, 1]", "cable_length takes one value or 3"),
        ("system.payload.attachments=[[0.5, 0, 0]]", "at least 2"),
        ("system.payload.inertia=[[1, 0, 0], [0.5, 1, 0], [0, 0, 1]]", "symmetric"),
        ("system.bar_mass=0.4", "not both"),
    ],
)
def test_a_plate_s_bad_values_are_named(tmp_path: Path, override: str, reason: str) -> None:
    setup = tmp_path / "plate.toml"
    setup.write_text(PLATE.format(base=CONFIGS / "sim.toml"))
    with pytest.raises(ConfigError, match="system") as caught:
        load_config(setup, [override])
    assert reason in str(caught.value)


def test_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "absent.toml")
    broken = tmp_path / "broken.toml"
    broken.write_text("[system\n")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(broken)
    looped = tmp_path / "loop.toml"
    looped.write_text('extends = "loop.toml"\n')
    with pytest.raises(ConfigError, match="loops"):
        load_config(looped)


def test_cli_rejects_bad_config_with_status_2(capsys: pytest.CaptureFixture[str]) -> None:
    status = main(
        ["equilibria", "--theta-l", "30", "--config", str(KTH), "--set", "system.bar_mass=-1"]
    )
    out, err = capsys.readouterr()
    assert status == 2
    assert out == ""  # nothing else ran
    assert "system.bar_mass" in err


@pytest.mark.parametrize(
    ("theta_l", "why"),
    [("-1", "[0, 90)"), ("90", "[0, 90)"), ("120", "[0, 90)"), ("nan", "not a finite number")],
)
def test_cli_rejects_theta_l_outside_range(
    theta_l: str, why: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["equilibria", "--theta-l-deg", theta_l]) == 2
    out, err = capsys.readouterr()
    assert out == "" and why in err and len(err.strip().splitlines()) == 1


def test_cli_equilibria_json(capsys: pytest.CaptureFixture[str]) -> None:
    overrides = [
        "system.uav_mass=1.52",
        "system.bar_mass=0.41",
        "system.bar_d1=0.735",
        "system.bar_d2=0.735",
    ]
    args = ["equilibria", "--theta-l", "45", "--json"]
    for assignment in overrides:
        args += ["--set", assignment]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["theta_f"] == pytest.approx(0.1183, abs=1e-4)
    assert result["theta_l"] == pytest.approx(0.785398, abs=1e-6)
    assert len(result["thrust"]) == 2 and len(result["tension"]) == 2
    (x1, y1, z1), (x2, y2, z2) = result["uav_positions"]
    assert x1 < 0 < x2 and y1 == y2 == 0 and z1 == pytest.approx(z2)


def test_the_foxglove_view_stays_on_loopback_unless_an_interface_is_named() -> None:
    """The Foxglove protocol has no token: an API open to the lab network does not open
    the live view to it as well."""
    section = load_config(CONFIGS / "sim.toml").foxglove
    assert section.bind_host("127.0.0.1") == "127.0.0.1"
    assert section.bind_host("0.0.0.0") == "127.0.0.1"
    assert section.bind_host("192.168.1.4") == "127.0.0.1"
    named = load_config(CONFIGS / "sim.toml", ['foxglove.host="192.168.1.4"']).foxglove
    assert named.bind_host("0.0.0.0") == "192.168.1.4"


def test_the_tick_core_checks_setpoints_against_the_setup_s_bounds() -> None:
    """The API checks with ``Config.setpoint_bounds``, the tick core with what it was built
    from: the same bounds, set keys included."""
    from supervisor.app.assembly import flight_core_from_config

    overrides = ["control.max_theta_l_deg=60", "safety.max_tilt_deg=40", "mpc.thrust_max_n=24"]
    config = load_config(KTH, overrides)
    core = flight_core_from_config(config, clock=lambda: 0.0)
    assert core.setpoint_bounds == config.setpoint_bounds()
    assert core.safety.limits.max_tilt_rad == pytest.approx(math.radians(40.0))
    bounds = config.setpoint_bounds()
    assert bounds.settings.max_theta_l_rad == pytest.approx(math.radians(60.0))
    assert bounds.thrust_band_n == pytest.approx((0.5 + 2.4, 24.0 - 2.4))
    assert bounds.tilt_allowed_rad == pytest.approx(math.radians(30.0))


def test_the_core_settings_come_from_the_control_section() -> None:
    """Every key reaches the tick core, in SI units; a rates table given in part keeps its
    own defaults for the rest (the take-off's gentler acceleration)."""
    from supervisor.app.assembly import core_settings_from_config
    from supervisor.flight.core import CoreSettings

    assert core_settings_from_config(load_config(KTH)) == CoreSettings()  # same defaults
    overrides = [
        "control.takeoff_height_m=0.8",
        "control.reached_yaw_deg=2",
        "control.flight_rates.position_mps=0.5",
        "control.flight_rates.theta_l_deg_s=5",
        "control.takeoff_rates.position_mps=0.2",
        "control.abort_rates.acceleration_mps2=0.6",
        "control.bumpless_ticks=20",
        "control.pd.max_tilt_deg=20",
    ]
    settings = core_settings_from_config(load_config(KTH, overrides))
    assert settings.takeoff_height_m == 0.8
    assert settings.reached_yaw_rad == pytest.approx(math.radians(2.0))
    assert settings.flight_rates.position_mps == 0.5
    assert settings.flight_rates.theta_l_radps == pytest.approx(math.radians(5.0))
    assert settings.flight_rates.acceleration_mps2 == 0.3
    assert (settings.takeoff_rates.position_mps, settings.takeoff_rates.acceleration_mps2) == (
        0.2,
        0.15,
    )
    assert (settings.abort_rates.position_mps, settings.abort_rates.acceleration_mps2) == (
        0.4,
        0.6,
    )
    assert settings.bumpless_ticks == 20
    assert settings.pd_gains.max_tilt_rad == pytest.approx(math.radians(20.0))
