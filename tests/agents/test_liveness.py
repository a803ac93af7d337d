"""The ground station's loss as each agent decides it, time an argument."""

from __future__ import annotations

from supervisor.agents.liveness import GroundAction, GroundWatch, behind_the_peers
from supervisor.agents.messages import AgentTick, VehicleReport
from supervisor.flight.modes import Mode

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


def _tick(queued: int, finished: int) -> AgentTick:
    own = VehicleReport(connected=True, armed=True, px4_mode="OFFBOARD")
    return AgentTick(
        vehicle=2,
        sent_s=0.0,
        tick=0,
        mode=Mode.TRACKING,
        own=own,
        setpoints_queued=queued,
        setpoints_finished=finished,
    )


def test_an_agent_behind_a_peer_given_the_same_setpoints_ends_its_own() -> None:
    assert behind_the_peers(5, 2, [_tick(5, 3)])
    assert not behind_the_peers(5, 3, [_tick(5, 3), None])  # level, or a peer not heard
    assert not behind_the_peers(5, 4, [_tick(5, 3)])  # ahead: the peer follows
    # A peer not yet given what this agent was (a request on its way): not compared.
    assert not behind_the_peers(7, 2, [_tick(5, 3)])
