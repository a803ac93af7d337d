"""The terminal client against the API on loopback (the CLI runs in a worker thread, as it
would in its own process)."""

from __future__ import annotations

import asyncio
import contextlib
import http.server
import json
import re
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from api.server import TlsFiles
from supervisor.cli.main import main
from supervisor.cli.output import format_status
from supervisor.flight.modes import Mode
from tests.api.conftest import TOKEN, ApiUnderTest, serve_api
from tests.status_examples import a_status, status_json


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


PATH_FILE = """
speed_mps = 0.4
accel_mps2 = 0.5
hold_s = 2

[[waypoints]]
bar_position = [0.2, 0.0, 1.1]

[[waypoints]]
bar_position = [0.5, 0.0, 1.2]
bar_yaw = 0.3
"""


async def test_a_path_from_a_file_is_queued_or_refused_with_the_reason(
    api: ApiUnderTest, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    file = tmp_path / "path.toml"
    file.write_text(PATH_FILE)
    assert await cli(api, "arm") == 0
    assert await cli(api, "path", str(file)) == 0
    said = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(r"path: accepted, queued 1, \d\.\d\d m in \d+\.\d s", said), said
    [end] = api.core.queue.queued
    assert end.path is not None and end.bar_position_m == pytest.approx((0.5, 0.0, 1.2))
    assert end.bar_yaw_rad == pytest.approx(0.3) and end.hold_s == 2.0
    file.write_text(PATH_FILE.replace("1.2]", "2.9]"))
    assert await cli(api, "path", str(file)) == 1
    refused = capsys.readouterr().err
    assert (
        "path refused (409): waypoint 1: bar centre would be at (0.50, 0.00, 2.90) m" in refused
    ), refused
    file.write_text(PATH_FILE.replace("0.4", "0"))
    assert await cli(api, "path", str(file), "--json") == 1
    assert (
        "path refused (422): speed_mps: Input should be greater than 0" in capsys.readouterr().err
    )
    assert len(api.core.queue.queued) == 1


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
    lines = format_status(a_status(mode="hover", notices=notices)).splitlines()
    assert lines[-3:] == [
        "notice (68 s ago): swing: 2",
        "notice (67 s ago): swing: 3",
        "notice (66 s ago): swing: 4",
    ]
    quiet = format_status(a_status(mode="hover")).splitlines()
    assert not [line for line in quiet if "notice" in line]


@contextlib.contextmanager
def service_answering(status: object) -> Iterator[str]:
    """A service whose ``GET /api/status`` answers ``status`` (JSON) and whose requests are
    all accepted; its URL."""

    class Handler(http.server.BaseHTTPRequestHandler):
        def _answer(self, body: object) -> None:
            payload = json.dumps(body).encode()
            self.send_response(200)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(payload)))
            self.end_headers()
            self.wfile.write(payload)

        def do_GET(self) -> None:
            self._answer(status)

        def do_POST(self) -> None:
            self._answer({"accepted": True, "mode": "armed"})

        def log_message(self, *args: object) -> None:
            pass

    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), Handler) as server:
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            yield f"http://127.0.0.1:{server.server_address[1]}"
        finally:
            server.shutdown()
            thread.join()


def without(key: str, body: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in body.items() if k != key}


@pytest.mark.parametrize(
    ("answer", "words"),
    [
        (without("mode", status_json()), "mode: Field required"),
        (status_json(mode_for_s="12.5"), "mode_for_s: Input should be a valid number"),
        (
            status_json(bar=status_json()["bar"] | {"position": ["0", 0.0, 0.02]}),
            "bar.position.0: Input should be a valid number",
        ),
        ([1, 2, 3], "Input should be a valid dictionary"),
    ],
)
@pytest.mark.parametrize("command", [["status"], ["arm", "--wait", "--timeout", "5"]])
def test_a_status_that_does_not_fit_is_said_in_one_line_not_a_traceback(
    answer: object, words: str, command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with service_answering(answer) as url:
        assert main([*command, "--url", url, "--token", TOKEN]) == 1
    said = capsys.readouterr().err
    assert words in said and "does not fit this client's" in said, said
    assert len(said.strip().splitlines()) == 1 and "Traceback" not in said


def test_the_status_of_a_service_that_fits_is_printed(capsys: pytest.CaptureFixture[str]) -> None:
    with service_answering(status_json(mode="armed", armed=[True, True])) as url:
        assert main(["status", "--url", url]) == 0
        assert main(["arm", "--wait", "--url", url, "--token", TOKEN]) == 0
    out = capsys.readouterr().out
    assert out.startswith("mode armed (ground), controller centralized") and "arm: armed" in out


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
