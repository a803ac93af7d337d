"""A peer's vehicle as an agent sees it: fresh ticks, a lost token, actions shown done."""

from __future__ import annotations

import asyncio

import pytest

from supervisor.agents.messages import AgentTick, VehicleReport
from supervisor.agents.peer_vehicle import PeerVehicle
from supervisor.flight.modes import Mode
from supervisor.vehicles.types import VehicleCommandError


class _Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def _tick(armed: bool = False, mode: str = "POSCTL", connected: bool = True) -> AgentTick:
    own = VehicleReport(connected=connected, armed=armed, px4_mode=mode)
    return AgentTick(vehicle=2, sent_s=0.0, tick=0, mode=Mode.DISARMED, own=own)


def test_a_peer_is_connected_while_its_ticks_are_fresh_and_its_vehicle_heard() -> None:
    clock = _Clock()
    peer = PeerVehicle(2, timeout_s=0.25, action_timeout_s=1.0, clock=clock)
    assert not peer.connected  # never heard
    peer.observe(_tick(armed=True, mode="OFFBOARD"))
    assert peer.connected
    view = peer.view()
    assert view.armed and view.px4_mode == "OFFBOARD"
    clock.now_s += 0.3
    assert not peer.connected and peer.view().px4_mode == "unknown"
    peer.observe(_tick(connected=False))
    assert not peer.connected  # heard, but its own link to its vehicle is lost


def test_a_lost_liveliness_token_loses_the_peer_at_once() -> None:
    peer = PeerVehicle(2, timeout_s=0.25, action_timeout_s=1.0, clock=_Clock())
    peer.observe(_tick())
    peer.token_lost()
    assert not peer.connected and peer.latest() is None


def test_an_action_waits_for_the_peer_to_show_it_done_and_fails_if_it_never_does() -> None:
    peer = PeerVehicle(2, timeout_s=5.0, action_timeout_s=0.2)
    peer.observe(_tick())

    async def arm_while_the_peer_arms() -> None:
        waiting = asyncio.create_task(peer.arm())
        await asyncio.sleep(0.05)
        assert not waiting.done()
        peer.observe(_tick(armed=True))
        await asyncio.wait_for(waiting, 1.0)

    asyncio.run(arm_while_the_peer_arms())
    with pytest.raises(VehicleCommandError, match="did not show it in offboard"):
        asyncio.run(peer.set_offboard())
    with pytest.raises(VehicleCommandError, match="checks its own"):
        asyncio.run(peer.read_parameter("COM_OF_LOSS_T"))
