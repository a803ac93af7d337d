"""A flight's mocap replayed on the flight's own clock, against what the flight logged (pure).

While a flight is logged the flight process records the stream as it receives it, beside
the log (``flight-….qtm.gz``: every datagram with its receive time), and the log's header
holds where the receiver and the fusion stood when the recording started
(``mocap_recording``). Replayed here the way the flight process took it — each datagram
through the client's receiving side at its receive time, the frames fused at the first
logged tick after they came, with the repeat refusal the tick logged — the estimate at each
tick is the one the flight used, bit for bit, as long as the fusion, its gate and the
receiver work as they did: a regression test of them on recorded flights
(``uavbar-supervisor mocap check LOG``). A recording cut short (the flight process killed,
the disk full) is compared over the ticks before its last packet only, and the comparison
says so. ``mocap replay`` serves the same file over the QTM RT protocol, where the arrival
times become the replaying machine's own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocap.client import FrameReceiver
from mocap.fusion import MocapFusion
from mocap.recording import Recording, read_recording
from supervisor.flight.estimation import BodyNames, Estimate, estimate_state
from supervisor.logs.flight_log import FlightLog, mocap_recording_path


@dataclass(frozen=True)
class ReplayComparison:
    """The replayed estimates against the logged ones: ``ticks`` compared of the log's
    ``logged_ticks`` (fewer when the recording was cut short), ``state_difference`` the
    largest |Δ| over every tick and state (a NaN where the other is not counts as infinite),
    ``age_difference_s`` the largest |Δ| of the mocap age, ``first_difference_s`` the
    first tick (since the log's first) where either exceeds ``tolerance``."""

    ticks: int
    logged_ticks: int
    state_difference: float
    age_difference_s: float
    tolerance: float
    first_difference_s: float | None

    @property
    def same(self) -> bool:
        return self.first_difference_s is None


def flight_recording(log: FlightLog) -> Recording:
    """The mocap recording made during ``log``'s flight. Raises ``ValueError`` when the
    flight recorded none (an older log, mocap over TCP) or the file is missing."""
    if "mocap_recording" not in log.header:
        raise ValueError(f"{log.path}: this flight recorded no mocap (no mocap_recording)")
    path = mocap_recording_path(log.path)
    if not path.is_file():
        raise ValueError(f"{log.path}: its mocap recording {path.name} is missing")
    return read_recording(path)


def replay_estimates(
    log: FlightLog, recording: Recording, fusion: MocapFusion, names: BodyNames
) -> list[Estimate]:
    """The estimate at each of ``log``'s ticks from ``recording``, taken as the flight
    process took it, starting from the log's ``mocap_recording`` state (``fusion``: a new
    fusion of the flight's config). Raises ``ValueError`` when ``names`` (the config's)
    name another number of UAVs than the log's."""
    if len(names.uavs) != log.layout.n_vehicles:
        raise ValueError(
            f"{log.path}: a flight of {log.layout.n_vehicles} UAVs, not the "
            f"{len(names.uavs)} of this setup"
        )
    receiver = FrameReceiver(recording.body_names, recording.component)
    try:
        start = log.header["mocap_recording"]
        fusion.restore(start["fusion"])
        receiver.resume(start["receiver"])
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(
            f"{log.path}: its mocap_recording header does not read ({error!r})"
        ) from error
    received_s = [recording.clock_start_s + p.arrival_s for p in recording.packets]
    estimates: list[Estimate] = []
    next_packet = 0
    for t_s, extra in zip(log.t_s.tolist(), log.extra, strict=True):
        while next_packet < len(received_s) and received_s[next_packet] <= t_s:
            receiver.receive_datagram(recording.packets[next_packet].data, received_s[next_packet])
            next_packet += 1
        fusion.refuse_repeats = bool(extra.get("repeats_refused", False))
        for frame in receiver.drain():
            fusion.update(frame)
        estimates.append(estimate_state(fusion.states(t_s), names))
    return estimates


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    """The largest |a − b|, NaN against NaN equal, NaN against a number infinite."""
    nan_a, nan_b = np.isnan(a), np.isnan(b)
    if np.any(nan_a != nan_b):
        return math.inf
    finite = ~nan_a
    return float(np.max(np.abs(a[finite] - b[finite]), initial=0.0))


def compare_with_log(
    log: FlightLog, estimates: list[Estimate], tolerance: float = 1e-9
) -> ReplayComparison:
    """``estimates`` (one per tick of ``log``) against the logged states and mocap ages."""
    state_max = age_max = 0.0
    first: float | None = None
    for k, estimate in enumerate(estimates):
        state = _difference(estimate.x, log.state[k])
        age = _difference(np.array([estimate.age_s]), np.array([log.mocap_age_ms[k] * 1e-3]))
        state_max, age_max = max(state_max, state), max(age_max, age)
        if first is None and (state > tolerance or age > tolerance):
            first = float(log.t_s[k] - log.t_s[0])
    return ReplayComparison(len(estimates), len(log.t_s), state_max, age_max, tolerance, first)


def recorded_ticks(log: FlightLog, recording: Recording) -> int:
    """How many of ``log``'s first ticks came before ``recording``'s last packet: all that a
    recording cut short still accounts for (a later tick may have fused packets it lost)."""
    if not recording.packets:
        return 0
    end_s = recording.clock_start_s + recording.packets[-1].arrival_s
    return int(np.searchsorted(log.t_s, end_s, side="left"))


def check_flight(
    log: FlightLog,
    fusion: MocapFusion,
    names: BodyNames,
    tolerance: float = 1e-9,
    recording: Recording | None = None,
) -> tuple[list[Estimate], ReplayComparison]:
    """Replay ``log``'s own recording (``recording`` when already read, else
    ``flight_recording``) and compare: every tick, or of a recording cut short the ticks it
    accounts for (``recorded_ticks``). Raises ``ValueError`` when it accounts for none."""
    if recording is None:
        recording = flight_recording(log)
    estimates = replay_estimates(log, recording, fusion, names)
    if recording.truncation is not None:
        estimates = estimates[: recorded_ticks(log, recording)]
        if not estimates:
            raise ValueError(
                f"{mocap_recording_path(log.path)}: truncated ({recording.truncation}) "
                "before the flight's first tick: nothing to compare"
            )
    return estimates, compare_with_log(log, estimates, tolerance)


def describe(path: Path, comparison: ReplayComparison) -> str:
    """One line for the operator."""
    c = comparison
    verdict = (
        "the same as logged"
        if c.same
        else f"NOT the same: first beyond {c.tolerance:g} {c.first_difference_s:.2f} s in"
    )
    ticks = (
        f"{c.ticks} ticks"
        if c.ticks == c.logged_ticks
        else f"{c.ticks} of {c.logged_ticks} ticks (the recording is truncated: the later "
        "ticks are not compared)"
    )
    return (
        f"{path.name}: {ticks} replayed from the flight's own mocap recording: "
        f"{verdict} (largest difference: state {c.state_difference:.3g}, "
        f"mocap age {c.age_difference_s:.3g} s)"
    )
