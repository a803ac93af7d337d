"""What every child process of ``serve`` does the same way: stop on SIGTERM or when its
parent goes away, and leave SIGINT (Ctrl-C reaches the whole process group) to the parent."""

from __future__ import annotations

import asyncio
import signal
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from multiprocessing.connection import Connection


@asynccontextmanager
async def stop_event(parent: Connection) -> AsyncIterator[asyncio.Event]:
    """An event set on SIGTERM or when ``parent`` closes its end of the pipe (readable at
    EOF), for the duration of the block."""
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)
    loop.add_signal_handler(signal.SIGINT, lambda: None)  # the parent decides
    loop.add_reader(parent.fileno(), stop.set)
    try:
        yield stop
    finally:
        loop.remove_reader(parent.fileno())
