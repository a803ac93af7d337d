"""Shared fixtures: the paper's lab parameters and symmetric variants."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from controllers.formation_params import FormationParams, formation_from_bar
from controllers.params import UavParams
from geometry.state import payload_points
from supervisor.app.config import CONFIG_DIR, load_config
from supervisor.flight.estimation import Estimate

CONFIGS = CONFIG_DIR
# A solve is late by the wall clock (a fallback tick), which a loaded machine may make of any
# tick: tests that compare two simulated flights judge none late, so that only what they
# vary decides the flights (one pair differed in CI by one such tick).
NEVER_LATE = "mpc.late_after_s=60.0"
LAB_INERTIA = (0.0348, 0.0459, 0.0977)


@pytest.fixture(scope="session")
def lab_params() -> FormationParams:
    """The paper's lab (configs/kth_sml.toml): asymmetric bar, d1 = 0.705, d2 = 0.765."""
    return load_config(CONFIGS / "kth_sml.toml").system.to_params()


def symmetric_params(m_uav: float = 1.52, m_b: float = 0.41, d: float = 0.735) -> FormationParams:
    """A setup that satisfies Assumption 1 (Section VII's masses by default)."""
    uav = UavParams(m_uav, LAB_INERTIA)
    return formation_from_bar((uav, uav), m_b, d, d, m_b * (2 * d) ** 2 / 12.0, (1.0, 1.0), 9.81)


def uneven_params() -> FormationParams:
    """Everything different between the two sides: masses, arms, cable lengths."""
    return formation_from_bar(
        (UavParams(1.15, LAB_INERTIA), UavParams(1.4, (0.04, 0.05, 0.09))),
        0.39,
        0.6,
        0.87,
        0.0706,
        (0.9, 1.2),
        9.81,
    )


def hover_reference(params: FormationParams, z_m: float = 1.0) -> FormationReference:
    """The payload level at (0, 0, ``z_m``), every yaw 0, the cables vertical."""
    return FormationReference((0.0, 0.0, z_m), 0.0, (0.0,) * params.n_vehicles)


def resting_estimate(params: FormationParams) -> Estimate:
    """A fresh, healthy estimate of the system resting on the ground: the bar level at
    2 cm, each UAV standing on its own cable's attachment."""
    x = formation_equilibrium(params, hover_reference(params, 0.02)).x
    layout = params.layout
    for i, end in zip(
        layout.vehicles, payload_points(x, params.payload.attachments_m), strict=True
    ):
        x[layout.uav_slices(i)[0]] = end + np.array([0.0, 0.0, 0.05])
    return Estimate(x, 0.005, ())


# Tests on the wall clock (serve and its real-time processes, real PX4, a browser) run in two
# lanes, each an xdist group that one worker takes in turn: at most two of them at once,
# whatever the number of workers (`make test` runs pytest-xdist with --dist loadgroup). One
# lane took 23 minutes of the suite's 23 on 2 cores; once the world and the flight process
# took real-time priority only after their set-up, two `serve`s at once kept their ticks
# and frames (docs/safety.md: the hovers beside the suite), and two lanes take 16. The
# second lane (the browser, the OpenAPI contract, the wheel, signing) is about as long as
# the first. End-to-end modules are the ones at the top of tests/.
WALL_CLOCK_MODULES = {
    "tests/api/test_openapi_contract.py",
    "tests/sim/test_px4_mavsdk.py",
    "tests/supervisor/test_mavlink_px4.py",
    "tests/supervisor/test_foxglove_live.py",
}
SECOND_LANE_MODULES = {
    "tests/test_dashboard.py",
    "tests/test_service.py",
    "tests/api/test_openapi_contract.py",
    "tests/test_wheel.py",
    "tests/test_service_signing.py",
    "tests/test_formation_service.py",
    "tests/test_agents_faults.py",
}
BESIDE_THE_LANES = 3
# Pure computation on simulated time (the MPCs, closed-loop flights of the plant): never
# late for anything, so it may run niced beside the lanes. Other tests beside the lanes
# run a world or a client on the wall clock and keep their priority: niced, an in-process
# world stalled 240 ms beside two serves.
NICED_BESIDE_THE_LANES = (
    "tests/controllers/",
    "tests/supervisor/test_simulation.py",
    "tests/supervisor/test_descent.py",
    "tests/supervisor/test_large_theta.py",
)
NICE_OF_PURE_COMPUTATION = 10
TESTS = Path(__file__).parent
RERUN_REASON_LINES = 25  # of the first failure's report: its error and where


