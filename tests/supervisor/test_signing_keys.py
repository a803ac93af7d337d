"""The signing key file: made by ``uavbar-supervisor keys`` readable by its owner only,
refused (as ssh refuses a private key) when anyone else may read it; and the links' bind
address."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from supervisor.app.config import CONFIG_DIR, ConfigError, load_config
from supervisor.app.signing_keys import load_signing_keys
from supervisor.cli.main import main


def make_keys(path: Path, *extra: str) -> int:
    return main(["keys", "--out", str(path), *extra])


def test_keys_makes_a_private_file_with_one_key_per_vehicle(tmp_path: Path) -> None:
    path = tmp_path / "keys" / "signing"
    assert make_keys(path) == 0
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    keys = load_signing_keys(path, [1, 2])
    assert set(keys) == {1, 2} and keys[1] != keys[2] and all(len(k) == 32 for k in keys.values())
    assert make_keys(path) == 2  # an existing file is kept
    assert load_signing_keys(path, [1, 2]) == keys
    assert make_keys(path, "--force") == 0
    assert load_signing_keys(path, [1, 2]) != keys


@pytest.mark.parametrize("mode", [0o640, 0o604, 0o620, 0o601])
def test_a_key_file_others_may_use_is_refused(tmp_path: Path, mode: int) -> None:
    path = tmp_path / "signing"
    make_keys(path)
    os.chmod(path, mode)
    with pytest.raises(ConfigError, match=r"accessible by others.*chmod 600"):
        load_signing_keys(path, [1, 2])


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("1 " + "ab" * 32 + "\n", "no key for system id 2"),
        ("1 " + "ab" * 31 + "\n2 " + "cd" * 32 + "\n", "a key is 32 bytes"),
        ("1 " + "zz" * 32 + "\n", "not hexadecimal"),
        ("1 " + "00" * 32 + "\n2 " + "cd" * 32 + "\n", "all-zero key"),
        ("1 " + "ab" * 32 + "\n1 " + "cd" * 32 + "\n", "a second key"),
        ("one key\n", "expected 'system_id hexkey'"),
    ],
)
def test_a_malformed_key_file_names_its_problem(tmp_path: Path, text: str, problem: str) -> None:
    path = tmp_path / "signing"
    path.write_text(text)
    path.chmod(0o600)
    with pytest.raises(ConfigError, match=problem):
        load_signing_keys(path, [1, 2])


def test_a_missing_key_file_says_how_to_make_one(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="uavbar-supervisor keys"):
        load_signing_keys(tmp_path / "none", [1, 2])


def test_the_links_bind_loopback_for_the_embedded_world_and_a_named_interface_in_a_lab() -> None:
    assert load_config(CONFIG_DIR / "sim.toml").link_bind_host() == "127.0.0.1"
    lab = load_config(CONFIG_DIR / "kth_sml.toml")
    with pytest.raises(ConfigError, match=r"vehicles\.bind_host"):
        lab.link_bind_host()
    named = load_config(CONFIG_DIR / "kth_sml.toml", ['vehicles.bind_host="192.168.1.20"'])
    assert named.link_bind_host() == "192.168.1.20"
    with pytest.raises(ConfigError, match="embedded world is on loopback"):
        load_config(CONFIG_DIR / "sim.toml", ['vehicles.bind_host="0.0.0.0"'])
    with pytest.raises(ConfigError, match=r"PX4 v1\.15\.4 SITL cannot sign"):
        load_config(CONFIG_DIR / "sim.toml", ['sim.vehicles="px4_sitl"', "vehicles.signing=true"])
