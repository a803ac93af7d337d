"""How fast the terminal client answers: ``uavbar-supervisor status`` with no service
running (it exits 3) against ``python -c pass`` in the same run, wall time of each whole
process, interleaved so that both see the same load.

Run: ``python -m benchmarks.cli_startup [--runs N] [--json]``.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _free_port() -> int:
    """A port nothing listens on (bound, then closed)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _wall_time_s(command: list[str], env: dict[str, str], expected: int) -> float:
    started = time.perf_counter()
    result = subprocess.run(command, env=env, capture_output=True, check=False)
    took_s = time.perf_counter() - started
    if result.returncode != expected:
        raise RuntimeError(f"{command} exited {result.returncode}: {result.stderr.decode()}")
    return took_s


def _summary(times_s: list[float]) -> dict[str, float]:
    ordered = sorted(times_s)
    return {
        "median_s": statistics.median(ordered),
        "p90_s": ordered[min(len(ordered) - 1, round(0.9 * (len(ordered) - 1)))],
        "min_s": ordered[0],
    }


def run(runs: int) -> dict[str, object]:
    """Median, p90 and min wall time of both commands over ``runs`` interleaved runs."""
    with tempfile.TemporaryDirectory() as runtime:
        # No discovery file of a serve running on this machine is found, and no service
        # answers at the URL: the client does all it does before it reports "unreachable".
        env = {
            **os.environ,
            "PYTHONPATH": str(ROOT),
            "XDG_RUNTIME_DIR": runtime,
            "UAVBAR_URL": f"http://127.0.0.1:{_free_port()}",
        }
        status_command = [sys.executable, "-m", "supervisor.cli.main", "status"]
        baseline_command = [sys.executable, "-c", "pass"]
        status_s, baseline_s = [], []
        for _ in range(runs):
            baseline_s.append(_wall_time_s(baseline_command, env, 0))
            status_s.append(_wall_time_s(status_command, env, 3))
    status, baseline = _summary(status_s), _summary(baseline_s)
    return {
        "runs": runs,
        "status": status,
        "python_pass": baseline,
        "status_over_baseline_s": status["median_s"] - baseline["median_s"],
        "load_average": os.getloadavg()[0],
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20, help="runs of each (default: 20)")
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    result = run(max(1, args.runs))
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"{result['runs']} runs each, load average {result['load_average']:.2f}")
    for name in ("status", "python_pass"):
        figures = result[name]
        assert isinstance(figures, dict)
        label = "uavbar-supervisor status (exit 3)" if name == "status" else "python -c pass"
        print(
            f"  {label:34s} median {figures['median_s'] * 1e3:6.0f} ms, "
            f"p90 {figures['p90_s'] * 1e3:6.0f} ms, min {figures['min_s'] * 1e3:6.0f} ms"
        )
    over_s = result["status_over_baseline_s"]
    assert isinstance(over_s, float)
    print(f"  status over the interpreter's own start: {over_s * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
