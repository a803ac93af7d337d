"""What a real PX4 SITL saw of its sensors and what its rate loop did, from the ULogs it
keeps with ``sim.px4_ulog = true`` (read with pyulog, PX4's own ULog parser).

Per log: the gyro samples' rate and their spacing as PX4 stamped them (p50 and the
smallest; ``< 1 ms``: how many came less than a millisecond after the one before, which
is what a burst of samples looks like), the largest angular acceleration PX4 computed
for its D term (roll and pitch), the largest roll/pitch torque setpoint (normalized: 1
is the mixer's limit) and the largest roll/pitch rate. A sensor burst shows as samples
microseconds apart with an angular acceleration in the hundreds or thousands of rad/s²
(docs/results.md, issue 31).

Run: ``python -m benchmarks.px4_ulog LOG.ulg ... [--json]`` (a serve's logs:
``LOG_FOLDER/px4/uav*/log/*/*.ulg``).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from pyulog import ULog

TOPICS = ["sensor_combined", "vehicle_angular_velocity", "vehicle_torque_setpoint"]
BURST_GAP_MS = 1.0


def ulog_figures(path: Path) -> dict[str, float]:
    """The figures of one ULog (see the module's docstring)."""
    data = {d.name: d.data for d in ULog(str(path), TOPICS).data_list if d.multi_id == 0}
    sensors = data["sensor_combined"]
    rates = data["vehicle_angular_velocity"]
    torques = data["vehicle_torque_setpoint"]
    stamps_s = sensors["timestamp"] / 1e6
    gaps_ms = sensors["gyro_integral_dt"][1:] / 1e3
    roll_pitch = ("[0]", "[1]")
    return {
        "sensor_rate_hz": (len(stamps_s) - 1) / float(stamps_s[-1] - stamps_s[0]),
        "gyro_gap_p50_ms": float(np.median(gaps_ms)),
        "gyro_gap_min_ms": float(gaps_ms.min()),
        "gyro_gaps_under_1ms": int(np.sum(gaps_ms < BURST_GAP_MS)),
        "max_angular_acceleration_radps2": max(
            float(np.abs(rates[f"xyz_derivative{axis}"]).max()) for axis in roll_pitch
        ),
        "max_torque_setpoint": max(float(np.abs(torques[f"xyz{a}"]).max()) for a in roll_pitch),
        "max_rate_radps": max(float(np.abs(rates[f"xyz{axis}"]).max()) for axis in roll_pitch),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("logs", nargs="+", type=Path, metavar="LOG.ulg")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    figures = {str(path): ulog_figures(path) for path in args.logs}
    if args.json:
        print(json.dumps(figures))
        return 0
    print(
        f"{'log':<48} {'Hz':>5} {'p50 ms':>7} {'min ms':>7} {'< 1 ms':>6} "
        f"{'dω/dt max':>10} {'torque max':>10} {'rate max':>8}"
    )
    for path, f in figures.items():
        print(
            f"{path[-48:]:<48} {f['sensor_rate_hz']:5.0f} {f['gyro_gap_p50_ms']:7.2f} "
            f"{f['gyro_gap_min_ms']:7.3f} {f['gyro_gaps_under_1ms']:6d} "
            f"{f['max_angular_acceleration_radps2']:10.0f} {f['max_torque_setpoint']:10.2f} "
            f"{f['max_rate_radps']:8.2f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
