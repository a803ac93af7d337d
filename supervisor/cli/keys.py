"""``uavbar-supervisor keys``: make the vehicles' MAVLink 2 signing keys.

Writes one fresh random key per configured vehicle (``vehicles.system_ids``) to
``vehicles.signing_keys`` (or ``--out``), a file only its owner may read; an existing file
is kept unless ``--force``. ``serve`` with ``vehicles.signing = true`` reads it and gives
each PX4 its key (SETUP_SIGNING) before arming.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from supervisor.app.config import Config
from supervisor.app.signing_keys import signing_keys_path, write_signing_keys


def _keys(config: Config, args: argparse.Namespace) -> int:
    path: Path = args.out or signing_keys_path(config.vehicles.signing_keys)
    system_ids = config.vehicles.system_ids
    write_signing_keys(path, system_ids, replace=args.force)
    print(f"{path}: a signing key for each of system ids {', '.join(map(str, system_ids))}")
    return 0


def add_keys_command(commands: Any) -> None:
    """Register ``keys`` on the CLI's subcommands (``argparse`` subparsers)."""
    keys = commands.add_parser("keys", help="make the vehicles' MAVLink 2 signing keys")
    keys.add_argument(
        "--out", type=Path, metavar="PATH", help="write here (default: vehicles.signing_keys)"
    )
    keys.add_argument("--force", action="store_true", help="replace the keys of an existing file")
    keys.set_defaults(handler=_keys)
