"""Every operator request in every mode: accepted where the mode table allows it, else
refused naming the mode, what the system is doing and the next step."""

from __future__ import annotations

import time

import pytest

from controllers.formation_equilibria import FormationReference, formation_equilibrium
from supervisor.app.assembly import flight_core_from_config
from supervisor.app.config import load_config
from supervisor.flight.core import TAKES_SETPOINTS, FlightCore
from supervisor.flight.estimation import Estimate
from supervisor.flight.modes import TRANSITIONS, Event, Mode
from supervisor.flight.refusals import STATE, Request
from supervisor.flight.setpoints import Setpoint, SetpointRefusedError
from tests.conftest import CONFIGS, resting_estimate

CONFIG = load_config(CONFIGS / "sim.toml")

# What the next step must say, in the operator's words, for each refused pair.
NEXT_STEP_SAYS: dict[tuple[Mode, Request], str] = {
    (Mode.DISARMED, Request.DISARM): "disarmed already",
    (Mode.DISARMED, Request.TAKEOFF): "arm first",
    (Mode.DISARMED, Request.LAND): "on the ground",
    (Mode.DISARMED, Request.SETPOINT): "arm first",
    (Mode.ARMED, Request.ARM): "take off, or disarm",
    (Mode.ARMED, Request.LAND): "disarm instead",
    (Mode.TAKEOFF, Request.ARM): "wait for the hover",
    (Mode.TAKEOFF, Request.TAKEOFF): "wait for the hover",
    (Mode.TAKEOFF, Request.DISARM): "land first",
    (Mode.HOVER, Request.ARM): "flying already",
    (Mode.HOVER, Request.TAKEOFF): "airborne already",
    (Mode.HOVER, Request.DISARM): "land first",
    (Mode.TRACKING, Request.ARM): "flying already",
    (Mode.TRACKING, Request.TAKEOFF): "airborne already",
    (Mode.TRACKING, Request.DISARM): "land first",
    (Mode.LANDING, Request.ARM): "wait until it has landed and disarmed",
    (Mode.LANDING, Request.TAKEOFF): "wait until it has landed and disarmed",
    (Mode.LANDING, Request.LAND): "landing already",
    (Mode.LANDING, Request.DISARM): "disarms itself on the ground",
    (Mode.LANDING, Request.SETPOINT): "wait until it has landed and disarmed",
    (Mode.ABORT, Request.ARM): "wait until it has landed and disarmed",
    (Mode.ABORT, Request.TAKEOFF): "wait until it has landed and disarmed",
    (Mode.ABORT, Request.LAND): "the abort lands it already",
    (Mode.ABORT, Request.DISARM): "disarms itself on the ground",
    (Mode.ABORT, Request.SETPOINT): "wait until it has landed and disarmed",
    (Mode.DISARMING, Request.ARM): "wait until every vehicle shows disarmed",
    (Mode.DISARMING, Request.TAKEOFF): "wait until every vehicle shows disarmed",
    (Mode.DISARMING, Request.LAND): "landed already",
    (Mode.DISARMING, Request.DISARM): "disarming already",
    (Mode.DISARMING, Request.SETPOINT): "wait until every vehicle shows disarmed",
    (Mode.PX4_LANDING, Request.ARM): "wait until every PX4 has landed and disarmed",
    (Mode.PX4_LANDING, Request.TAKEOFF): "wait until every PX4 has landed and disarmed",
    (Mode.PX4_LANDING, Request.LAND): "each PX4 lands already",
    (Mode.PX4_LANDING, Request.DISARM): "disarms on the ground by itself",
    (Mode.PX4_LANDING, Request.SETPOINT): "wait until every PX4 has landed and disarmed",
    (Mode.KILLED, Request.ARM): "disarm to acknowledge the kill",
    (Mode.KILLED, Request.TAKEOFF): "disarm to acknowledge the kill",
    (Mode.KILLED, Request.LAND): "disarm to acknowledge the kill",
    (Mode.KILLED, Request.SETPOINT): "disarm to acknowledge the kill",
}


def hovering(core: FlightCore) -> Estimate:
    x = formation_equilibrium(core.params, FormationReference((0.0, 0.0, 1.0), 0.0, (0.0, 0.0))).x
    estimate = Estimate(x, 0.005, ())
    core.start_in_hover(estimate, 0.0, (0.02, 0.05, 0.05))
    return estimate


def land_on_the_ground(core: FlightCore) -> None:
    """Land from the hover with every body measured resting: the landing ends on the
    ground, waiting for the vehicles to disarm."""
    core.request(Event.LAND, 0.0)
    resting = resting_estimate(core.params)
    for tick in range(1, 500):
        core.tick(0.02 * tick, resting)
        if core.modes.mode is not Mode.LANDING:
            return


def core_in(mode: Mode) -> FlightCore:
    """A core brought into ``mode`` the way a flight gets there."""
    core = flight_core_from_config(CONFIG, clock=time.perf_counter)
    core.tick(0.0, resting_estimate(core.params))
    if mode is Mode.ARMED:
        core.request(Event.ARM, 0.0)
    elif mode is Mode.TAKEOFF:
        core.request(Event.ARM, 0.0)
        core.request(Event.TAKEOFF, 0.0)
    elif mode is Mode.KILLED:
        core.request(Event.KILL, 0.0)
    elif mode is not Mode.DISARMED:
        estimate = hovering(core)
        if mode is Mode.TRACKING:
            core.queue_setpoints([Setpoint((0.3, 0.0, 1.0))])
            core.tick(0.0, estimate)
        elif mode in (Mode.LANDING, Mode.ABORT):
            core.request(Event.LAND if mode is Mode.LANDING else Event.ABORT, 0.0)
        elif mode is Mode.DISARMING:
            land_on_the_ground(core)
        elif mode is Mode.PX4_LANDING:
            core.hand_over_to_px4("the test's reason", 0.0)
    assert core.modes.mode is mode
    return core


def answer(core: FlightCore, request: Request) -> str | None:
    """None when ``request`` is taken, else the refusal's reason."""
    if request is Request.SETPOINT:
        try:
            core.queue_setpoints([Setpoint((0.0, 0.0, 1.0))])
        except SetpointRefusedError as refused:
            return str(refused)
        return None
    result = core.request(Event(request.value), 0.02)
    return None if result.accepted else result.reason


@pytest.mark.parametrize("request_", list(Request))
@pytest.mark.parametrize("mode", list(Mode))
def test_every_request_in_every_mode_is_taken_or_says_why_and_what_next(
    mode: Mode, request_: Request
) -> None:
    allowed = (
        mode in TAKES_SETPOINTS
        if request_ is Request.SETPOINT
        else (mode, Event(request_.value)) in TRANSITIONS
    )
    reason = answer(core_in(mode), request_)
    if allowed:
        assert reason is None
        assert (mode, request_) not in NEXT_STEP_SAYS
        return
    assert reason is not None
    assert f"mode '{mode.value}'" in reason and STATE[mode] in reason, reason
    assert NEXT_STEP_SAYS[(mode, request_)] in reason, reason


@pytest.mark.parametrize("mode", list(Mode))
def test_abort_kill_and_the_controller_are_taken_in_every_mode(mode: Mode) -> None:
    for event in (Event.ABORT, Event.KILL):
        assert core_in(mode).request(event, 0.02).accepted
    assert core_in(mode).set_controller("decentralized", 0.02).accepted
