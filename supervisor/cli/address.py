"""Where the terminal client finds the service, without importing the service.

In order: ``--url``; the environment variable ``UAVBAR_URL``; the address in the setup when
``--set api.host``/``api.port`` names it; else what ``serve`` wrote in its discovery file
for the setup's port (``supervisor.ipc.rendezvous``), else the one ``serve`` running on
this computer, else the setup's ``api.host``:``api.port``. The setup is read as TOML only
(``supervisor.app.config_files``), never validated: the client needs two keys of it.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from typing import Any

from supervisor.app.config_files import (
    DEFAULT_SETUP,
    OVERRIDE_SOURCE,
    ConfigError,
    read_setup,
    setup_path,
)
from supervisor.ipc.rendezvous import discovery_folder, read_discovery

URL_ENV = "UAVBAR_URL"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
ANY_ADDRESS = ("0.0.0.0", "::", "")


@dataclass(frozen=True)
class ServiceAddress:
    """The service's base URL and how it was found (said when it cannot be reached)."""

    url: str
    found_by: str


def _configured(args: argparse.Namespace) -> tuple[str, int, bool]:
    """The setup's API host and port, and whether ``--set`` named either."""
    path = setup_path(args.config) if args.config is not None else DEFAULT_SETUP
    setup = read_setup(path, args.overrides)
    api: Any = setup.data.get("api", {})
    host = api.get("host", DEFAULT_HOST) if isinstance(api, dict) else DEFAULT_HOST
    port = api.get("port", DEFAULT_PORT) if isinstance(api, dict) else DEFAULT_PORT
    if not isinstance(host, str) or not isinstance(port, int) or not 0 < port < 65536:
        raise ConfigError(f"api.host {host!r} / api.port {port!r}: not an address to reach")
    named = any(setup.sources.get(f"api.{key}") == OVERRIDE_SOURCE for key in ("host", "port"))
    return (DEFAULT_HOST if host in ANY_ADDRESS else host), port, named


def _alive(found: dict[str, Any]) -> bool:
    pid = found.get("pid")
    if not isinstance(pid, int):
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _running_services() -> list[str]:
    """The URLs of every ``serve`` of this user running on this computer."""
    urls = []
    for path in sorted(discovery_folder().glob("serve-*.json")):
        port = path.stem.removeprefix("serve-")
        found = read_discovery(int(port)) if port.isdigit() else None
        if found is not None and isinstance(found.get("url"), str) and _alive(found):
            urls.append(str(found["url"]))
    return urls


def service_address(args: argparse.Namespace) -> ServiceAddress:
    """The address of the service ``args`` mean (raises ``ConfigError`` for a bad setup)."""
    if args.url:
        return ServiceAddress(str(args.url).rstrip("/"), "--url")
    from_env = os.environ.get(URL_ENV)
    if from_env:
        return ServiceAddress(from_env.rstrip("/"), f"${URL_ENV}")
    host, port, named = _configured(args)
    configured = ServiceAddress(f"http://{host}:{port}", "the setup's api.host and api.port")
    if named:
        return configured
    found = read_discovery(port)
    if found is not None and isinstance(found.get("url"), str) and _alive(found):
        return ServiceAddress(str(found["url"]).rstrip("/"), "serve's discovery file")
    running = _running_services()
    if len(running) == 1:
        return ServiceAddress(running[0].rstrip("/"), "the one serve running here")
    if running:
        others = ", ".join(running)
        return ServiceAddress(
            configured.url, f"{configured.found_by}; serves running here: {others}"
        )
    return configured
