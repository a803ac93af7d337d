"""The set-down's pacing: the rate its target descends at, and its hold while the lost
UAV's end falls (the flights themselves: test_fault_responses, test_agents_e2e)."""

from __future__ import annotations

import itertools

import pytest

from supervisor.flight.set_down import (
    BEHIND_MPS,
    FAR_FALLING_MPS,
    SetDownProfile,
    SetDownView,
)

DT_S = 0.02
ABORT_MPS = 0.4
ACCELERATION_MPS2 = 0.5
REST_Z_M = 0.01


def profile(start_z_m: float = 1.0, always_slower: bool = False) -> SetDownProfile:
    return SetDownProfile(start_z_m, ABORT_MPS, ACCELERATION_MPS2, always_slower)


def view(own_z_m: float, lost_z_m: float, lost_descent_mps: float = 0.0) -> SetDownView:
    return SetDownView(own_z_m, lost_z_m, lost_descent_mps, REST_Z_M)


def run(profile: SetDownProfile, seen: SetDownView, ticks: int) -> list[tuple[float, float]]:
    return [profile.step(seen, DT_S) for _ in range(ticks)]


@pytest.mark.parametrize(
    ("always_slower", "lost_z_m", "rate_mps"),
    [
        (False, 1.0, ABORT_MPS),  # level: the abort rate
        (False, 0.5, BEHIND_MPS),  # the lost end lower: slower
        (True, 1.0, BEHIND_MPS),  # an agent: always slower
    ],
)
def test_the_target_accelerates_to_its_rate_and_stops_at_rest(
    always_slower: bool, lost_z_m: float, rate_mps: float
) -> None:
    paced = profile(always_slower=always_slower)
    steps = run(paced, view(1.0, lost_z_m), 400)
    lowering = [speed for z, speed in steps if z > REST_Z_M]
    heights = [z for z, _ in steps]
    assert max(lowering) == pytest.approx(rate_mps)
    for before, after in itertools.pairwise(lowering):
        assert abs(after - before) <= ACCELERATION_MPS2 * DT_S + 1e-12
    for before, after in itertools.pairwise(heights):
        assert before - rate_mps * DT_S - 1e-12 <= after <= before
    assert heights[-1] == REST_Z_M and steps[-1][1] == 0.0  # at rest, the reference stops


def test_a_falling_lost_end_holds_the_target() -> None:
    paced = profile(always_slower=True)
    run(paced, view(1.0, 1.0), 50)  # lowering at the slower rate
    held_from_m = paced.target_z_m
    falling = view(paced.target_z_m, 0.6, FAR_FALLING_MPS + 0.3)
    steps = run(paced, falling, 50)
    assert paced.waiting
    assert steps[-1][1] == 0.0  # the target stopped, no faster than it may decelerate
    decelerating_m = BEHIND_MPS**2 / (2 * ACCELERATION_MPS2) + BEHIND_MPS * DT_S
    assert held_from_m - decelerating_m <= steps[-1][0] < held_from_m


def test_after_the_fall_it_goes_on_from_where_it_was_dragged() -> None:
    paced = profile(start_z_m=1.0, always_slower=True)
    run(paced, view(1.0, 0.6, FAR_FALLING_MPS + 0.3), 20)
    assert paced.waiting and paced.target_z_m == 1.0
    dragged_z_m = 0.8
    z, _ = paced.step(view(dragged_z_m, REST_Z_M, 0.0), DT_S)  # the lost end rests
    assert not paced.waiting
    assert z <= dragged_z_m  # no climb back to the held height


@pytest.mark.parametrize(
    ("lost_z_m", "lost_descent_mps"),
    [
        (REST_Z_M + 0.01, FAR_FALLING_MPS + 0.3),  # its end on the ground, its UAV still landing
        (0.6, FAR_FALLING_MPS - 0.05),  # lowered, not falling: a peer setting its end down
    ],
)
def test_no_hold_unless_the_lost_end_falls_off_the_ground(
    lost_z_m: float, lost_descent_mps: float
) -> None:
    paced = profile(always_slower=True)
    steps = run(paced, view(1.0, lost_z_m, lost_descent_mps), 50)
    assert not paced.waiting
    assert steps[-1][1] == pytest.approx(BEHIND_MPS)
