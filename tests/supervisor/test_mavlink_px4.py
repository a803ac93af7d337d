"""The MAVLink link against the real PX4 v1.15.4 firmware (SITL, SIH physics, no simulator).

The build is found as the embedded world finds it (``sim.px4_firmware.resolve_px4_dir``:
``UAVBAR_PX4_DIR``, else the cache filled from ../shared/px4/). Instance 7: PX4 sends
from UDP 14587 to 14547, system id 8. Each test starts a cold PX4 in its own working
directory and stops it after.
"""

from __future__ import annotations

import asyncio
import os
import re
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from px4_mavlink.events import EventCatalog
from sim.px4_firmware import FirmwareError, resolve_px4_dir
from supervisor.mavlink.link import LinkConfig, MavlinkLink
from supervisor.mavlink.parameters import MAV_PARAM_TYPE_INT32, MAV_PARAM_TYPE_REAL32
from supervisor.vehicles.sequences import apply_parameters, check_failsafe_parameters
from supervisor.vehicles.types import VehicleCommandError

pytestmark = pytest.mark.px4

INSTANCE = 7
SYSTEM_ID = INSTANCE + 1
API_PORT = 14540 + INSTANCE


def px4_dir() -> Path:
    try:
        return resolve_px4_dir(None)
    except FirmwareError as missing:
        pytest.skip(f"real PX4 firmware not available: {missing}")


def events_path(root: Path) -> Path:
    return root / "etc" / "extras" / "all_events.json.xz"


@pytest.fixture
def px4(tmp_path: Path) -> Iterator[Path]:
    """A cold PX4 SIH quadrotor on instance 7, working in ``tmp_path``; stopped after."""
    root = px4_dir()
    environment = {
        **os.environ,
        "PX4_SYS_AUTOSTART": "10040",
        "PX4_SIMULATOR": "sihsim",
        "PX4_SIM_MODEL": "sihsim_quadx",
    }
    with (tmp_path / "px4.log").open("wb") as log:
        process = subprocess.Popen(
            [str(root / "bin" / "px4"), "-d", "-i", str(INSTANCE), str(root / "etc")],
            cwd=tmp_path,
            env=environment,
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            yield root
        finally:
            process.send_signal(signal.SIGTERM)  # PX4 stops within ~2 s
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait(timeout=5)


async def test_the_link_with_real_px4(px4: Path) -> None:
    link = MavlinkLink(
        LinkConfig(
            system_id=SYSTEM_ID,
            local_host="127.0.0.1",
            local_port=API_PORT,
            ack_timeout_s=0.5,
            link_loss_s=0.5,  # far below PX4's heartbeat gaps: only the streams keep it alive
            events_path=str(events_path(px4)),
        )
    )
    await link.start()
    try:
        async with asyncio.timeout(20):
            while not link.connected:  # noqa: ASYNC110  (the link offers no event to wait on)
                await asyncio.sleep(0.02)

        # Liveness without heartbeat reliance: over 3 s the heartbeat (1 Hz) gets ≥ 0.9 s old
        # while the link, on a 0.5 s loss limit, never counts the vehicle lost.
        loop = asyncio.get_running_loop()
        heartbeat_ages, silences = [], []
        end = loop.time() + 3.0
        while loop.time() < end:
            now = time.monotonic()  # the link's clock
            heartbeat_ages.append(link.session.heartbeat_age_s(now))
            silences.append(link.session.silence_s(now))
            assert link.connected
            await asyncio.sleep(0.01)
        assert max(heartbeat_ages) >= 0.9 and max(silences) < 0.5
        view = link.view()
        assert view.px4_mode == "AUTO.LOITER" and not view.armed  # PX4's boot mode

        # Parameters: a REAL32 and a bytewise INT32, set and verified by PX4's echo.
        assert await link.read_parameter("COM_OF_LOSS_T") == 1.0
        assert link.parameters.known["COM_OF_LOSS_T"].param_type == MAV_PARAM_TYPE_REAL32
        assert await link.read_parameter("COM_OBL_RC_ACT") == 0
        assert link.parameters.known["COM_OBL_RC_ACT"].param_type == MAV_PARAM_TYPE_INT32
        expected = {"COM_OBL_RC_ACT": 4.0, "COM_OF_LOSS_T": 1.0}
        assert await check_failsafe_parameters((link,), expected) == [
            "vehicle 1: COM_OBL_RC_ACT is 0, expected 4"
        ]
        assert await apply_parameters((link,), {"COM_OBL_RC_ACT": 4}) == []
        assert await link.read_parameter("COM_OBL_RC_ACT") == 4
        assert await check_failsafe_parameters((link,), expected) == []

        # Arming seconds after a cold start: refused, with PX4's own words from its EVENT.
        try:
            await link.arm()
        except VehicleCommandError as refused:
            reason = str(refused)
        else:
            await link.kill()
            pytest.fail("PX4 armed seconds after a cold start")
        assert reason.startswith("command 400 temporarily rejected (Arming denied: ")

        def from_event() -> bool:  # PX4 also sends the words as STATUSTEXT, µs apart
            said = [t for t in link.session.texts if t.text.startswith("Arming denied")]
            return bool(said) and said[-1].source == "event"

        async with asyncio.timeout(1.0):
            while not from_event():  # noqa: ASYNC110
                await asyncio.sleep(0.01)
        assert link.counters.timesync_answered > 10  # PX4 asks at 10 Hz
        assert link.counters.bad_data == 0
    finally:
        await link.close()


def test_every_event_of_the_firmware_renders() -> None:
    """The firmware's whole catalog: each event's text from zeroed arguments, no template
    left behind (a placeholder or markup the renderer does not know)."""
    catalog = EventCatalog.load(events_path(px4_dir()))
    assert len(catalog.events) > 300
    leftovers = []
    for event_id, definition in catalog.events.items():
        text = catalog.text(event_id, bytes(40))
        assert text, definition.name
        if re.search(r"\{\d|<\w|\\", text):
            leftovers.append(f"{definition.name}: {text}")
    assert leftovers == []
    assert catalog.text(0x0102089D, b"") == "Arming denied: Resolve system health failures first"
