"""``uavbar-supervisor keys``: make the vehicles' MAVLink 2 signing keys.

Writes one fresh random key per configured vehicle (``vehicles.system_ids``) to
``vehicles.signing_keys`` (or ``--out``), a file only its owner may read; an existing file
is kept unless ``--force``. ``serve`` with ``vehicles.signing = true`` reads it and gives
each PX4 its key (SETUP_SIGNING) before arming.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from supervisor.app.config import Config


def make_keys(config: Config, args: argparse.Namespace) -> int:
    """Write the key file ``args`` ask for; returns the exit status."""
    from supervisor.app.signing_keys import signing_keys_path, write_signing_keys

    path: Path = args.out or signing_keys_path(config.vehicles.signing_keys)
    system_ids = config.vehicles.system_ids
    write_signing_keys(path, system_ids, replace=args.force)
    print(f"{path}: a signing key for each of system ids {', '.join(map(str, system_ids))}")
    return 0


def add_keys_command(commands: Any, handler: Callable[[argparse.Namespace], int]) -> None:
    """Register ``keys`` on the CLI's subcommands (``argparse`` subparsers), run by
    ``handler`` (which loads the setup and calls ``make_keys``)."""
    keys = commands.add_parser(
        "keys",
        help="make the vehicles' MAVLink 2 signing keys",
        description="Write a fresh MAVLink 2 signing key for each vehicle, in a file only "
        "you may read (serve with vehicles.signing = true gives each PX4 its key).",
        epilog="example:\n  uavbar-supervisor keys --out ~/.config/uavbar-supervisor/signing-keys",
    )
    keys.add_argument(
        "--out", type=Path, metavar="PATH", help="write here (default: vehicles.signing_keys)"
    )
    keys.add_argument("--force", action="store_true", help="replace the keys of an existing file")
    keys.set_defaults(handler=handler)
