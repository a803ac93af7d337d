"""A Zenoh session as every process of a fleet opens it: a peer (no router to run);
scouting off, multicast and gossip (who talks to whom is the setup's, never whoever answers
on the network or whatever a peer heard of); listening where its peers connect,
connecting to the endpoints it is given and retrying them while they are down; over the
network link only (no shared memory); and a 1 s lease, so that a silent link (a cable
pulled, a network partitioned) ends within a second, and with it every liveliness token
over it. Beyond loopback, TLS and access control (``fleet_security``)."""

from __future__ import annotations

import json
from collections.abc import Sequence

import zenoh

from supervisor.agents.fleet_security import FleetSecurity

LEASE_MS = 1000
KEEP_ALIVES_PER_LEASE = 4


def session_config(
    listen: Sequence[str], connect: Sequence[str], security: FleetSecurity | None
) -> zenoh.Config:
    """The configuration of a fleet's peer listening on ``listen`` and joining ``connect``
    (with ``security``: over TLS, under the fleet's access control)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    config.insert_json5("transport/link/tx/lease", str(LEASE_MS))
    config.insert_json5("transport/link/tx/keep_alive", str(KEEP_ALIVES_PER_LEASE))
    # Off: processes of one computer would otherwise share memory segments, which processes
    # on a vehicle's own computer cannot; every message goes over the network link.
    config.insert_json5("transport/shared_memory/enabled", "false")
    if security is not None:
        config.insert_json5("transport/link/tls", json.dumps(security.tls()))
        config.insert_json5("access_control", json.dumps(security.access_control()))
    return config


def open_session(
    listen: Sequence[str], connect: Sequence[str], security: FleetSecurity | None
) -> zenoh.Session:
    """Open the session (connections are made, and made again, in the background)."""
    return zenoh.open(session_config(listen, connect, security))
