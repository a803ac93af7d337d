"""``uavbar-supervisor mocap record`` and ``mocap replay``: a QTM RT stream to a file and
back (``mocap.recorder``, ``mocap.recording``, ``sim.qtm_replay``)."""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Callable
from pathlib import Path

from mocap.recorder import RecordingError, record_stream
from mocap.recording import read_recording, write_recording
from sim.qtm_replay import QtmReplayServer

Say = Callable[[str], None]


def run_record(host: str, port: int, duration_s: float, out: Path, say: Say) -> int:
    """Record ``duration_s`` of ``host:port`` into ``out``; 0 done, 1 failed (``say``
    gets what happened, one line)."""
    try:
        recording = asyncio.run(record_stream(host, port, duration_s))
    except (OSError, TimeoutError, RecordingError) as error:
        say(f"mocap record: {host}:{port}: {error or type(error).__name__}")
        return 1
    write_recording(recording, out)
    frames = sum(1 for _ in recording.frames())
    say(
        f"{out}: {len(recording.packets)} packets ({frames} frames of "
        f"{', '.join(recording.body_names)}) over {recording.duration_s:.1f} s"
    )
    return 0 if recording.packets else 1


async def _serve(path: Path, host: str, port: int, loop: bool, say: Say) -> None:
    recording = read_recording(path)
    async with QtmReplayServer(recording, loop=loop, host=host, port=port) as server:
        say(
            f"replaying {path} ({len(recording.packets)} packets, {recording.duration_s:.1f} s"
            f"{', looped' if loop else ''}) as QTM RT on {host}:{server.port}: it starts with "
            "the first client's StreamFrames"
        )
        stop = asyncio.Event()
        running = asyncio.get_running_loop()
        for sig in (signal.SIGINT, signal.SIGTERM):
            running.add_signal_handler(sig, stop.set)
        done = asyncio.create_task(server.finished.wait())
        stopped = asyncio.create_task(stop.wait())
        await asyncio.wait({done, stopped}, return_when=asyncio.FIRST_COMPLETED)
        for task in (done, stopped):
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        say(f"replayed {server.passes} pass(es), {server.frames_sent} packets sent")


def run_replay(path: Path, host: str, port: int, loop: bool, say: Say) -> int:
    """Serve the recording at ``path`` until it has played (or, with ``loop``, until
    SIGINT/SIGTERM); 0 done, 1 failed."""
    try:
        asyncio.run(_serve(path, host, port, loop, say))
    except OSError as error:
        say(f"mocap replay: {host}:{port}: {error}")
        return 1
    return 0
