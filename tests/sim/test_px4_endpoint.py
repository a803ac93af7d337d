"""The simulated PX4's MAVLink endpoint, driven datagram by datagram on simulated time (no
sockets): parameters, heartbeat timing, TIMESYNC and vision stamps, events."""

from __future__ import annotations

import asyncio
import json
import lzma
import random
import socket
import struct
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from px4_mavlink.codec import MavlinkCodec, mavlink
from px4_mavlink.events import EventCatalog
from px4_mavlink.px4_messages import request_event_send
from sim import px4
from sim.ports import AirframeState
from sim.px4 import PX4_NAMES, Px4Params
from sim.px4_endpoint import CATALOG_PATH, HeartbeatSchedule, Px4Endpoint
from sim.px4_firmware import resolve_px4_dir
from tests.test_service import require_px4

INT32, REAL32 = 6, 9
CLIENT_SYSTEM = 245


class Resting:
    """An airframe standing on the ground."""

    def state(self) -> AirframeState:
        return AirframeState(
            0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), np.zeros(3), True
        )

    def command(self, thrust_n: float, torque_nm: Any) -> None:
        pass


class Bench:
    """One simulated PX4 and a client on the bench: the client's frames go in by
    ``handle_datagram``; what the vehicle sends is collected and decoded."""

    def __init__(self, params: Px4Params | None = None) -> None:
        self.px4 = Px4Endpoint(0, Resting(), params, local_port=0, client_port=0)
        self.px4.outbox = deque()
        self.client = MavlinkCodec(system=CLIENT_SYSTEM, component=190)
        self.reader = MavlinkCodec(system=CLIENT_SYSTEM, component=190)
        self.now_s = 0.0
        self.log: list[tuple[float, Any]] = []

    @property
    def out(self) -> Any:
        """The client's pymavlink ``MAVLink`` (``*_send`` queues a frame to the vehicle)."""
        return self.client.messages

    def deliver(self) -> list[Any]:
        """Hand the client's queued frames to the vehicle; what it answered at once."""
        for frame in self.client.outgoing():
            self.px4.handle_datagram(frame, self.now_s)
        return self.collect()

    def collect(self) -> list[Any]:
        assert self.px4.outbox is not None
        messages = [m for f in self.px4.outbox for m in self.reader.decode(f).messages]
        self.px4.outbox.clear()
        self.log += [(self.now_s, m) for m in messages]
        return messages

    def run(self, until_s: float, every: Any = None) -> None:
        """Step the vehicle at 500 Hz to ``until_s``; ``every(bench, messages)`` after each."""
        while self.now_s < until_s - 1e-9:
            self.now_s = round(self.now_s + 0.002, 6)
            self.px4.step(self.now_s)
            messages = self.collect()
            if every is not None:
                every(self, messages)

    def of(self, kind: str) -> list[tuple[float, Any]]:
        return [(t, m) for t, m in self.log if m.get_type() == kind]


def of_type(messages: list[Any], kind: str) -> list[Any]:
    return [m for m in messages if m.get_type() == kind]


def int32_bytes(raw: float) -> bytes:
    return struct.pack("<f", raw)


