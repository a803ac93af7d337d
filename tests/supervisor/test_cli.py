"""The command line as a user meets it: in a process of its own, what it imports, its help,
its one-line errors and exit statuses, and where it looks for the service."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from supervisor.cli.address import service_address
from supervisor.cli.config_show import effective_config
from supervisor.cli.main import build_parser
from supervisor.ipc.rendezvous import write_discovery
from tests.conftest import CONFIGS

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("matplotlib", "numba", "casadi", "scipy", "numpy", "pydantic", "httpx")


def cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``uavbar-supervisor ARGS`` in its own process, from another directory."""
    environment = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    environment.pop("UAVBAR_URL", None)
    return subprocess.run(
        [sys.executable, "-m", "supervisor.cli.main", *args],
        capture_output=True,
        text=True,
        env=environment,
        cwd="/",
        timeout=120,
    )


def test_the_client_commands_import_none_of_the_heavy_libraries() -> None:
    code = (
        "import sys; import supervisor.cli.main, supervisor.cli.client; "
        "supervisor.cli.main.build_parser(); "
        f"print([m for m in {HEAVY!r} if m in sys.modules])"
    )
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}
    result = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=environment, check=True
    )
    assert result.stdout.strip() == "[]", result.stdout


@pytest.mark.parametrize(
    ("args", "status", "words"),
    [
        (["setpoint", "nan", "0", "1"], 2, "'nan' is not a finite number"),
        (["setpoint", "inf", "0", "1"], 2, "'inf' is not a finite number"),
        (["setpoint", "0", "0", "1", "--yaw", "0.4"], 2, "unrecognized arguments: --yaw"),
        (["setpoint", "0", "0"], 2, "takes X Y Z"),
        (["setpoint", "0", "0", "1", "--theta-l-deg", "95"], 2, "[0, 90) degrees"),
        (["setpoint", "--wait"], 2, "--wait waits for a request"),
        (["takeoff", "--wait", "--timeout", "-1"], 2, "'-1' must be > 0"),
        (["kill"], 2, "add --confirm"),
        (["fault", "udp_loss", "--fraction", "nan"], 2, "'nan' is not a finite number"),
        (["status", "--config", "no-such-setup"], 2, "no such shipped setup"),
        (["status", "--set", "api.port=x"], 2, "is not a TOML value"),
        (["stat"], 2, "invalid choice: 'stat'"),
        (["status", "--url", "http://127.0.0.1:9"], 3, "cannot reach the service"),
        (["status", "--url", "ftp://somewhere"], 2, "is not an http:// or https:// address"),
        (["abort", "--url", "http://127.0.0.1:9"], 3, "directly: no service on port 9"),
    ],
)
def test_a_mistake_is_one_line_and_an_exit_status(args: list[str], status: int, words: str) -> None:
    result = cli(*args)
    assert result.returncode == status, result.stderr
    assert words in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""


GOOD_PATH = """
speed_mps = 0.4
accel_mps2 = 0.5

[[waypoints]]
bar_position = [0.5, 0.0, 1.2]
"""


@pytest.mark.parametrize(
    ("text", "words"),
    [
        (None, "cannot read the path file: No such file or directory"),
        ("speed_mps = ", "not valid TOML: Invalid value (at end of document)"),
        (GOOD_PATH.replace("accel_mps2 = 0.5", ""), "accel_mps2: missing"),
        (GOOD_PATH.replace("speed_mps", "speed"), "speed: unknown key (known: speed_mps, "),
        ("speed_mps = 1\naccel_mps2 = 1\nwaypoints = 3", "waypoints: one [[waypoints]] table"),
        (GOOD_PATH.replace("0.4", "nan"), "speed_mps: nan is not a finite number"),
        (GOOD_PATH.replace("0.4", '"fast"'), "speed_mps: 'fast' is not a finite number"),
        (GOOD_PATH + "bar_yaw_deg = 20", "waypoints[0].bar_yaw_deg: unknown key"),
        (GOOD_PATH + "theta_l = true", "waypoints[0].theta_l: True is not a finite number"),
        (GOOD_PATH.replace(", 1.2]", "]"), "waypoints[0].bar_position: three numbers [x, y, z]"),
        (GOOD_PATH.replace("1.2]", "inf]"), "waypoints[0].bar_position: inf is not a finite"),
        (GOOD_PATH.replace("bar_position", "position"), "waypoints[0].position: unknown key"),
    ],
)
def test_a_path_file_that_cannot_be_used_is_one_line_naming_the_file_and_the_key(
    tmp_path: Path, text: str | None, words: str
) -> None:
    """Said before any service is looked for (none runs here): exit 2, as a usage error."""
    file = tmp_path / "path.toml"
    if text is not None:
        file.write_text(text)
    result = cli("path", str(file), "--url", "http://127.0.0.1:9")
    assert result.returncode == 2, result.stderr
    assert f"path: {file}: {words}" in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "Traceback" not in result.stderr and result.stdout == ""


