"""The Zenoh key expressions of a fleet (docs/agents.md). Version 1: a change to a message's
meaning takes a new version, so agents of two versions never read each other."""

from __future__ import annotations

PROTOCOL_VERSION = 1
PREFIX = f"uavbar/v{PROTOCOL_VERSION}"


def tick_key(fleet: str, vehicle: int) -> str:
    """Each tick of agent ``vehicle``: its vehicle, its estimate of its bar end, its plan."""
    return f"{PREFIX}/{fleet}/agent/{vehicle}/tick"


def all_ticks_key(fleet: str) -> str:
    return f"{PREFIX}/{fleet}/agent/*/tick"


def report_key(fleet: str, vehicle: int) -> str:
    """Agent ``vehicle``'s status, for the ground station (25 Hz)."""
    return f"{PREFIX}/{fleet}/agent/{vehicle}/report"


def all_reports_key(fleet: str) -> str:
    return f"{PREFIX}/{fleet}/agent/*/report"


def command_key(fleet: str, vehicle: int) -> str:
    """Agent ``vehicle``'s queryable: the ground station's operator requests, and pings."""
    return f"{PREFIX}/{fleet}/agent/{vehicle}/command"


def all_commands_key(fleet: str) -> str:
    return f"{PREFIX}/{fleet}/agent/*/command"


def fleet_key(fleet: str) -> str:
    """Every key of ``fleet``."""
    return f"{PREFIX}/{fleet}/**"


def agent_alive_key(fleet: str, vehicle: int) -> str:
    """Agent ``vehicle``'s liveliness token."""
    return f"{PREFIX}/{fleet}/alive/agent/{vehicle}"


def ground_alive_key(fleet: str) -> str:
    """The ground station's liveliness token."""
    return f"{PREFIX}/{fleet}/alive/ground"


def all_alive_key(fleet: str) -> str:
    return f"{PREFIX}/{fleet}/alive/**"


def vehicle_of(key: str) -> int | None:
    """The vehicle an agent's key names (``.../agent/I/...``), None for any other key."""
    parts = key.split("/")
    try:
        index = parts.index("agent")
        return int(parts[index + 1])
    except (ValueError, IndexError):
        return None
