"""The flight-mode table: refusals change nothing; abort, kill and faults end safe."""

from __future__ import annotations

import itertools

import pytest

from supervisor.flight.modes import (
    OPERATOR_REQUESTS,
    TRANSITIONS,
    Event,
    FlightEnding,
    FlightModes,
    Mode,
)


def test_nominal_flight() -> None:
    modes = FlightModes()
    for event, expected in [
        (Event.ARM, Mode.ARMED),
        (Event.TAKEOFF, Mode.TAKEOFF),
        (Event.AIRBORNE, Mode.HOVER),
        (Event.TRACK, Mode.TRACKING),
        (Event.HOLD, Mode.HOVER),
        (Event.LAND, Mode.LANDING),
        (Event.LANDED, Mode.DISARMING),
        (Event.DISARMED, Mode.DISARMED),
    ]:
        result = modes.handle(event, 1.0)
        assert result.accepted and modes.mode is expected


@pytest.mark.parametrize(("mode", "event"), list(itertools.product(Mode, OPERATOR_REQUESTS)))
def test_every_request_in_every_mode(mode: Mode, event: Event) -> None:
    modes = FlightModes(mode)
    result = modes.handle(event, 2.0)
    if event in ("abort", "kill"):
        assert result.accepted  # the way out is always open
        assert modes.mode in (
            Mode.ABORT,
            Mode.KILLED,
            Mode.DISARMED,
            Mode.DISARMING,
            Mode.PX4_LANDING,
        )
        assert modes.mode is not Mode.ABORT or mode.airborne
        # Blind, PX4's own landing is already the way out: an abort leaves it alone. Landed
        # and disarming, the abort's end is already under way.
        assert modes.mode is not Mode.PX4_LANDING or mode is Mode.PX4_LANDING
        assert modes.mode is not Mode.DISARMING or mode is Mode.DISARMING
    elif (mode, event) in TRANSITIONS:
        assert result.accepted and modes.mode is TRANSITIONS[(mode, event)]
    else:
        assert not result.accepted and modes.mode is mode and modes.changed_at_s == 0.0
        assert event in result.reason and mode.value in result.reason


@pytest.mark.parametrize("mode", list(Mode))
def test_a_fault_always_ends_in_a_safe_mode(mode: Mode) -> None:
    modes = FlightModes(mode)
    assert modes.handle(Event.FAULT, 3.0).accepted
    assert modes.mode in (Mode.ABORT, Mode.DISARMED, Mode.DISARMING, Mode.KILLED, Mode.PX4_LANDING)
    if mode is Mode.PX4_LANDING:
        assert modes.mode is Mode.PX4_LANDING  # nothing the supervisor flies is better
    elif mode is Mode.DISARMING:
        assert modes.mode is Mode.DISARMING  # on the ground: no abort would fly it again
    elif mode.airborne:
        assert modes.mode is Mode.ABORT


@pytest.mark.parametrize("mode", list(Mode))
def test_blind_hands_every_airborne_mode_to_px4s_landing(mode: Mode) -> None:
    modes = FlightModes(mode)
    result = modes.handle(Event.BLIND, 3.0)
    assert result.accepted is mode.airborne
    assert modes.mode is (Mode.PX4_LANDING if mode.airborne else mode)
    if mode.airborne:
        assert modes.handle(Event.LANDED, 4.0).accepted and modes.mode is Mode.DISARMED


FLIGHTS = {
    "landed": ([Event.LAND, Event.LANDED, Event.DISARMED], Mode.LANDING),
    "aborted": ([Event.ABORT, Event.LANDED, Event.DISARMED], Mode.ABORT),
    "landing, then aborted": ([Event.LAND, Event.ABORT, Event.LANDED, Event.DISARMED], Mode.ABORT),
    "aborted, then blind": ([Event.ABORT, Event.BLIND, Event.LANDED], Mode.PX4_LANDING),
    "killed": ([Event.KILL, Event.DISARM], Mode.KILLED),
}


@pytest.mark.parametrize("events, ending", FLIGHTS.values(), ids=FLIGHTS.keys())
def test_how_the_last_flight_ended_is_kept_until_the_next_arm(
    events: list[Event], ending: Mode
) -> None:
    modes = FlightModes()
    for t_s, event in enumerate([Event.ARM, Event.TAKEOFF, Event.AIRBORNE]):
        assert modes.handle(event, float(t_s)).accepted
    assert modes.last_flight is None
    for t_s, event in enumerate(events, start=10):
        assert modes.handle(event, float(t_s)).accepted
        assert (modes.last_flight is None) == (modes.mode is not Mode.DISARMED)
    assert modes.last_flight == FlightEnding(ending, 9.0 + len(events))
    modes.handle(Event.FAULT, 30.0)  # on the ground: stays disarmed, the record too
    assert modes.last_flight == FlightEnding(ending, 9.0 + len(events))
    assert modes.handle(Event.ARM, 31.0).accepted
    assert modes.last_flight is None
    assert modes.handle(Event.DISARM, 32.0).accepted
    assert modes.last_flight is None  # armed and disarmed on the ground: no flight


def test_a_flight_under_way_when_the_modes_were_made_is_not_theirs() -> None:
    modes = FlightModes(Mode.PX4_LANDING)  # a restarted flight process waits for its vehicles
    modes.handle(Event.LANDED, 1.0)
    assert modes.mode is Mode.DISARMED and modes.last_flight is None