def test_serve_on_a_port_in_use_says_so_in_one_line() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        result = cli("serve", "--set", f"api.port={port}", env={"UAVBAR_TOKEN": "t" * 16})
    assert result.returncode == 2
    assert f"cannot listen on 127.0.0.1:{port}: Address already in use" in result.stderr
    assert "--set api.port=N" in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_version_and_help_name_units_defaults_and_examples() -> None:
    version = cli("--version")
    assert version.returncode == 0 and version.stdout.startswith("uavbar-supervisor ")
    top = cli("--help")
    assert top.returncode == 0
    assert "examples:" in top.stdout and "exit status:" in top.stdout
    assert "``" not in top.stdout
    setpoint = " ".join(cli("setpoint", "--help").stdout.split())
    for words in (
        "--yaw-deg DEG",
        "--theta-l-deg DEG",
        "--hold-s S",
        "[m]",
        "default: 5",
        "--wait",
    ):
        assert words in setpoint, words
    assert "(default: 60)" in " ".join(cli("takeoff", "--help").stdout.split())  # --timeout
    path = " ".join(cli("path", "--help").stdout.split())
    for words in ("FILE", "bar_position = [0.5, 0.0, 1.2]", "[m/s]", "[rad]", "--wait"):
        assert words in path, words
    assert "(default: 120 beyond the path's duration and hold)" in path
    assert "path" in cli("--help").stdout


def test_over_https_the_client_trusts_the_certificate_the_service_found_uses(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("UAVBAR_URL", raising=False)
    monkeypatch.delenv("UAVBAR_CA_FILE", raising=False)
    served = {"url": "https://127.0.0.1:8000", "pid": os.getpid(), "cert_file": "/lab/api.pem"}
    write_discovery(8000, served)
    found = service_address(build_parser().parse_args(["status"]))
    assert (found.url, found.cafile) == ("https://127.0.0.1:8000", "/lab/api.pem")
    named = build_parser().parse_args(["status", "--cafile", "/lab/ca.pem"])
    assert service_address(named).cafile == "/lab/ca.pem"  # --cafile first
    configured = build_parser().parse_args(
        ["status", "--set", "api.port=8443", "--set", 'api.tls_cert_file="/lab/own.pem"']
    )
    found = service_address(configured)  # --set names the address: the setup's, over HTTPS
    assert (found.url, found.cafile) == ("https://127.0.0.1:8443", "/lab/own.pem")


def test_no_option_is_taken_by_its_abbreviation() -> None:
    """``--yaw 0.4`` (radians, before) must never be read as ``--yaw-deg 0.4``."""
    parser = build_parser()
    for prefix in ("--yaw", "--theta", "--hold-"):
        with pytest.raises(SystemExit):
            parser.parse_args(["setpoint", "0", "0", "1", prefix, "1"])


def test_the_client_finds_the_service(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("UAVBAR_URL", raising=False)
    args = build_parser().parse_args(["status"])
    assert service_address(args).url == "http://127.0.0.1:8000"  # nothing running
    write_discovery(8131, {"url": "http://127.0.0.1:8131", "pid": os.getpid()})
    found = service_address(args)
    assert found.url == "http://127.0.0.1:8131" and found.found_by == "the one serve running here"
    write_discovery(8132, {"url": "http://127.0.0.1:8132", "pid": os.getpid()})
    several = service_address(args)  # which one is meant? the setup's, naming the others
    assert several.url == "http://127.0.0.1:8000" and "http://127.0.0.1:8132" in several.found_by
    write_discovery(8000, {"url": "http://127.0.0.1:8000", "pid": os.getpid()})
    assert service_address(args).found_by == "serve's discovery file"  # the setup's port first
    named = build_parser().parse_args(["status", "--set", "api.port=8200"])
    assert service_address(named).url == "http://127.0.0.1:8200"  # --set is what was asked
    monkeypatch.setenv("UAVBAR_URL", "http://10.0.0.5:8000/")
    assert service_address(args).url == "http://10.0.0.5:8000"
    given = build_parser().parse_args(["status", "--url", "http://h:1"])
    assert service_address(given).url == "http://h:1"


def test_a_dead_serve_s_discovery_file_is_ignored(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    monkeypatch.delenv("UAVBAR_URL", raising=False)
    gone = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        check=True,
        capture_output=True,
        text=True,
    )
    write_discovery(8131, {"url": "http://127.0.0.1:8131", "pid": int(gone.stdout)})
    assert service_address(build_parser().parse_args(["status"])).url == "http://127.0.0.1:8000"


def test_config_show_names_each_key_s_source() -> None:
    shown = effective_config(CONFIGS / "sim.toml", ["api.port=8131", 'api.token="secret-token"'])
    assert shown["api.port"] == {"value": 8131, "source": "--set"}
    assert shown["api.token"]["value"] == "(set, not shown)"
    assert shown["api.host"] == {"value": "127.0.0.1", "source": "default"}
    assert shown["name"]["source"].endswith("sim.toml")
    assert shown["system.bar_mass"]["source"].endswith("kth_sml.toml")  # sim.toml extends it
    result = cli("config", "show", "--json", "--config", "kth_sml")
    assert result.returncode == 0
    assert json.loads(result.stdout)["name"]["value"] == "kth_sml"
