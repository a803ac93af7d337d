"""A fleet's certificates (``uavbar-supervisor fleet-certs``): an authority of the fleet's
own, and a certificate and key for the ground station and for each agent, named as access
control knows them (``ground``, ``agent-I``). The authority's key signs nothing else and
stays with whoever issues; each computer gets ``ca.pem`` and its own pair only."""

from __future__ import annotations

import datetime
import os
import tempfile
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from supervisor.agents.fleet_security import (
    CA_CERTIFICATE,
    GROUND,
    agent_identity,
    certificate_file,
    private_key_file,
)

CA_PRIVATE_KEY = "ca.key"
CLOCK_SKEW = datetime.timedelta(days=1)  # a vehicle computer's clock a day behind still works


class CertificatesExistError(Exception):
    """The folder already holds a fleet's files; nothing was written."""


def _key() -> ec.EllipticCurvePrivateKey:
    return ec.generate_private_key(ec.SECP256R1())


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _valid(builder: x509.CertificateBuilder, days: int) -> x509.CertificateBuilder:
    now = datetime.datetime.now(datetime.UTC)
    return builder.not_valid_before(now - CLOCK_SKEW).not_valid_after(
        now + datetime.timedelta(days=days)
    )


def _authority(fleet: str, days: int) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    key = _key()
    usage = x509.KeyUsage(
        digital_signature=True,
        key_cert_sign=True,
        crl_sign=True,
        content_commitment=False,
        key_encipherment=False,
        data_encipherment=False,
        key_agreement=False,
        encipher_only=False,
        decipher_only=False,
    )
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(f"uavbar fleet {fleet}"))
        .issuer_name(_name(f"uavbar fleet {fleet}"))
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(usage, critical=True)
    )
    return key, _valid(builder, days).sign(key, hashes.SHA256())


def _member(
    authority: tuple[ec.EllipticCurvePrivateKey, x509.Certificate], identity: str, days: int
) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """A certificate for both ends of a link (each process listens and connects)."""
    ca_key, ca_certificate = authority
    key = _key()
    both_ends = x509.ExtendedKeyUsage(
        [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
    )
    builder = (
        x509.CertificateBuilder()
        .subject_name(_name(identity))
        .issuer_name(ca_certificate.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName([x509.DNSName(identity)]), critical=False)
        .add_extension(both_ends, critical=False)
    )
    return key, _valid(builder, days).sign(ca_key, hashes.SHA256())


def _pem_key(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def _pem(certificate: x509.Certificate) -> bytes:
    return certificate.public_bytes(serialization.Encoding.PEM)


def _members(n_vehicles: int) -> list[str]:
    return [GROUND, *(agent_identity(v) for v in range(1, n_vehicles + 1))]


def fleet_files(folder: Path, n_vehicles: int) -> list[Path]:
    """Every file ``issue`` writes in ``folder``."""
    files = [folder / CA_CERTIFICATE, folder / CA_PRIVATE_KEY]
    for identity in _members(n_vehicles):
        files += [certificate_file(folder, identity), private_key_file(folder, identity)]
    return files


def _write_fleet(folder: Path, fleet: str, n_vehicles: int, days: int) -> None:
    """The fleet's files in ``folder``, keys readable by their owner only."""

    def write(path: Path, data: bytes, mode: int) -> None:
        path.write_bytes(data)
        os.chmod(path, mode)

    authority = _authority(fleet, days)
    write(folder / CA_CERTIFICATE, _pem(authority[1]), 0o644)
    write(folder / CA_PRIVATE_KEY, _pem_key(authority[0]), 0o600)
    for identity in _members(n_vehicles):
        key, certificate = _member(authority, identity, days)
        write(certificate_file(folder, identity), _pem(certificate), 0o644)
        write(private_key_file(folder, identity), _pem_key(key), 0o600)


def issue(folder: Path, fleet: str, n_vehicles: int, days: int) -> list[Path]:
    """Write a new fleet's files into ``folder`` (made if absent; keys readable by their
    owner only). All or nothing: they are made beside it first, then moved in; a folder
    that already holds any of them is refused (CertificatesExistError)."""
    targets = fleet_files(folder, n_vehicles)
    present = [path for path in targets if path.exists()]
    if present:
        raise CertificatesExistError(
            f"{folder} already holds {', '.join(p.name for p in present)}: a new authority "
            "would lock out every computer holding the old one; choose another folder"
        )
    folder.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder, prefix=".fleet-certs-") as staging:
        _write_fleet(Path(staging), fleet, n_vehicles, days)
        for path in targets:
            os.replace(Path(staging) / path.name, path)
    return targets
