"""Flight phases move only along their table; the flights in the suite stay on it."""

from __future__ import annotations

import pytest

from supervisor.errors import LocalError
from supervisor.flight.phases import PHASE_TRANSITIONS, Phase, PhaseError, next_phase


def test_the_ways_through_a_flight_are_in_the_table() -> None:
    flight = [Phase.GROUND, Phase.CLIMB, Phase.LIFT, Phase.HOVER, Phase.TRACKING, Phase.HOVER]
    flight += [Phase.LOWER, Phase.DESCEND, Phase.GROUND]
    phase = flight[0]
    for target in flight[1:]:
        phase = next_phase(phase, target)
    assert phase is Phase.GROUND
    assert next_phase(Phase.CLIMB, Phase.DESCEND) is Phase.DESCEND  # abort before lifting


@pytest.mark.parametrize(
    ("current", "target"),
    [
        (Phase.GROUND, Phase.LOWER),
        (Phase.GROUND, Phase.LIFT),
        (Phase.DESCEND, Phase.HOVER),
        (Phase.LOWER, Phase.HOVER),
        (Phase.CLIMB, Phase.HOVER),
    ],
)
def test_a_change_outside_the_table_is_a_local_error(current: Phase, target: Phase) -> None:
    assert (current, target) not in PHASE_TRANSITIONS
    with pytest.raises(PhaseError, match="no phase change") as raised:
        next_phase(current, target)
    assert isinstance(raised.value, LocalError)


def test_every_phase_can_reach_the_ground() -> None:
    assert all((phase, Phase.GROUND) in PHASE_TRANSITIONS for phase in Phase)
