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
