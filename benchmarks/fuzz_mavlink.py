"""Fuzz both MAVLink receive paths with random and mutated frames; print what happened.

    python -m benchmarks.fuzz_mavlink [--count 100000] [--seed 0] [--json]

Each case is a valid MAVLink 2 frame of a message the project exchanges (HEARTBEAT,
COMMAND_LONG/ACK, SET_ATTITUDE_TARGET, SET_ACTUATOR_CONTROL_TARGET, SET_MODE,
VISION_POSITION_ESTIMATE, ODOMETRY, STATUSTEXT, SYS_STATUS, ATTITUDE, with random field
values including NaN and inf) passed through one mutation: none, bit flips, truncation,
trailing bytes, a wrong length byte, a wrong checksum, random bytes, or two frames spliced.
Each case goes as one datagram to the simulated PX4 (``Px4Endpoint.handle_datagram``) and
to the supervisor's link (``MavlinkLink.handle_datagram``). Anything raised out of them is
*escaped*; every bad input must show up in their counters instead. Exit status 1 if any
exception escaped. ``run_fuzz`` is what the test suite calls with a few thousand cases.
"""

from __future__ import annotations

import argparse
import json
import math
import random
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sim.ports import AirframeState
from sim.px4_endpoint import Px4Endpoint
from supervisor.mavlink.link import LinkConfig, MavlinkLink

MUTATIONS = (
    "none",
    "flip",
    "truncate",
    "extend",
    "length",
    "checksum",
    "random_bytes",
    "splice",
)
SPECIAL = (math.nan, math.inf, -math.inf, 0.0, -0.0, 1e38, -1e38)


class _RestingAirframe:
    """An airframe standing on the ground (the endpoint asks for its state on commands)."""

    def state(self) -> AirframeState:
        return AirframeState(
            0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), True
        )

    def command(self, thrust_n: float, torque_nm: np.ndarray) -> None:
        return None


@dataclass
class FuzzCounts:
    """Outcomes over all cases, per receiver."""

    cases: int = 0
    escaped: int = 0
    by_mutation: dict[str, int] = field(default_factory=dict)
    px4: dict[str, int] = field(default_factory=dict)
    link: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.escaped == 0


def _value(rng: random.Random) -> float:
    return rng.choice(SPECIAL) if rng.random() < 0.1 else rng.uniform(-1e3, 1e3)


def random_frame(rng: random.Random, mav: mavlink.MAVLink) -> bytes:
    """One valid frame of a message the project sends or receives."""

    def f() -> float:
        return _value(rng)

    target = rng.choice((0, 1, 2, 255))
    kind = rng.randrange(11)
    if kind == 0:
        message = mav.heartbeat_encode(2, 12, rng.randrange(256), rng.getrandbits(32), 4)
    elif kind == 1:
        command = rng.choice((400, 176, 21, 185, 511, 512, 520, 31010, rng.randrange(65536)))
        params = [
            rng.choice((0.0, 1.0, 6.0, 21196.0)) if rng.random() < 0.5 else f() for _ in range(7)
        ]
        message = mav.command_long_encode(target, 1, command, 0, *params)
    elif kind == 2:
        message = mav.command_ack_encode(rng.choice((400, 176)), rng.randrange(8))
    elif kind == 3:
        mask = rng.choice((128, 0, 7, 255, rng.randrange(256)))
        message = mav.set_attitude_target_encode(
            0, target, 1, mask, [f(), f(), f(), f()], f(), f(), f(), f()
        )
    elif kind == 4:
        message = mav.set_actuator_control_target_encode(
            0, rng.choice((0, 0, 1, 3)), target, 1, [f() for _ in range(8)]
        )
    elif kind == 5:
        message = mav.set_mode_encode(target, rng.randrange(256), rng.getrandbits(32))
    elif kind == 6:
        message = mav.vision_position_estimate_encode(0, f(), f(), f(), f(), f(), f())
    elif kind == 7:
        message = mav.odometry_encode(
            0, 1, 12, f(), f(), f(), [f(), f(), f(), f()], f(), f(), f(), f(), f(), f(),
            [f()] * 21, [f()] * 21,
        )  # fmt: skip
    elif kind == 8:
        text = bytes(rng.randrange(256) for _ in range(rng.randrange(51)))
        message = mav.statustext_encode(rng.randrange(8), text)
    elif kind == 9:
        message = mav.sys_status_encode(0, 0, 0, 0, rng.randrange(65536), 0, 0, 0, 0, 0, 0, 0, 0)
    else:
        message = mav.attitude_encode(0, f(), f(), f(), f(), f(), f())
    data: bytes = message.pack(mav)
    return data


