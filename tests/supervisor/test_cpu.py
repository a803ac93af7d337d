"""Whether a process can raise its priority, as the API process asks before it nices itself
(supervisor/app/api_process.py)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from supervisor.runtime.cpu import can_raise_priority

ROOT = Path(__file__).resolve().parents[2]
ASK = "from supervisor.runtime.cpu import can_raise_priority; print(can_raise_priority())"


def test_root_can_and_an_unprivileged_user_cannot() -> None:
    if os.geteuid() != 0 or shutil.which("setpriv") is None:
        pytest.skip("needs root and setpriv to run the question as another user")
    assert can_raise_priority()
    unprivileged = subprocess.run(
        [
            "setpriv",
            "--reuid=65534",
            "--regid=65534",
            "--clear-groups",
            "--inh-caps=-all",
            "--bounding-set=-sys_nice",
            sys.executable,
            "-c",
            ASK,
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=60,
        check=True,
    )
    assert unprivileged.stdout.strip() == "False", unprivileged


def test_blas_loaded_after_the_limit_runs_on_one_thread_too() -> None:
    """scipy brings an OpenBLAS of its own on first use: limited only when it was already
    loaded, its idle threads spun a second core in the flight process."""
    program = (
        "from supervisor.runtime.cpu import single_threaded_blas; single_threaded_blas(); "
        "import scipy.linalg; from threadpoolctl import threadpool_info; "
        "print(sorted({pool['num_threads'] for pool in threadpool_info()}))"
    )
    environment = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    pools = subprocess.run(
        [sys.executable, "-c", program],
        cwd=ROOT,
        env=environment,
        capture_output=True,
        text=True,
        check=True,
    )
    assert pools.stdout.strip() == "[1]"
