"""A fleet beyond loopback: Zenoh over TLS, each process proving who it is with a
certificate of the fleet's own authority (mutual TLS), and access control keyed on those
certificates' common names — an agent takes commands only from its ground station, and
each agent speaks only for its own vehicle (docs/agents.md, "Access")."""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from supervisor.agents.keys import (
    agent_alive_key,
    all_commands_key,
    command_key,
    fleet_key,
    ground_alive_key,
    report_key,
    tick_key,
)

CA_CERTIFICATE = "ca.pem"
GROUND = "ground"
LOOPBACK_NAMES = {"localhost"}


def agent_identity(vehicle: int) -> str:
    """Agent ``vehicle``'s certificate common name (and its files' stem)."""
    return f"agent-{vehicle}"


def certificate_file(folder: Path, identity: str) -> Path:
    return folder / f"{identity}.pem"


def private_key_file(folder: Path, identity: str) -> Path:
    return folder / f"{identity}.key"


def _host(endpoint: str) -> str:
    """``tcp/10.0.0.2:7447`` → ``10.0.0.2`` (``tcp/[::1]:7447`` → ``::1``)."""
    address = endpoint.split("/", 1)[1]
    return address.rpartition(":")[0].strip("[]")


def is_loopback(endpoint: str) -> bool:
    host = _host(endpoint)
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: wherever it resolves, it may be off this computer


def unprotected(endpoints: Iterable[str]) -> list[str]:
    """The endpoints that would carry the fleet in clear beyond this computer."""
    return [e for e in endpoints if not e.startswith("tls/") and not is_loopback(e)]


@dataclass(frozen=True)
class FleetSecurity:
    """One process's side of a fleet's TLS: the folder of the fleet's certificates, who
    this process is, and the fleet whose keys it guards."""

    folder: Path
    identity: str
    fleet: str
    n_vehicles: int

    def missing_files(self) -> list[Path]:
        needed = (
            self.folder / CA_CERTIFICATE,
            certificate_file(self.folder, self.identity),
            private_key_file(self.folder, self.identity),
        )
        return [path for path in needed if not path.is_file()]

    def tls(self) -> dict[str, Any]:
        """Zenoh's ``transport/link/tls``: this process's certificate for both ends of a
        link, and the fleet's authority required of the other end. Host names are not
        checked: a vehicle's address changes from field to field, its certificate does not,
        and who it is (the common name) is what access control reads."""
        certificate = str(certificate_file(self.folder, self.identity))
        key = str(private_key_file(self.folder, self.identity))
        return {
            "root_ca_certificate": str(self.folder / CA_CERTIFICATE),
            "listen_certificate": certificate,
            "listen_private_key": key,
            "connect_certificate": certificate,
            "connect_private_key": key,
            "enable_mtls": True,
            "verify_name_on_connect": False,
        }

    def access_control(self) -> dict[str, Any]:
        return access_control(self.fleet, self.n_vehicles)


def _rule(rule_id: str, messages: list[str], keys: list[str], flow: str) -> dict[str, Any]:
    return {
        "id": rule_id,
        "messages": messages,
        "flows": [flow],
        "permission": "allow",
        "key_exprs": keys,
    }


def access_control(fleet: str, n_vehicles: int) -> dict[str, Any]:
    """Zenoh's ``access_control``, the same in every process of the fleet: everything not
    allowed is refused. What comes in from a peer is checked against what its certificate
    says it is — queries on the agents' command keys only from the ground station, an
    agent's ticks, reports, replies and liveliness only on its own keys. What goes out to a
    member of the fleet is this process's own code's to decide."""
    everything = fleet_key(fleet)
    listening = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
    vehicles = range(1, n_vehicles + 1)
    sent = [*listening, "put", "query", "declare_queryable", "reply", "liveliness_token"]
    rules = [
        _rule("to-the-fleet", sent, [everything], "egress"),
        _rule("anyone-listens", listening, [everything], "ingress"),
        _rule(
            "ground-commands",
            ["query", "liveliness_token"],
            [all_commands_key(fleet), ground_alive_key(fleet)],
            "ingress",
        ),
    ]
    for v in vehicles:
        own_keys = [tick_key(fleet, v), report_key(fleet, v), agent_alive_key(fleet, v)]
        rules.append(
            _rule(
                f"agent-{v}-answers",
                ["declare_queryable", "reply"],
                [command_key(fleet, v)],
                "ingress",
            )
        )
        rules.append(_rule(f"agent-{v}-speaks", ["put", "liveliness_token"], own_keys, "ingress"))
    subjects = [{"id": GROUND, "cert_common_names": [GROUND]}]
    subjects += [
        {"id": agent_identity(v), "cert_common_names": [agent_identity(v)]} for v in vehicles
    ]
    everyone = [subject["id"] for subject in subjects]
    policies = [
        {"rules": ["to-the-fleet", "anyone-listens"], "subjects": everyone},
        {"rules": ["ground-commands"], "subjects": [GROUND]},
    ]
    policies += [
        {"rules": [f"agent-{v}-answers", f"agent-{v}-speaks"], "subjects": [agent_identity(v)]}
        for v in vehicles
    ]
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }
