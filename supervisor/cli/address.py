"""Where the terminal client finds the service, without importing the service.

In order: ``--url``; the environment variable ``UAVBAR_URL``; the address in the setup when
``--set api.host``/``api.port`` names it; else what ``serve`` wrote in its discovery file
for the setup's port (``supervisor.ipc.rendezvous``), else the one ``serve`` running on
this computer, else the setup's ``api.host``:``api.port``. The setup is read as TOML only
(``supervisor.app.config_files``), never validated: the client needs three keys of it.

Over HTTPS the certificate to trust (a lab's is often self-signed: it is its own CA) is
``--cafile``, else ``UAVBAR_CA_FILE``, else the one the service found uses (its discovery
file's ``cert_file``, or the setup's ``api.tls_cert_file``), else the system's CAs.
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
CA_FILE_ENV = "UAVBAR_CA_FILE"
DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8000
ANY_ADDRESS = ("0.0.0.0", "::", "")


@dataclass(frozen=True)
class ServiceAddress:
    """The service's base URL and how it was found (said when it cannot be reached)."""

    url: str
    found_by: str
    cafile: str | None = None  # the certificate to trust over HTTPS (None: the system's)


@dataclass(frozen=True)
class _Configured:
    host: str
    port: int
    named: bool  # --set named api.host or api.port
    cert_file: str | None  # api.tls_cert_file: the API serves HTTPS

    @property
    def url(self) -> str:
        return f"{'https' if self.cert_file else 'http'}://{self.host}:{self.port}"


def _configured(args: argparse.Namespace) -> _Configured:
    """The setup's API address, whether ``--set`` named it, and its certificate."""
    path = setup_path(args.config) if args.config is not None else DEFAULT_SETUP
    setup = read_setup(path, args.overrides)
    api: Any = setup.data.get("api", {})
    api = api if isinstance(api, dict) else {}
    host, port = api.get("host", DEFAULT_HOST), api.get("port", DEFAULT_PORT)
    if not isinstance(host, str) or not isinstance(port, int) or not 0 < port < 65536:
        raise ConfigError(f"api.host {host!r} / api.port {port!r}: not an address to reach")
    cert_file = api.get("tls_cert_file")
    named = any(setup.sources.get(f"api.{key}") == OVERRIDE_SOURCE for key in ("host", "port"))
    return _Configured(
        DEFAULT_HOST if host in ANY_ADDRESS else host,
        port,
        named,
        cert_file if isinstance(cert_file, str) else None,
    )


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


def _running_services() -> list[dict[str, Any]]:
    """What every ``serve`` of this user running on this computer wrote about itself."""
    services = []
    for path in sorted(discovery_folder().glob("serve-*.json")):
        port = path.stem.removeprefix("serve-")
        found = read_discovery(int(port)) if port.isdigit() else None
        if found is not None and isinstance(found.get("url"), str) and _alive(found):
            services.append(found)
    return services


def service_address(args: argparse.Namespace) -> ServiceAddress:
    """The address of the service ``args`` mean (raises ``ConfigError`` for a bad setup)."""
    found = _found_address(args)
    cafile = getattr(args, "cafile", None) or os.environ.get(CA_FILE_ENV) or found.cafile
    return ServiceAddress(found.url, found.found_by, cafile)


def _found_address(args: argparse.Namespace) -> ServiceAddress:
    if args.url:
        return ServiceAddress(str(args.url).rstrip("/"), "--url")
    from_env = os.environ.get(URL_ENV)
    if from_env:
        return ServiceAddress(from_env.rstrip("/"), f"${URL_ENV}")
    setup = _configured(args)
    configured = ServiceAddress(setup.url, "the setup's api.host and api.port", setup.cert_file)
    if setup.named:
        return configured
    found = read_discovery(setup.port)
    if found is not None and isinstance(found.get("url"), str) and _alive(found):
        return _discovered(found, "serve's discovery file")
    running = _running_services()
    if len(running) == 1:
        return _discovered(running[0], "the one serve running here")
    if running:
        others = ", ".join(str(service["url"]) for service in running)
        return ServiceAddress(
            configured.url, f"{configured.found_by}; serves running here: {others}", setup.cert_file
        )
    return configured


def _discovered(found: dict[str, Any], how: str) -> ServiceAddress:
    cert_file = found.get("cert_file")
    return ServiceAddress(
        str(found["url"]).rstrip("/"), how, cert_file if isinstance(cert_file, str) else None
    )
