"""``uavbar-supervisor fleet-certs``: an authority of the fleet's own signs a certificate
for the ground station and each agent, named as access control knows them; nothing is
ever replaced."""

from __future__ import annotations

import datetime
import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from supervisor.agents.certificates import CertificatesExistError, fleet_files, issue
from supervisor.app.config import ConfigError, load_config
from supervisor.app.config_files import setup_path
from supervisor.cli.main import main


def _certificate(path: Path) -> x509.Certificate:
    return x509.load_pem_x509_certificate(path.read_bytes())


def _common_name(certificate: x509.Certificate) -> str:
    return str(certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value)


def test_each_member_is_signed_by_the_fleets_authority_under_its_name(tmp_path: Path) -> None:
    issue(tmp_path, "lab", n_vehicles=3, days=30)
    authority = _certificate(tmp_path / "ca.pem")
    authority_key = authority.public_key()
    assert isinstance(authority_key, ec.EllipticCurvePublicKey)
    assert authority.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for identity in ("ground", "agent-1", "agent-2", "agent-3"):
        member = _certificate(tmp_path / f"{identity}.pem")
        assert _common_name(member) == identity
        assert member.issuer == authority.subject
        signature_hash = member.signature_hash_algorithm
        assert signature_hash is not None
        authority_key.verify(
            member.signature, member.tbs_certificate_bytes, ec.ECDSA(signature_hash)
        )
        key = serialization.load_pem_private_key((tmp_path / f"{identity}.key").read_bytes(), None)
        assert key.public_key() == member.public_key()  # the pair belongs together
        lifetime = member.not_valid_after_utc - datetime.datetime.now(datetime.UTC)
        assert datetime.timedelta(days=29) < lifetime <= datetime.timedelta(days=30)
        assert not member.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for path in fleet_files(tmp_path, 3):
        private = stat.S_IMODE(path.stat().st_mode) == 0o600
        assert private == path.name.endswith(".key"), path
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        p.name for p in fleet_files(tmp_path, 3)
    )  # nothing staged is left behind


def test_a_folder_holding_a_fleet_is_refused_and_kept(tmp_path: Path) -> None:
    issue(tmp_path, "lab", n_vehicles=2, days=30)
    before = {path: path.read_bytes() for path in tmp_path.iterdir()}
    with pytest.raises(CertificatesExistError, match=r"ca\.pem"):
        issue(tmp_path, "lab", n_vehicles=3, days=30)
    assert {path: path.read_bytes() for path in tmp_path.iterdir()} == before


def test_the_command_makes_the_setups_fleet_then_refuses_to_replace_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "fleet"
    assert main(["fleet-certs", "--config", "sim_tri", "--folder", str(folder)]) == 0
    assert (folder / "agent-3.pem").is_file() and not (folder / "agent-4.pem").exists()
    assert main(["fleet-certs", "--folder", str(folder)]) == 2
    assert "already holds" in capsys.readouterr().err


def test_a_process_without_its_files_says_which(tmp_path: Path) -> None:
    issue(tmp_path, "lab", n_vehicles=2, days=30)
    (tmp_path / "agent-2.key").unlink()
    config = load_config(
        setup_path("sim"),
        [f"agents.tls_folder={str(tmp_path)!r}", "agents.ground_endpoint='tls/127.0.0.1:0'"],
    )
    security = config.agents.security("agent-1", 2)
    assert security is not None and security.missing_files() == []
    with pytest.raises(ConfigError, match=r"no agent-2\.key in"):
        config.agents.security("agent-2", 2)
