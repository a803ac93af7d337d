"""End to end with MAVLink signing on: ``serve`` gives the embedded world's PX4s their keys,
flies a take-off and landing, an unsigned kill from the network is refused, and no socket
of the service binds beyond loopback."""

from __future__ import annotations

import asyncio
import os
import re
import socket
from pathlib import Path

import pytest

from benchmarks.service import RunningService, all_disarmed, in_mode, position_m, running_service
from px4_mavlink.codec import MavlinkCodec
from supervisor.cli.main import main
from supervisor.flight.modes import Mode

TOKEN = "e2e-token-0123456789"
FORCE_DISARM = 21196


def px4_addresses(service: RunningService) -> list[tuple[str, int]]:
    """The simulated PX4s' addresses, from serve's log line about the world."""
    line = next(line for line in service.output if "simulated world:" in line)
    return [(host, int(port)) for host, port in re.findall(r"(\d+\.\d+\.\d+\.\d+):(\d+)", line)][1:]


def udp_binds(pids: list[int]) -> list[str]:
    """The local addresses of every UDP socket the processes ``pids`` hold (from /proc)."""
    inodes = set()
    for pid in pids:
        for fd in os.listdir(f"/proc/{pid}/fd"):
            with_target = os.readlink(f"/proc/{pid}/fd/{fd}") if fd.isdigit() else ""
            match = re.fullmatch(r"socket:\[(\d+)\]", with_target)
            if match:
                inodes.add(match.group(1))
    binds = []
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with open(table) as handle:
            for row in handle.readlines()[1:]:
                fields = row.split()
                if fields[9] in inodes:
                    binds.append(fields[1])
    return binds


def is_loopback(hex_address: str) -> bool:
    host = hex_address.split(":")[0]
    if len(host) == 8:  # IPv4, little-endian hex
        return socket.inet_ntoa(bytes.fromhex(host)[::-1]).startswith("127.")
    return host == "00000000000000000000000001000000"  # ::1


@pytest.mark.slow
async def test_a_signed_flight_and_an_unsigned_kill_refused(tmp_path: Path) -> None:
    keys = tmp_path / "signing-keys"
    assert main(["keys", "--out", str(keys)]) == 0
    overrides = ["vehicles.signing=true", f'vehicles.signing_keys="{keys}"']
    async with (
        running_service(TOKEN, tmp_path, overrides) as service,
        service.client() as http,
    ):
        await service.take_off(http)
        pids = [service.process.pid] + [
            service.child_pid(name) for name in ("uavbar-flight", "uavbar-world", "uavbar-relay")
        ]
        binds = udp_binds(pids)
        assert len(binds) >= 4 and all(is_loopback(b) for b in binds), binds
        rogue = MavlinkCodec(255, 190)  # the supervisor's ids, without its key
        sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            for system_id, address in enumerate(px4_addresses(service), start=1):
                rogue.messages.command_long_send(
                    system_id, 1, 400, 0, 0.0, FORCE_DISARM, 0, 0, 0, 0, 0
                )
                for frame in rogue.outgoing():
                    sender.sendto(frame, address)
        finally:
            sender.close()
        await asyncio.sleep(1.0)
        status = await service.status(http)
        assert all(status.armed) and status.mode is Mode.HOVER
        for uav in status.uavs:  # unsigned: each PX4's telemetry before it had the key
            assert uav.link_refused["unsigned"] > 0 and uav.link_refused["bad_signature"] == 0
        assert (await http.post("/api/land")).status_code == 200
        status = await service.wait_for(http, in_mode(Mode.DISARMED), 90.0, "landed")
        status = await service.wait_for(http, all_disarmed, 10.0, "vehicles disarmed")
        assert all(position_m(uav.position)[2] < 0.15 for uav in status.uavs)
