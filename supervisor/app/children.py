"""``serve``'s child processes: start one, notice at once when it ends, start it again.

Each child gets a lifeline pipe: ``serve`` holds one end, and the child stops (landing
first, for the flight process) when that end closes, so nothing outlives ``serve``. A child
that ends while ``serve`` is not stopping is reported and, when it is restartable, started
again — at most ``MAX_RESTARTS`` times a minute, so that one that dies at start does not
spin.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess

log = logging.getLogger(__name__)

SPAWN = multiprocessing.get_context("spawn")
MAX_RESTARTS = 5
RESTART_WINDOW_S = 60.0
# A signal to the whole process group (``timeout``, a service manager) ends the children
# and serve at once, in any order: wait this long before deciding it was a death.
RESTART_DELAY_S = 0.3

Lifeline = multiprocessing.connection.Connection
# Starts the child (the argument: why it is started again, None the first time) and returns
# it with serve's end of its lifeline.
Starter = Callable[[str | None], tuple[BaseProcess, Lifeline]]


def start_deaf_to_ctrl_c(process: BaseProcess) -> None:
    """Start ``process`` with SIGINT blocked, as a spawned child inherits it across exec:
    Ctrl-C reaches the whole process group, and a child still importing would die of it
    before it could leave SIGINT to serve (``ignore_ctrl_c``). Blocked in the calling
    thread only, so serve's own Ctrl-C waits, pending, until the child is started."""
    blocked = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        process.start()
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)


def ignore_ctrl_c() -> None:
    """In a child started by ``start_deaf_to_ctrl_c``: SIGINT ignored, then unblocked (a
    Ctrl-C that came meanwhile is dropped; serve had it too, and decides)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


def exit_text(process: BaseProcess) -> str:
    """How a process ended, in words (``exitcode`` -N: killed by signal N)."""
    code = process.exitcode
    if code is not None and code < 0:
        return f"killed by {signal.Signals(-code).name}"
    return f"exit status {code}"


@dataclass
class Child:
    """One of ``serve``'s processes, started by ``starter``; ``on_exit`` is told how it
    ended (before any restart)."""

    name: str
    starter: Starter
    restartable: bool
    on_exit: Callable[[Child, str], None] = lambda child, how: None
    process: BaseProcess | None = None
    lifeline: Lifeline | None = None
    restarts: int = 0
    last_exit: str | None = None  # how it ended last ("killed by SIGKILL"), for the status
    stopped: bool = False  # serve stops it on purpose: not restarted
    _recent: deque[float] = field(default_factory=deque)

    def start(self, because: str | None = None) -> None:
        self.process, self.lifeline = self.starter(because)
        asyncio.get_running_loop().add_reader(self.process.sentinel, self._ended)

    @property
    def alive(self) -> bool:
        return self.process is not None and self.process.is_alive()

    def _ended(self) -> None:
        assert self.process is not None
        asyncio.get_running_loop().remove_reader(self.process.sentinel)
        self.process.join()
        self._close_lifeline()
        how = exit_text(self.process)
        asyncio.get_running_loop().call_later(RESTART_DELAY_S, self._after_exit, how)

    def _after_exit(self, how: str) -> None:
        if self.stopped:
            return
        self.last_exit = how
        self.on_exit(self, how)
        if not self.restartable:
            return
        now = time.monotonic()
        while self._recent and self._recent[0] < now - RESTART_WINDOW_S:
            self._recent.popleft()
        if len(self._recent) >= MAX_RESTARTS:
            log.error(
                "the %s process died %d times within a minute: not started again",
                self.name,
                MAX_RESTARTS,
            )
            return
        self._recent.append(now)
        self.restarts += 1
        log.warning("starting the %s process again", self.name)
        self.start(f"the {self.name} process died ({how})")

    def _close_lifeline(self) -> None:
        if self.lifeline is not None:
            self.lifeline.close()
            self.lifeline = None

    def stop(self, timeout_s: float) -> None:
        """Stop it (SIGTERM, then SIGKILL after ``timeout_s``) and wait; blocking."""
        process = self.process
        if process is not None and process.is_alive() and process.pid is not None:
            os.kill(process.pid, signal.SIGTERM)
            process.join(timeout_s)
            if process.is_alive():
                process.kill()
                process.join(5.0)
        self._close_lifeline()


async def stop_child(child: Child, timeout_s: float) -> None:
    """Stop ``child`` for good (it is not restarted)."""
    child.stopped = True
    if child.process is not None and child.process.exitcode is None:
        asyncio.get_running_loop().remove_reader(child.process.sentinel)
    await asyncio.to_thread(child.stop, timeout_s)
