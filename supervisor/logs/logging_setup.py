"""How every process of the service logs: standard ``logging`` to stderr, one line per
record with the time, the process and the logger's name.

The flight process must never wait on a handler inside a tick (a terminal that is slow to
read, a full pipe): there the root logger only puts records on a queue
(``logging.handlers.QueueHandler``) and a listener thread writes them out.
"""

from __future__ import annotations

import logging
import logging.handlers
import queue
import sys
from collections.abc import Iterator
from contextlib import contextmanager

FORMAT = "%(asctime)s %(processName)s %(name)s %(levelname)s: %(message)s"
DATE_FORMAT = "%H:%M:%S"


def _stderr_handler() -> logging.Handler:
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(FORMAT, DATE_FORMAT))
    return handler


def configure_logging(level: int = logging.INFO) -> None:
    """Root logger to stderr (this process's only handler)."""
    root = logging.getLogger()
    root.handlers[:] = [_stderr_handler()]
    root.setLevel(level)


@contextmanager
def queued_logging(level: int = logging.INFO) -> Iterator[None]:
    """Within the block, log records go through a queue to a writer thread (the flight
    process: a tick never waits on a handler). Records left are written on exit."""
    records: queue.SimpleQueue[logging.LogRecord] = queue.SimpleQueue()
    listener = logging.handlers.QueueListener(records, _stderr_handler())
    root = logging.getLogger()
    root.handlers[:] = [logging.handlers.QueueHandler(records)]
    root.setLevel(level)
    listener.start()
    try:
        yield
    finally:
        listener.stop()
        root.handlers[:] = [_stderr_handler()]