def _module(item: pytest.Item) -> str:
    return f"tests/{Path(item.path).relative_to(TESTS).as_posix()}"


def _on_the_wall_clock(item: pytest.Item) -> bool:
    marked = any(item.get_closest_marker(name) is not None for name in ("px4", "wall_clock"))
    return Path(item.path).parent == TESTS or _module(item) in WALL_CLOCK_MODULES or marked


def _lane(item: pytest.Item) -> int:
    """1 or 2 for a test on the wall clock (its lane), ``BESIDE_THE_LANES`` otherwise."""
    if not _on_the_wall_clock(item):
        return BESIDE_THE_LANES
    return 2 if _module(item) in SECOND_LANE_MODULES else 1


# Before xdist's own hook, which turns the marker into the group it schedules by: hooks of
# plugins registered later run first, and without tryfirst the marker came too late (every
# worker then ran serve-based tests at once).
@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    # The lanes first: xdist (`--no-loadscope-reorder`) hands out work units in collection
    # order, so each lane starts at once on a worker of its own and the third worker takes
    # the other modules; a lane queued behind them ended the run minutes late.
    items.sort(key=_lane)
    for item in items:
        lane = _lane(item)
        if lane != BESIDE_THE_LANES:
            item.add_marker(pytest.mark.xdist_group(f"wall_clock_{lane}"))
            # Run once more after a failure (pytest-rerunfailures; the summary counts reruns):
            # with the simulated QTM on this same computer, a loaded CI VM delays its frames
            # by 100 ms at times, which the supervisor rightly answers as blind (PX4 lands).
            item.add_marker(pytest.mark.flaky(reruns=1, reruns_delay=2))


@pytest.fixture(autouse=True)
def _yield_to_the_lanes(request: pytest.FixtureRequest) -> Iterator[None]:
    """Pure computation beside the lanes runs niced, so that the serves, browsers and
    clients of the two lanes keep the CPU they need while it soaks up what they leave;
    only as root (as CI runs), where the priority can be given back after the test."""
    niced = _module(request.node).startswith(NICED_BESIDE_THE_LANES)
    if os.geteuid() != 0 or not niced or _lane(request.node) != BESIDE_THE_LANES:
        yield
        return
    before = os.getpriority(os.PRIO_PROCESS, 0)
    os.setpriority(os.PRIO_PROCESS, 0, NICE_OF_PURE_COMPUTATION)
    try:
        yield
    finally:
        os.setpriority(os.PRIO_PROCESS, 0, before)


def pytest_collection_finish(session: pytest.Session) -> None:
    """Under ``--dist loadgroup`` every wall-clock test must carry its group in its id (what
    xdist schedules by): otherwise every worker may run a ``serve``-based test at once,
    which on a machine with more cores than lanes starve each other and fail as flaky."""
    if not session.config.getoption("loadgroup", default=False):
        return
    ungrouped = [i.nodeid for i in session.items if _on_the_wall_clock(i) and "@" not in i.nodeid]
    if ungrouped:
        raise pytest.UsageError(f"xdist would run {ungrouped[0]} outside its group")


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Why each rerun test failed the first time (the rerun plugin names it only), so that
    a CI log that passes on a rerun still tells what a loaded machine did to it."""
    reruns = terminalreporter.stats.get("rerun", [])
    if not reruns:
        return
    terminalreporter.section("why tests were rerun")
    for report in reruns:
        terminalreporter.write_line(f"{report.nodeid}:")
        lines = report.longreprtext.splitlines()
        for line in lines[-RERUN_REASON_LINES:]:
            terminalreporter.write_line(f"    {line}")
