"""The ground station's loss as each agent decides it, time an argument."""

from __future__ import annotations

from supervisor.agents.liveness import GroundAction, GroundWatch

HOLD_S = 3.0


def test_heard_it_flies_lost_it_holds_then_lands() -> None:
    watch = GroundWatch().heard(True, 10.0)
    assert watch.action(10.0, HOLD_S) is GroundAction.FLY
    watch = watch.heard(False, 11.0)
    assert watch.action(11.0, HOLD_S) is GroundAction.HOLD
    watch = watch.heard(False, 13.9)  # still lost: the loss dates from when it began
    assert watch.action(13.9, HOLD_S) is GroundAction.HOLD
    assert watch.action(14.0, HOLD_S) is GroundAction.LAND


def test_heard_again_the_hold_ends_and_a_new_loss_counts_afresh() -> None:
    watch = GroundWatch().heard(False, 0.0).heard(True, 2.0)
    assert watch.action(2.0, HOLD_S) is GroundAction.FLY
    watch = watch.heard(False, 5.0)
    assert watch.action(7.9, HOLD_S) is GroundAction.HOLD
    assert watch.action(8.0, HOLD_S) is GroundAction.LAND
