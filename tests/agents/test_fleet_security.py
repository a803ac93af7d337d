"""A fleet over TLS under access control, between real Zenoh sessions on loopback: the
ground station commands an agent; another agent can neither command it nor speak for its
vehicle; a computer holding another authority's certificate does not join at all."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from supervisor.agents import keys
from supervisor.agents.certificates import issue
from supervisor.agents.fleet_security import GROUND, FleetSecurity, agent_identity, unprotected
from supervisor.agents.zenoh_session import open_session
from supervisor.cli.main import main
from tests.mocap.test_recording import free_port

FLEET = "lab"
CONNECT_TIMEOUT_S = 20.0  # a TLS handshake between Python processes on a loaded machine


def test_only_tls_or_loopback_carries_the_fleet() -> None:
    assert unprotected(["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:1"]) == []
    assert unprotected(["tls/10.0.0.2:7447", "tls/drone-3.lab:7447"]) == []
    clear = ["tcp/10.0.0.2:7447", "udp/192.168.1.4:7447", "tcp/drone-3.lab:7447"]
    assert unprotected(clear) == clear


def _wait_until(done: Callable[[], bool], what: str) -> None:
    deadline = time.monotonic() + CONNECT_TIMEOUT_S
    while not done():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


class Agent1:
    """Agent 1's session (listening over TLS) and what reached its queryable and tick
    subscriber."""

    def __init__(self, session: zenoh.Session) -> None:
        self.session = session
        self.commands: list[bytes] = []
        self.ticks: list[tuple[str, bytes]] = []
        self._declared = [
            session.declare_queryable(keys.command_key(FLEET, 1), self._on_query),
            session.declare_subscriber(keys.all_ticks_key(FLEET), self._on_tick),
        ]

    def _on_query(self, query: zenoh.Query) -> None:
        self.commands.append(query.payload.to_bytes() if query.payload else b"")
        query.reply(query.key_expr, b"done")

    def _on_tick(self, sample: zenoh.Sample) -> None:
        self.ticks.append((str(sample.key_expr), sample.payload.to_bytes()))


def _security(folder: Path, identity: str) -> FleetSecurity:
    return FleetSecurity(folder, identity, FLEET, n_vehicles=2)


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[tuple[Path, str, Agent1]]:
    """The fleet's certificates, and agent 1 listening on a loopback TLS endpoint."""
    issue(tmp_path, FLEET, n_vehicles=2, days=1)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    session = open_session([endpoint], [], _security(tmp_path, agent_identity(1)))
    try:
        yield tmp_path, endpoint, Agent1(session)
    finally:
        session.close()  # type: ignore[no-untyped-call]


def _command(session: zenoh.Session, payload: bytes) -> list[bytes]:
    replies = session.get(keys.command_key(FLEET, 1), payload=payload, timeout=2.0)
    return [reply.ok.payload.to_bytes() for reply in replies if reply.ok is not None]


def test_the_ground_station_commands_an_agent(fleet: tuple[Path, str, Agent1]) -> None:
    folder, endpoint, agent = fleet
    ground = open_session([], [endpoint], _security(folder, GROUND))
    try:
        _wait_until(lambda: _command(ground, b"arm") == [b"done"], "the ground's command")
        assert agent.commands and set(agent.commands) == {b"arm"}
    finally:
        ground.close()  # type: ignore[no-untyped-call]


def test_another_agent_neither_commands_nor_speaks_for_agent_1(
    fleet: tuple[Path, str, Agent1],
) -> None:
    folder, endpoint, agent = fleet
    agent_2 = open_session([], [endpoint], _security(folder, agent_identity(2)))
    try:
        own_tick = (keys.tick_key(FLEET, 2), b"agent 2's own")

        def heard_its_own() -> bool:
            agent_2.put(*own_tick)
            return own_tick in agent.ticks

        _wait_until(heard_its_own, "agent 2's own tick")  # joined, and allowed its own keys
        assert _command(agent_2, b"disarm") == []
        agent_2.put(keys.tick_key(FLEET, 1), b"forged")
        agent.ticks.clear()
        _wait_until(heard_its_own, "agent 2's own tick again")  # in order, after the forgery
        assert agent.commands == []
        assert all(key == own_tick[0] for key, _ in agent.ticks), agent.ticks
    finally:
        agent_2.close()  # type: ignore[no-untyped-call]


def test_a_certificate_of_another_authority_does_not_join(
    fleet: tuple[Path, str, Agent1], tmp_path_factory: pytest.TempPathFactory
) -> None:
    folder, endpoint, agent = fleet
    elsewhere = tmp_path_factory.mktemp("other-fleet")
    issue(elsewhere, FLEET, n_vehicles=2, days=1)  # the same names, another authority
    stranger = open_session([], [endpoint], _security(elsewhere, GROUND))
    ground = open_session([], [endpoint], _security(folder, GROUND))
    try:
        # The real ground station, started after the stranger, joins and is answered ...
        _wait_until(lambda: _command(ground, b"arm") == [b"done"], "ground")
        # ... while the stranger, trying since before, has reached nobody.
        assert stranger.info.peers_zid() == []
        assert _command(stranger, b"kill") == []
        assert b"kill" not in agent.commands
    finally:
        stranger.close()  # type: ignore[no-untyped-call]
        ground.close()  # type: ignore[no-untyped-call]


def test_an_agent_refuses_to_join_in_clear_beyond_loopback(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("UAVBAR_TOKEN", "agent-token-0123456789")
    command = ["agent", "--vehicle", "1", "--connect", "tcp/10.0.0.2:7447"]
    assert main(command) == 2  # refused before anything starts
    said = capsys.readouterr().err
    assert "--listen/--connect: tcp/10.0.0.2:7447: beyond loopback" in said, said
