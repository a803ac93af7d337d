"""MAVLink receive paths under fuzzing (the full run: benchmarks/fuzz_mavlink.py)."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from benchmarks.fuzz_mavlink import MUTATIONS, _RestingAirframe, run_fuzz
from sim.px4_endpoint import Px4Endpoint
from supervisor.mavlink.link import LinkConfig, MavlinkLink


def test_fuzzed_frames_never_raise_and_are_counted() -> None:
    counts = run_fuzz(4000, seed=5)
    assert counts.escaped == 0, counts.examples
    assert set(counts.by_mutation) == set(MUTATIONS)
    for receiver in (counts.px4, counts.link):
        assert receiver["datagrams"] == 4000
        assert receiver["bad_data"] > 1000  # broken frames are counted...
        assert receiver["messages"] > 300  # ...and the intact ones still get through
    assert counts.px4["handled"] > 50


def test_a_truncated_datagram_does_not_spoil_the_next_one() -> None:
    encoder = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    frame = encoder.heartbeat_encode(2, 12, 129, 6 << 16, 4).pack(encoder)
    link = MavlinkLink(LinkConfig(system_id=1, local_port=0))
    px4 = Px4Endpoint(0, _RestingAirframe(), local_port=0, client_port=0)
    link.handle_datagram(frame[:7], ("127.0.0.1", 1))
    link.handle_datagram(frame, ("127.0.0.1", 1))
    assert link.counters.messages == 1 and link.session.armed
    px4.handle_datagram(frame[:9], 0.0)
    assert px4.handle_datagram(frame, 0.0)
