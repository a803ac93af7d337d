"""``uavbar-supervisor fleet-certs``: make a fleet's TLS certificates.

Writes an authority of the fleet's own and a certificate and key for the ground station
and each agent of the setup (``agents.fleet``, its UAVs) into ``--folder``; ``serve`` and
each ``agent`` read theirs there with ``agents.tls_folder`` (docs/agents.md, "Access").
A folder that already holds a fleet's files is refused: nothing is replaced.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from supervisor.app.config import Config

DEFAULT_VALID_DAYS = 365


def make_fleet_certificates(config: Config, args: argparse.Namespace) -> int:
    """Write the files ``args`` ask for; returns the exit status."""
    from supervisor.agents.certificates import CertificatesExistError, issue
    from supervisor.app.config import ConfigError

    if args.days < 1:
        raise ConfigError(f"--days: at least 1, got {args.days}")
    n = config.system.n_vehicles
    try:
        written = issue(args.folder, config.agents.fleet, n, args.days)
    except CertificatesExistError as error:
        raise ConfigError(str(error)) from None
    print(f"{args.folder}: fleet {config.agents.fleet!r}, the ground station and {n} agents")
    for path in written:
        print(f"  {path.name}")
    print(
        "Give each computer ca.pem and its own pair (the ground station ground.*, agent I "
        "agent-I.*); keep ca.key with whoever issues."
    )
    return 0


def add_fleet_certs_command(commands: Any, handler: Callable[[argparse.Namespace], int]) -> None:
    """Register ``fleet-certs`` on the CLI's subcommands (``argparse`` subparsers), run by
    ``handler`` (which loads the setup and calls ``make_fleet_certificates``)."""
    certs = commands.add_parser(
        "fleet-certs",
        help="make the agents' TLS certificates (Zenoh beyond loopback)",
        description="Write a certificate authority of the fleet's own and a certificate "
        "and key for the ground station and each agent of the setup; agents.tls_folder "
        "names the folder that holds them.",
        epilog="example:\n  uavbar-supervisor fleet-certs --config lab_tri --folder ~/fleet-lab",
    )
    certs.add_argument("--folder", type=Path, required=True, metavar="DIR", help="write here")
    certs.add_argument(
        "--days",
        type=int,
        default=DEFAULT_VALID_DAYS,
        metavar="N",
        help=f"how long they are valid (default {DEFAULT_VALID_DAYS})",
    )
    certs.set_defaults(handler=handler)
