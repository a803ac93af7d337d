"""The vehicles' MAVLink 2 signing keys: a file the operator owns, one line per vehicle.

    # uavbar-supervisor MAVLink 2 signing keys (one per vehicle: system id, 32 bytes hex)
    1 3f5c…(64 hex digits)
    2 a19e…

Like ssh with a private key, a file that anyone but its owner may read, write or run is
refused, and so is one owned by another user: whoever holds a key can command that
vehicle. ``write_signing_keys`` makes a new file (``uavbar-supervisor keys``), readable by
its owner only, and never overwrites one unless told to.
"""

from __future__ import annotations

import os
import secrets
import stat
from collections.abc import Sequence
from pathlib import Path

from px4_mavlink.signing import KEY_BYTES
from supervisor.app.config import ConfigError

HEADER = "# uavbar-supervisor MAVLink 2 signing keys (one per vehicle: system id, 32 bytes hex)\n"


def signing_keys_path(path: str) -> Path:
    """The configured key file (``~`` expanded)."""
    return Path(path).expanduser()


def _check_private(path: Path) -> None:
    try:
        info = path.stat()
    except FileNotFoundError:
        raise ConfigError(
            f"vehicles.signing_keys: {path} does not exist (make one: uavbar-supervisor keys)"
        ) from None
    except OSError as error:
        raise ConfigError(f"vehicles.signing_keys: cannot read {path}: {error.strerror}") from None
    if not stat.S_ISREG(info.st_mode):
        raise ConfigError(f"vehicles.signing_keys: {path} is not a regular file")
    if info.st_uid != os.geteuid():
        raise ConfigError(f"vehicles.signing_keys: {path} belongs to another user")
    if info.st_mode & 0o077:
        raise ConfigError(
            f"vehicles.signing_keys: {path} is accessible by others "
            f"(mode {stat.S_IMODE(info.st_mode):04o}): chmod 600 {path}"
        )


def _parse(path: Path, text: str) -> dict[int, bytes]:
    keys: dict[int, bytes] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        where = f"vehicles.signing_keys: {path} line {number}"
        parts = line.split()
        if len(parts) != 2 or not parts[0].isdigit():
            raise ConfigError(f"{where}: expected 'system_id hexkey'")
        system_id = int(parts[0])
        try:
            key = bytes.fromhex(parts[1])
        except ValueError:
            raise ConfigError(f"{where}: the key is not hexadecimal") from None
        if len(key) != KEY_BYTES:
            raise ConfigError(f"{where}: a key is {KEY_BYTES} bytes, this one {len(key)}")
        if not any(key):
            raise ConfigError(f"{where}: an all-zero key turns signing off in MAVLink")
        if system_id in keys:
            raise ConfigError(f"{where}: a second key for system id {system_id}")
        keys[system_id] = key
    return keys


def load_signing_keys(path: Path, system_ids: Sequence[int]) -> dict[int, bytes]:
    """The key of each of ``system_ids`` from the file at ``path``; raises ``ConfigError``
    naming the problem (missing, not private, malformed, a vehicle without a key)."""
    _check_private(path)
    try:
        text = path.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"vehicles.signing_keys: cannot read {path}: {error}") from None
    keys = _parse(path, text)
    missing = [str(s) for s in system_ids if s not in keys]
    if missing:
        raise ConfigError(
            f"vehicles.signing_keys: {path} has no key for system id {', '.join(missing)}"
        )
    return {s: keys[s] for s in system_ids}


def write_signing_keys(path: Path, system_ids: Sequence[int], *, replace: bool = False) -> None:
    """A new key file at ``path`` with a fresh random key for each of ``system_ids``, mode
    0600 from its creation; an existing file is kept unless ``replace``."""
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    lines = [HEADER] + [f"{s} {secrets.token_bytes(KEY_BYTES).hex()}\n" for s in system_ids]
    flags = os.O_WRONLY | os.O_CREAT | (os.O_TRUNC if replace else os.O_EXCL)
    try:
        fd = os.open(path, flags, 0o600)
    except FileExistsError:
        raise ConfigError(f"{path} exists: keep it, or --force to replace its keys") from None
    except OSError as error:
        raise ConfigError(f"cannot write {path}: {error.strerror}") from None
    with os.fdopen(fd, "w", encoding="ascii") as handle:
        os.fchmod(handle.fileno(), 0o600)  # a replaced file keeps its old mode otherwise
        handle.write("".join(lines))