def as_float(value: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", value))[0])


# ---- parameters --------------------------------------------------------------------------
def test_parameters_read_by_name_or_index_with_int32_sent_bytewise() -> None:
    bench = Bench()
    table = bench.px4.model.parameters
    bench.out.param_request_read_send(1, 1, b"COM_OBL_RC_ACT", -1)
    bench.out.param_request_read_send(1, 1, b"COM_OF_LOSS_T", -1)
    (act, loss) = of_type(bench.deliver(), "PARAM_VALUE")
    assert (act.param_id, act.param_type, int32_bytes(act.param_value)) == (
        "COM_OBL_RC_ACT", INT32, b"\x00\x00\x00\x00"
    )  # fmt: skip
    assert (loss.param_type, loss.param_value) == (REAL32, 1.0)
    assert act.param_count == len(table) and act.param_index == table.index("COM_OBL_RC_ACT")
    # An index ≥ 0 wins over the name (measured); unknown names and indices: silence.
    index = table.index("MPC_LAND_SPEED")
    bench.out.param_request_read_send(1, 1, b"COM_OBL_RC_ACT", index)
    (by_index,) = of_type(bench.deliver(), "PARAM_VALUE")
    assert by_index.param_id == "MPC_LAND_SPEED"
    bench.out.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    bench.out.param_request_read_send(1, 1, b"", len(table))
    bench.out.param_request_read_send(0, 0, b"MAV_SYS_ID", -1)  # not addressed to system 1
    assert not bench.deliver()


def test_param_set_is_echoed_and_drives_the_behaviour_at_once() -> None:
    bench = Bench()
    model = bench.px4.model
    bench.out.param_set_send(1, 1, b"COM_OBL_RC_ACT", as_float(4), INT32)
    echoes = of_type(bench.deliver(), "PARAM_VALUE")
    assert len(echoes) == 2  # the answer and PX4's notice of the change (measured)
    assert all(int32_bytes(e.param_value) == b"\x04\x00\x00\x00" for e in echoes)
    assert model.parameters.get("COM_OBL_RC_ACT") == 4
    bench.out.param_set_send(1, 0, b"COM_OBL_RC_ACT", as_float(4), INT32)  # unchanged
    assert len(of_type(bench.deliver(), "PARAM_VALUE")) == 1
    # The wrong type, an unknown name, another system: no answer, nothing set (measured).
    bench.out.param_set_send(1, 1, b"COM_OBL_RC_ACT", 5.0, REAL32)
    bench.out.param_set_send(1, 1, b"COM_OF_LOSS_T", as_float(2), INT32)
    bench.out.param_set_send(1, 1, b"NO_SUCH_PARAM", 1.0, REAL32)
    bench.out.param_set_send(2, 1, b"COM_OF_LOSS_T", 0.3, REAL32)
    assert not bench.deliver()
    table = model.parameters
    assert (table.get("COM_OBL_RC_ACT"), table.get("COM_OF_LOSS_T")) == (4, 1.0)
    bench.out.param_set_send(1, 1, b"COM_OF_LOSS_T", 0.5, REAL32)
    bench.deliver()

    def client(bench: Bench, messages: list[Any]) -> None:
        if bench.now_s < 2.0 and round(bench.now_s * 500) % 10 == 0:
            bench.out.set_attitude_target_send(0, 1, 1, 128, [1, 0, 0, 0], 0, 0, 0, 0.0)
            bench.deliver()

    bench.run(1.5, client)
    bench.out.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    assert [a.result for a in of_type(bench.deliver(), "COMMAND_ACK")] == [0, 0]
    bench.run(2.0, client)  # the stream stops at 2.0 s: land after 0.5 s
    bench.run(2.49)
    assert model.mode_name == "OFFBOARD"
    bench.run(2.61)
    assert model.mode_name == "AUTO.LAND"


def test_param_list_sends_every_parameter_in_index_order() -> None:
    bench = Bench()
    bench.out.param_request_list_send(1, 1)
    values = of_type(bench.deliver(), "PARAM_VALUE")
    assert [v.param_index for v in values] == list(range(len(values)))
    assert {v.param_id for v in values} == PX4_NAMES
    assert all(v.param_count == len(values) for v in values)


# ---- heartbeat and streams ---------------------------------------------------------------
def test_heartbeat_jitters_over_a_simulated_minute_while_the_streams_keep_their_rates() -> None:
    bench = Bench(Px4Params(seed=3))
    bench.run(60.0)
    beats = np.array([t for t, m in bench.of("HEARTBEAT")])
    gaps = np.diff(beats)
    assert 57 <= beats.size <= 61
    assert np.median(gaps) == pytest.approx(1.0, abs=0.02)
    assert gaps.max() <= 1.8 + 0.004 and gaps.std() > 0.005
    attitude = np.array([t for t, m in bench.of("ATTITUDE")])
    assert attitude.size == pytest.approx(3000, abs=3)
    assert np.diff(attitude).max() < 0.025  # no gap in the 50 Hz stream when a beat is late
    assert len(bench.of("TIMESYNC")) == pytest.approx(600, abs=2)
    assert len(bench.of("CURRENT_MODE")) == pytest.approx(30, abs=1)
    assert len(bench.of("CURRENT_EVENT_SEQUENCE")) == pytest.approx(20, abs=1)
    (_, first), *_ = bench.of("HEARTBEAT")
    assert (first.base_mode, first.custom_mode, first.system_status) == (29, 0x03040000, 3)


def test_heartbeat_schedule_statistics() -> None:
    """Ten simulated minutes: late beats (1.3–1.8 s gaps) now and then, never longer; about
    1 Hz on average; without jitter exactly 1 Hz."""
    schedule = HeartbeatSchedule(random.Random(11))
    times = [t for t in np.arange(0.0, 600.0, 0.002) if schedule.due(float(t))]
    gaps = np.diff(times)
    assert 590 <= len(times) <= 601  # a beat 0.5 s late or more restarts the schedule
    assert 5 <= int(np.sum(gaps > 1.3)) <= 40
    assert gaps.max() <= 1.8 + 0.002
    steady = HeartbeatSchedule(None)
    times = [t for t in np.arange(0.0, 10.0, 0.002) if steady.due(float(t))]
    np.testing.assert_allclose(np.diff(times), 1.0, atol=0.0021)


def test_the_heartbeat_interval_cannot_be_changed() -> None:
    bench = Bench()
    bench.out.command_long_send(1, 1, 511, 0, 0, 500_000, 0, 0, 0, 0, 0)
    (ack,) = of_type(bench.deliver(), "COMMAND_ACK")
    assert ack.result == 4  # FAILED, as v1.15.4


# ---- time synchronization and vision stamps ----------------------------------------------
CLIENT_OFFSET_S = 1000.25  # the client's clock runs this far ahead of the vehicle's


def answer_timesync(bench: Bench, messages: list[Any]) -> None:
    """A client that answers the vehicle's TIMESYNC requests at once (its clock ahead)."""
    for request in of_type(messages, "TIMESYNC"):
        if request.tc1 == 0:
            bench.out.timesync_send(round((bench.now_s + CLIENT_OFFSET_S) * 1e9), request.ts1)
    bench.deliver()


def send_pose(bench: Bench, captured_client_s: float) -> None:
    usec = round(captured_client_s * 1e6)
    bench.out.vision_position_estimate_send(usec, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    bench.deliver()


def test_timesync_requests_carry_our_clock_and_requests_are_answered() -> None:
    bench = Bench()
    bench.run(0.31)
    requests = [m for _, m in bench.of("TIMESYNC")]
    assert len(requests) == 4 and all(r.tc1 == 0 for r in requests)  # 10 Hz, from t = 0
    assert [r.ts1 for r in requests] == pytest.approx([0, 1e8, 2e8, 3e8], abs=3e6)  # ns
    bench.out.timesync_send(0, 123_456_789)
    (answer,) = of_type(bench.deliver(), "TIMESYNC")
    assert (answer.tc1, answer.ts1) == (round(0.31e9), 123_456_789)


def test_vision_is_stamped_with_its_arrival_until_timesync_converges_then_its_capture() -> None:
    bench = Bench(Px4Params(require_vision=True, vision_timeout_s=0.5))
    model = bench.px4.model
    bench.run(10.0, answer_timesync)
    send_pose(bench, captured_client_s=0.0)  # an ancient stamp: fresh on arrival, unsynced
    assert model.last_vision_s == pytest.approx(10.0)
    bench.run(51.0, answer_timesync)  # 500 answers at 10 Hz
    assert bench.px4.timesync.converged
    assert bench.px4.timesync.offset_us * 1e-6 == pytest.approx(-CLIENT_OFFSET_S, abs=1e-3)
    send_pose(bench, captured_client_s=bench.now_s + CLIENT_OFFSET_S - 0.8)  # 0.8 s old
    assert model.last_vision_s == pytest.approx(bench.now_s - 0.8, abs=1e-3)
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    assert of_type(bench.deliver(), "COMMAND_ACK")[0].result == 1  # stale: no position
    send_pose(bench, captured_client_s=bench.now_s + CLIENT_OFFSET_S - 0.05)
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    assert of_type(bench.deliver(), "COMMAND_ACK")[0].result == 0


# ---- events ------------------------------------------------------------------------------
def test_a_refused_arm_is_reported_by_event_not_statustext() -> None:
    bench = Bench(Px4Params(require_vision=True))
    catalog = EventCatalog.load(CATALOG_PATH)
    bench.out.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4)  # a companion
    bench.deliver()
    bench.run(0.2)
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    (ack,) = of_type(bench.deliver(), "COMMAND_ACK")
    assert ack.result == 1
    bench.run(0.21)
    events = [m for _, m in bench.of("EVENT")]
    decoded = [catalog.decode(e.id, bytes(e.arguments)) for e in events]
    names = [d.definition.name for d in decoded if d.definition is not None]
    assert names == [
        "commander_arming_check_summary",
        "check_modes_offboard_signal",
        "check_modes_local_pos",
        "commander_health_summary",
        "commander_arm_denied_resolve_failures",
    ]
    refusal = events[-1]
    assert refusal.id == (1 << 24) | 133277  # the firmware's id
    assert (refusal.log_levels, refusal.destination_system) == (0x62, 0)
    assert [e.sequence for e in events] == list(range(len(events)))
    position = decoded[2]
    assert int(position.values[0]) & catalog.mode_groups[0x03040000]  # blocks AUTO.LOITER
    assert not bench.of("STATUSTEXT")  # none to a companion, as v1.15.4
    bench.run(3.1)
    (_, sequence), *_ = bench.of("CURRENT_EVENT_SEQUENCE")[-1:]
    assert sequence.sequence == events[-1].sequence


def test_a_ground_station_also_gets_statustext_ending_in_a_tab() -> None:
    bench = Bench()
    bench.out.heartbeat_send(mavlink.MAV_TYPE_GCS, 8, 0, 0, 4)
    bench.deliver()
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    bench.deliver()
    bench.run(0.1)
    texts = [m.text for _, m in bench.of("STATUSTEXT")]
    assert texts == ["Motors armed (a command over MAVLink)\t"]
    bench.run(3.5)  # the ground station went quiet more than 3 s ago
    bench.out.command_long_send(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0)
    bench.deliver()
    bench.run(3.6)
    assert len(bench.of("STATUSTEXT")) == 1
    assert bench.px4.events_sent[-1] == (
        "commander_disarmed_by",
        "Motors disarmed (a command over MAVLink)",
    )


def test_lost_events_can_be_requested_again() -> None:
    bench = Bench()
    bench.run(0.2)
    sent = [m for _, m in bench.of("EVENT")]
    request_event_send(bench.out, 1, 1, sent[1].sequence, sent[2].sequence)
    again = of_type(bench.deliver(), "EVENT")
    assert [(e.sequence, e.id, bytes(e.arguments)) for e in again] == [
        (e.sequence, e.id, bytes(e.arguments)) for e in sent[1:3]
    ]
    request_event_send(bench.out, 1, 1, 500, 500)
    (error,) = of_type(bench.deliver(), "RESPONSE_EVENT_ERROR")
    assert (error.sequence, error.sequence_oldest_available) == (500, sent[0].sequence)


def test_current_mode_keeps_the_intended_offboard_through_a_failsafe() -> None:
    bench = Bench()

    def client(bench: Bench, messages: list[Any]) -> None:
        if bench.now_s < 1.5 and round(bench.now_s * 500) % 10 == 0:
            bench.out.set_attitude_target_send(0, 1, 1, 128, [1, 0, 0, 0], 0, 0, 0, 0.0)
            bench.deliver()

    bench.run(1.3, client)
    bench.out.command_long_send(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0)
    bench.out.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    bench.deliver()
    bench.run(5.0, client)
    (_, mode), *_ = bench.of("CURRENT_MODE")[-1:]
    assert (mode.custom_mode, mode.intended_custom_mode) == (0x00030000, 0x00060000)
    (_, beat), *_ = bench.of("HEARTBEAT")[-1:]
    assert (beat.custom_mode, beat.base_mode, beat.system_status) == (0x00030000, 209, 5)
    bench.out.command_long_send(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0)  # kill
    bench.deliver()
    bench.run(7.1)
    (_, beat), *_ = bench.of("HEARTBEAT")[-1:]
    assert (beat.custom_mode, beat.base_mode) == (0x00060000, 1)  # OFFBOARD, disarmed


# ---- the event catalog -------------------------------------------------------------------
def our_catalog() -> dict[str, tuple[int, dict[str, Any]]]:
    document = json.loads(CATALOG_PATH.read_text())
    return {
        e["name"]: (int(sub), e)
        for group in document["components"]["1"]["event_groups"].values()
        for sub, e in group["events"].items()
    }


def test_the_catalog_holds_only_what_the_model_emits() -> None:
    source = Path(px4.__file__).read_text()
    assert all(f'"{name}"' in source for name in our_catalog()), "an event the model never emits"


@pytest.mark.px4
def test_the_catalogs_events_have_the_firmwares_ids_in_their_own_words() -> None:
    require_px4()
    definitions = resolve_px4_dir(None) / "etc" / "extras" / "all_events.json.xz"
    ours = our_catalog()
    firmware = json.loads(lzma.decompress(definitions.read_bytes()))
    theirs = {
        e["name"]: (int(sub), e)
        for group in firmware["components"]["1"]["event_groups"].values()
        for sub, e in group["events"].items()
    }
    for name, (sub, event) in ours.items():
        their_sub, their_event = theirs[name]
        assert sub == their_sub, name
        assert event.get("arguments", []) == their_event.get("arguments", []), name
        assert event["message"] != their_event["message"], f"{name}: copied words"


def test_random_field_values_of_the_new_messages_never_raise() -> None:
    """The receive paths added here, fed random values (the fuzzer's other kinds are in
    tests/sim/test_fuzz_mavlink.py)."""
    rng = random.Random(7)
    bench = Bench()

    def number() -> float:
        return rng.choice([0.0, -1.0, 1e30, float("nan"), float("inf"), rng.uniform(-1e3, 1e3)])

    def name() -> bytes:
        return rng.choice([b"COM_OBL_RC_ACT", b"MPC_LAND_SPEED", b"", b"\xff\xfe", b"X" * 16])

    for k in range(2000):
        kind = k % 6
        if kind == 0:
            bench.out.param_set_send(1, rng.randrange(3), name(), number(), rng.randrange(12))
        elif kind == 1:
            bench.out.param_request_read_send(1, 1, name(), rng.randrange(-5, 40))
        elif kind == 2:
            bench.out.timesync_send(rng.randrange(-(2**63), 2**63), rng.randrange(-(2**63), 2**63))
        elif kind == 3:
            request_event_send(bench.out, 1, 1, rng.randrange(2**16), rng.randrange(2**16))
        elif kind == 4:
            usec = rng.randrange(2**64)
            bench.out.vision_position_estimate_send(usec, *(number() for _ in range(6)))
        else:
            bench.out.param_request_list_send(1, 1)
        bench.deliver()
        if k % 50 == 0:
            bench.run(bench.now_s + 0.1)
    counters = bench.px4.counters
    assert counters.messages == 2000 and counters.bad_data == 0


@pytest.mark.parametrize("first", ["link", "relay"])
async def test_the_first_sender_is_the_partner_for_good(first: str) -> None:
    """As PX4's UDP link (measured on v1.15.4 with a second socket sending poses): whoever
    talks first gets the telemetry from then on; the other is heard, never answered."""
    sockets = {name: socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for name in ("link", "relay")}
    for sock in sockets.values():
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
    px4 = Px4Endpoint(0, Resting(), local_port=0, client_port=sockets["link"].getsockname()[1])
    await px4.start()
    encoder = MavlinkCodec(system=CLIENT_SYSTEM, component=190)
    encoder.messages.heartbeat_send(mavlink.MAV_TYPE_ONBOARD_CONTROLLER, 8, 0, 0, 4)
    (frame,) = encoder.outgoing()
    second = "relay" if first == "link" else "link"
    received = dict.fromkeys(sockets, 0)
    try:
        for name in (first, second):
            sockets[name].sendto(frame, ("127.0.0.1", px4.local_port))
            await asyncio.sleep(0.05)
        for k in range(20):
            px4.step(0.01 * k)
            await asyncio.sleep(0.005)
        for name, sock in sockets.items():
            while True:
                try:
                    sock.recvfrom(65535)
                except BlockingIOError:
                    break
                received[name] += 1
    finally:
        await px4.close()
        for sock in sockets.values():
            sock.close()
    assert px4.counters.messages == 2  # both heard
    assert received[first] > 10 and received[second] == 0