def mutate(rng: random.Random, data: bytes, mutation: str, other: bytes) -> bytes:
    buffer = bytearray(data)
    if mutation == "flip":
        for _ in range(rng.randint(1, 4)):
            position = rng.randrange(len(buffer))
            buffer[position] ^= 1 << rng.randrange(8)
    elif mutation == "truncate":
        del buffer[rng.randrange(len(buffer)) :]
    elif mutation == "extend":
        buffer += bytes(rng.randrange(256) for _ in range(rng.randint(1, 40)))
    elif mutation == "length" and len(buffer) > 1:
        buffer[1] = rng.randrange(256)
    elif mutation == "checksum" and len(buffer) > 2:
        buffer[-2] ^= 0xFF
    elif mutation == "random_bytes":
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 300)))
    elif mutation == "splice":
        cut = rng.randrange(len(buffer) + 1)
        return bytes(buffer[:cut]) + other[rng.randrange(len(other) + 1) :]
    return bytes(buffer)


def run_fuzz(
    count: int, seed: int = 0, progress: Callable[[int], None] | None = None
) -> FuzzCounts:
    """Feed ``count`` cases to fresh receivers; deterministic for a given (count, seed)."""
    rng = random.Random(seed)
    encoder = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    px4 = Px4Endpoint(0, _RestingAirframe(), local_port=0, client_port=0)
    link = MavlinkLink(LinkConfig(system_id=1, local_port=0))
    counts = FuzzCounts()
    for index in range(count):
        mutation = MUTATIONS[index % len(MUTATIONS)]
        encoder.srcSystem = rng.choice((1, 1, 1, 2, 255))
        case = mutate(rng, random_frame(rng, encoder), mutation, random_frame(rng, encoder))
        counts.cases += 1
        counts.by_mutation[mutation] = counts.by_mutation.get(mutation, 0) + 1
        for receiver in ("px4", "link"):
            try:
                if receiver == "px4":
                    px4.handle_datagram(case, index * 0.001)
                else:
                    link.handle_datagram(case, ("127.0.0.1", 14580))
            except Exception as error:  # counting escapes is the point
                counts.escaped += 1
                if len(counts.examples) < 5:
                    counts.examples.append(f"{type(error).__name__}: {error}: {case.hex()}")
        if progress is not None and (index + 1) % 10000 == 0:
            progress(index + 1)
    counts.px4 = {k: v for k, v in asdict(px4.counters).items() if k != "per_type"}
    counts.link = asdict(link.counters)
    return counts


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100_000, help="cases (default 100000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    counts = run_fuzz(args.count, args.seed)
    elapsed = time.perf_counter() - started
    if args.json:
        print(json.dumps({**asdict(counts), "seconds": elapsed}))
    else:
        print(f"cases              {counts.cases} in {elapsed:.1f} s (seed {args.seed})")
        print(f"escaped exceptions {counts.escaped}")
        print("simulated PX4      " + ", ".join(f"{k} {v}" for k, v in counts.px4.items()))
        print("supervisor link    " + ", ".join(f"{k} {v}" for k, v in counts.link.items()))
        print("mutations          " + ", ".join(f"{k} {v}" for k, v in counts.by_mutation.items()))
        for example in counts.examples:
            print("example:", example[:300])
    return 0 if counts.ok else 1


if __name__ == "__main__":
    sys.exit(main())
