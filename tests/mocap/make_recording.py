"""Makes ``tests/data/hover-dropout.qtm.gz``: 20 s of the embedded simulator's QTM stream
during a hover, with 0.3 s of mocap silence in its middle, and what the live supervisor
did about it (``hover-dropout.live.json``: the flight log's first tick in PX4's landing,
on the same clock as the recording's arrival times, and the notice).

Run: ``python -m tests.mocap.make_recording`` (about a minute; needs nothing else running
on the machine's QTM and API ports it picks).
"""

from __future__ import annotations

import asyncio
import json
import sys
import tempfile
from pathlib import Path

from benchmarks.service import in_mode, running_service
from mocap.recorder import record_stream
from mocap.recording import write_recording
from supervisor.flight.modes import Mode
from supervisor.logs.flight_log import read_flight_log
from tests.test_faults_e2e import fault, qtm_address
from tests.test_service import TOKEN, flight_logs

DATA = Path(__file__).resolve().parents[1] / "data"
RECORDING = DATA / "hover-dropout.qtm.gz"
LIVE = DATA / "hover-dropout.live.json"
DURATION_S = 20.0
SILENCE_AT_S, SILENCE_S = 8.0, 0.3


async def make() -> None:
    with tempfile.TemporaryDirectory() as folder:
        async with running_service(TOKEN, Path(folder)) as service, service.client() as http:
            await service.take_off(http)
            await asyncio.sleep(2.0)  # a stable hover
            host, port = qtm_address(service)
            recording = asyncio.create_task(record_stream(host, port, DURATION_S))
            await asyncio.sleep(SILENCE_AT_S)
            await fault(http, kind="mocap_silent", duration_s=SILENCE_S)
            recorded = await recording
            await service.wait_for(http, in_mode(Mode.DISARMED), 60.0, "landed")
        [path] = flight_logs(Path(folder))
        log = read_flight_log(path)
    handed = log.modes.index("px4_landing")
    notices = [text for t, text in log.notices if t <= log.t_s[handed]]
    write_recording(recorded, RECORDING)
    LIVE.write_text(
        json.dumps(
            {
                "px4_landing_t_s": float(log.t_s[handed]) - recorded.clock_start_s,
                "mocap_age_ms": float(log.mocap_age_ms[handed]),
                "notice": notices[-1] if notices else None,
            },
            indent=2,
        )
        + "\n"
    )
    size = RECORDING.stat().st_size
    sys.stdout.write(f"{RECORDING}: {len(recorded.packets)} packets, {size} bytes\n")
    sys.stdout.write(LIVE.read_text())


if __name__ == "__main__":
    asyncio.run(make())
