"""The terminal client against the API on loopback (the CLI runs in a worker thread, as it
would in its own process)."""

from __future__ import annotations

import asyncio
import json

import pytest

from api.server import TlsFiles
from supervisor.cli.main import main
from supervisor.cli.output import format_status
from supervisor.flight.modes import Mode
from tests.api.conftest import TOKEN, ApiUnderTest, serve_api


async def cli(api: ApiUnderTest, *args: str, token: str | None = TOKEN) -> int:
    options = ["--url", api.url] + (["--token", token] if token else [])
    return await asyncio.to_thread(main, [*args, *options])


async def test_status_prints_a_summary(
    api: ApiUnderTest, capsys: pytest.CaptureFixture[str]
) -> None:
    assert await cli(api, "status") == 0
    out = capsys.readouterr().out
    assert "mode disarmed" in out and "controller centralized" in out and "uav2" in out


async def test_commands_change_the_service(
    api: ApiUnderTest, capsys: pytest.CaptureFixture[str]
) -> None:
    assert await cli(api, "arm") == 0
    assert api.core.modes.mode is Mode.ARMED
    assert await cli(api, "mode", "decentralized") == 0
    assert api.core.controller == "decentralized"
    assert await cli(api, "setpoint", "0.5", "0", "1", "--yaw-deg", "20", "--hold-s", "3") == 0
    assert await cli(api, "setpoint", "--json") == 0
    listed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert listed["queued"][0]["bar_position"] == [0.5, 0.0, 1.0]
    assert listed["queued"][0]["hold_s"] == 3.0
    assert await cli(api, "setpoint", "--clear") == 0
    assert api.core.queue.queued == []
    assert await cli(api, "kill", "--confirm") == 0
    assert api.core.modes.mode.value == "killed"


async def test_refusals_exit_1_with_the_reason(
    api: ApiUnderTest, capsys: pytest.CaptureFixture[str]
) -> None:
    assert await cli(api, "takeoff") == 1
    assert "not allowed in mode 'disarmed'" in capsys.readouterr().err
    assert await cli(api, "setpoint", "0", "0", "2.9") == 1
    assert "outside the arena" in capsys.readouterr().err
    assert await cli(api, "setpoint", "0", "0", "1.5", "--theta-l-deg", "86") == 1
    refused = capsys.readouterr().err
    assert "θ_l 86.0° exceeds the maximum 75.0° by 11.0°" in refused
    assert "UAV 1's equilibrium thrust 30.4 N is above the 26.0 N limit" in refused
    assert "UAV 2's equilibrium tilt 64.4° is above the 45.0° abort tilt" in refused
    assert await cli(api, "arm", token="not-the-token") == 1
    wrong = capsys.readouterr().err
    assert "401" in wrong and "not this service's" in wrong and "API token" in wrong
    assert api.core.modes.mode is Mode.DISARMED


async def test_a_missing_token_is_a_set_up_error_saying_where_the_token_is(
    api: ApiUnderTest, capsys: pytest.CaptureFixture[str]
) -> None:
    assert await cli(api, "arm", token=None) == 2
    said = capsys.readouterr().err
    assert "export UAVBAR_TOKEN" in said and "'API token'" in said, said
    assert api.core.modes.mode is Mode.DISARMED


async def test_an_unreachable_service_exits_3(capsys: pytest.CaptureFixture[str]) -> None:
    status = await asyncio.to_thread(main, ["status", "--url", "http://127.0.0.1:9"])
    assert status == 3
    assert "cannot reach" in capsys.readouterr().err


def test_status_shows_the_latest_safety_notices() -> None:
    notices = [{"age_s": 70.0 - k, "message": f"swing: {k}"} for k in range(5)]
    lines = format_status({"mode": "hover", "notices": notices}).splitlines()
    assert lines[-3:] == [
        "notice (68 s ago): swing: 2",
        "notice (67 s ago): swing: 3",
        "notice (66 s ago): swing: 4",
    ]
    assert not [line for line in format_status({"mode": "hover"}).splitlines() if "notice" in line]


async def test_status_over_https_trusts_the_certificate_it_is_given(
    certificate: TlsFiles, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A lab's self-signed certificate: trusted when named (``--cafile``, or
    ``UAVBAR_CA_FILE``), else refused in one line that says how to name it."""
    monkeypatch.delenv("UAVBAR_CA_FILE", raising=False)
    async with serve_api(tls=certificate) as api:
        named = await cli(api, "status", "--cafile", str(certificate.cert_file))
        assert named == 0 and capsys.readouterr().out.startswith("mode disarmed")
        assert await cli(api, "status") == 3
        err = capsys.readouterr().err
        assert "certificate verify failed" in err and "--cafile" in err, err
        assert "Traceback" not in err
        monkeypatch.setenv("UAVBAR_CA_FILE", str(certificate.cert_file))
        assert await cli(api, "arm") == 0
