"""Where ``serve``'s processes meet: listening Unix sockets in a private directory.

The flight process and the simulated world each accept any number of connections on a
socket of their own, so that a restarted API process connects afresh and the terminal
client reaches the flight process without the API (``uavbar-supervisor abort``). The
directory is made by ``serve`` with mode 0700 (only its user, and root, can connect);
``serve`` writes where it is into a discovery file for the terminal client.
"""

from __future__ import annotations

import json
import os
import socket
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

FLIGHT_SOCKET = "flight.sock"
WORLD_SOCKET = "world.sock"


@dataclass(frozen=True)
class Rendezvous:
    """The private directory and the sockets in it."""

    folder: Path

    @classmethod
    def create(cls) -> Rendezvous:
        return cls(Path(tempfile.mkdtemp(prefix="uavbar-")))  # mkdtemp: mode 0700

    @property
    def flight(self) -> Path:
        return self.folder / FLIGHT_SOCKET

    @property
    def world(self) -> Path:
        return self.folder / WORLD_SOCKET

    def remove(self) -> None:
        for path in (self.flight, self.world):
            path.unlink(missing_ok=True)
        os.rmdir(self.folder)


def listen_unix(path: Path) -> socket.socket:
    """A listening stream socket at ``path`` (readable and writable by its owner only)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(path))
    os.chmod(path, 0o600)
    sock.listen(16)
    return sock


def discovery_folder() -> Path:
    """Where every ``serve`` of this user writes its discovery file: the user's runtime
    directory, else a private one in /tmp."""
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return Path(runtime) / "uavbar-supervisor"
    return Path(tempfile.gettempdir()) / f"uavbar-supervisor-{os.getuid()}"


def discovery_file(port: int) -> Path:
    """Where ``serve`` listening on TCP ``port`` says how to reach it without HTTP (its
    URL, its PID, the flight process's socket): one file per port."""
    return discovery_folder() / f"serve-{port}.json"


def write_discovery(port: int, contents: dict[str, Any]) -> Path:
    """Write the discovery file for ``port`` (its folder private to this user)."""
    path = discovery_file(port)
    path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(path.parent, 0o700)
    temporary = path.with_suffix(".tmp")
    temporary.write_text(json.dumps(contents))
    os.chmod(temporary, 0o600)
    temporary.replace(path)
    return path


def read_discovery(port: int) -> dict[str, Any] | None:
    """What ``serve`` on ``port`` wrote, or None (none running, or not readable)."""
    try:
        contents = json.loads(discovery_file(port).read_text())
    except (OSError, ValueError):
        return None
    return contents if isinstance(contents, dict) else None
