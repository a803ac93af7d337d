"""How the processes that fly use the CPU: real-time priority for the control loop, and
BLAS on one thread.

A tick's matrices are small; a second BLAS thread only adds a hand-over per call, and that
helper thread is an ordinary thread that the API's load can keep waiting
(docs/reference/qp-solvers.md measures ~10× slower p50 on two cores with BLAS threads left on).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import re
import resource
from pathlib import Path

import setproctitle
from threadpoolctl import threadpool_limits

REALTIME_PRIORITY = 10
CAP_SYS_NICE = 23
PR_SET_NAME = 15


def raise_priority(priority: int = REALTIME_PRIORITY) -> str:
    """Run the calling process ahead of everything else where the OS allows it:
    SCHED_FIFO ``priority`` (as root; the control loop sleeps most of each period, so it
    cannot starve the machine), else a lower niceness, else as is. Returns what it got, for
    the operator."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f"real-time priority (SCHED_FIFO {priority})"
    except (PermissionError, AttributeError, OSError):
        pass
    try:
        os.nice(-5)
        return "niceness -5"
    except (PermissionError, OSError):
        return "normal priority (no permission for more)"


def can_raise_priority() -> bool:
    """Whether ``raise_priority`` gets more than normal priority in this process's place:
    root or CAP_SYS_NICE (real-time or a lower niceness), or a real-time priority limit."""
    if resource.getrlimit(resource.RLIMIT_RTPRIO)[0] > 0:
        return True
    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        return os.geteuid() == 0
    match = re.search(r"^CapEff:\s*([0-9a-fA-F]+)$", status, re.MULTILINE)
    return bool(match and int(match.group(1), 16) >> CAP_SYS_NICE & 1)


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Limit every BLAS/OpenMP pool of this process to one thread, for good: those loaded
    now, and through the environment those loaded later (scipy brings an OpenBLAS of its
    own on first use, whose idle threads spun a second core in the flight process)."""
    for variable in BLAS_THREAD_VARIABLES:
        os.environ[variable] = "1"
    threadpool_limits(limits=1)


def title_process(role: str) -> None:
    """Title this process ``uavbar-supervisor ROLE`` (what ``ps -o args`` shows) and name it
    ``uavbar-ROLE`` (the command name ``top`` and ``pgrep -x`` see)."""
    setproctitle.setproctitle(f"uavbar-supervisor {role}")
    name_process(f"uavbar-{role}")  # after the title, which sets a truncated name of its own


def name_process(name: str) -> None:
    """Give this process a name ``ps``/``top`` show (Linux: the 15-character command name),
    so that an operator can tell the flight process from the world at a glance."""
    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_NAME, name.encode()[:15], 0, 0, 0)
