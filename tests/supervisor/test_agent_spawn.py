"""How serve starts its agents: the world's addresses as a lab setup names them, and
endpoints with free ports."""

from __future__ import annotations

from supervisor.app.agent_spawn import agent_command, fleet_endpoints, world_overrides
from supervisor.app.child_entries import Setup
from supervisor.app.config import CONFIG_DIR, load_config

WORLD = {
    "qtm": "127.0.0.1:40001",
    "vehicles": ["127.0.0.1:40002", "127.0.0.1:40003"],
    "link_ports": None,
    "px4_events": "/tmp/events.json.xz",
}


def test_the_worlds_addresses_make_a_lab_setup_of_the_agents() -> None:
    config = load_config(CONFIG_DIR / "sim.toml", world_overrides(WORLD))
    assert not config.sim.embedded
    assert (config.mocap.host, config.mocap.port) == ("127.0.0.1", 40001)
    assert config.vehicles.addresses == WORLD["vehicles"]
    assert config.vehicles.ports == [0, 0] and config.vehicles.bind_host == "127.0.0.1"
    assert config.vehicles.px4_events == WORLD["px4_events"]


def test_an_agents_command_line_is_its_setup_and_its_endpoints() -> None:
    setup = Setup(CONFIG_DIR / "sim.toml", ("mpc.delay_s=0.02",))
    command = agent_command(setup, 2, "tcp/127.0.0.1:7448", ["tcp/127.0.0.1:7447"], WORLD)
    assert command[2:6] == ["supervisor.cli.main", "agent", "--vehicle", "2"]
    assert command[command.index("--listen") + 1] == "tcp/127.0.0.1:7448"
    assert command[command.index("--connect") + 1] == "tcp/127.0.0.1:7447"
    sets = [command[k + 1] for k, word in enumerate(command) if word == "--set"]
    assert sets[0] == "mpc.delay_s=0.02" and "sim.embedded=false" in sets


def test_port_0_becomes_a_free_port_for_every_process_of_the_fleet() -> None:
    config = load_config(CONFIG_DIR / "sim.toml", ["agents.enabled=true"])
    ground, agents = fleet_endpoints(config)
    ports = [int(endpoint.rsplit(":", 1)[1]) for endpoint in (ground, *agents)]
    assert len(agents) == 2 and 0 not in ports and len(set(ports)) == 3
