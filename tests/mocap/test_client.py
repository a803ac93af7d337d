"""QTM client: frames over UDP from the simulated server, sequencing counters, reconnects."""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
from collections.abc import AsyncIterator, Callable, Mapping
from pathlib import Path

import numpy as np
import pytest

from geometry import frames
from geometry.arrays import FloatArray
from mocap.client import FrameReceiver, MocapSource, QtmClient
from mocap.qtm_protocol import (
    GREETING,
    BodyPose,
    CommandPacket,
    ComponentType,
    DataPacket,
    EventPacket,
    MocapFrame,
    NoMoreDataPacket,
    QtmStreamDecoder,
    RawComponent,
    XmlPacket,
    build_6d_parameters_xml,
    encode_packet,
    packet_from_poses,
)
from mocap.recording import read_recording
from mocap.stream_recorder import StreamRecorder, StreamSession
from sim.qtm_server import QtmServer

NAMES = ("uav1", "uav2", "bar")
LOCALHOST = "127.0.0.1"


def source(t_s: float) -> Mapping[str, BodyPose]:
    """uav1 circles and yaws through ±π, uav2 is lost every other 50 ms, bar hangs still."""
    poses = {
        "uav1": BodyPose.from_rotation(
            "uav1",
            np.array([1.5 * math.cos(t_s), 1.5 * math.sin(t_s), 1.2]),
            frames.rotation_from_euler_zyx(0.1 * math.sin(3 * t_s), -0.05, 3.0 + 2.0 * t_s),
        ),
        "bar": BodyPose.from_rotation(
            "bar", np.array([0.2, -0.3, 0.8]), frames.rotation_from_euler_zyx(0.0, 0.3, -1.0)
        ),
    }
    if int(t_s * 20) % 2:
        poses["uav2"] = BodyPose.from_rotation(
            "uav2", np.array([-1.0, 0.5, 1.1]), frames.rotation_from_euler_zyx(0.2, 0.1, 0.5)
        )
    return poses


def attitude_error(q_a: FloatArray, q_b: FloatArray) -> float:
    relative = frames.quaternion_multiply(frames.quaternion_conjugate(q_a), q_b)
    return float(np.linalg.norm(frames.rotation_vector_from_quaternion(relative)))


def assert_matches_source(frame: MocapFrame) -> None:
    expected = source(frame.timestamp_us * 1e-6)
    assert tuple(frame.bodies) == NAMES
    for name, pose in frame.bodies.items():
        want = expected.get(name)
        assert pose.tracked == (want is not None)
        if want is None:
            assert np.isnan(pose.position_m).all()
            continue
        np.testing.assert_allclose(pose.position_m, want.position_m, atol=1e-6)  # float32 mm
        assert attitude_error(pose.quaternion, want.quaternion) < 5e-6
        euler_error = [
            frames.wrap_angle(a - b)
            for a, b in zip(pose.euler_zyx_rad, want.euler_zyx_rad, strict=True)
        ]
        assert max(abs(e) for e in euler_error) < 5e-6


async def wait_until(condition: Callable[[], bool], timeout_s: float = 5.0) -> None:
    """Poll a counter of the client (counters have no event to wait on)."""
    async with asyncio.timeout(timeout_s):
        while not condition():  # noqa: ASYNC110
            await asyncio.sleep(0.005)


@contextlib.asynccontextmanager
async def udp_sender(local_host: str = LOCALHOST) -> AsyncIterator[asyncio.DatagramTransport]:
    loop = asyncio.get_running_loop()
    transport, _ = await loop.create_datagram_endpoint(
        asyncio.DatagramProtocol, local_addr=(local_host, 0)
    )
    try:
        yield transport
    finally:
        transport.close()


# --- Against the simulated server ------------------------------------------------------------


@pytest.mark.parametrize("component", ["6D", "6DRes", "6DEuler", "6DEulerRes"])
async def test_client_gets_the_published_poses_over_udp(component: str) -> None:
    async with (
        QtmServer(NAMES, source, port=0, rate_hz=200.0) as server,
        QtmClient(LOCALHOST, server.port, component=component) as client,
    ):
        received: list[MocapFrame] = []
        async with asyncio.timeout(5.0):
            while len(received) < 30:
                await client.wait_frame()  # wakes up; the frame itself is in the queue too
                received += client.drain()
        stats = client.stats()
        udp_port = client.udp_port
    assert stats.connected and stats.protocol_version == "1.25" and stats.body_names == NAMES
    assert stats.malformed == stats.out_of_order == stats.duplicates == 0
    assert server.commands[:2] == ["Version 1.25", "GetParameters 6D"]
    assert server.commands[2] == f"StreamFrames AllFrames UDP:{udp_port} {component}"
    for frame in received:
        assert_matches_source(frame)
    assert any(not f.bodies["uav2"].tracked for f in received)
    numbers = [f.frame_number for f in received]
    assert numbers == sorted(set(numbers))


async def test_receive_time_comes_from_the_injected_clock() -> None:
    async with (
        QtmServer(NAMES, source, port=0, rate_hz=200.0) as server,
        QtmClient(LOCALHOST, server.port, clock=lambda: 42.5) as client,
    ):
        mocap: MocapSource = client  # the client satisfies the supervisor's protocol
        async with asyncio.timeout(5.0):
            frame = await client.wait_frame()
        assert frame.receive_time_s == 42.5
        assert mocap.stats().last_receive_time_s == 42.5
        assert mocap.latest() is not None


async def test_the_frame_listener_hears_every_accepted_frame_as_it_arrives() -> None:
    async with (
        QtmServer(NAMES, source, port=0, rate_hz=200.0) as server,
        QtmClient(LOCALHOST, server.port) as client,
    ):
        heard: list[int] = []
        drained: list[MocapFrame] = []
        enough = asyncio.Event()

        def listener() -> None:  # drains at once: each call finds exactly its frame
            frames = client.drain()
            heard.append(len(frames))
            drained.extend(frames)
            if len(drained) >= 20:
                enough.set()

        client.on_frame(listener)
        async with asyncio.timeout(5.0):
            await enough.wait()
        client.on_frame(None)
        calls = len(heard)
        await asyncio.sleep(0.05)  # frames keep coming; the removed listener hears none
    assert heard == [1] * calls and calls >= 20
    assert [f.frame_number for f in drained] == sorted({f.frame_number for f in drained})


async def test_crafted_datagrams_are_counted() -> None:
    poses = source(0.3)

    def datagram(n: int) -> bytes:
        return encode_packet(packet_from_poses(n, n * 5000, NAMES, poses, [ComponentType.SIX_D]))

    two_bodies = encode_packet(packet_from_poses(7, 0, NAMES[:2], poses, [ComponentType.SIX_D]))
    # rate_hz=None: the server sends nothing unless published to, so only our datagrams arrive.
    async with (
        QtmServer(NAMES, None, port=0, rate_hz=None) as server,
        QtmClient(LOCALHOST, server.port) as client,
        udp_sender() as sender,
    ):
        async with asyncio.timeout(5.0):
            await client.wait_connected()
        target = (LOCALHOST, client.udp_port)
        sequence = [
            datagram(1),
            datagram(2),
            datagram(5),  # gap: 3 and 4 missing
            datagram(4),  # late
            datagram(5),  # duplicate
            b"\x10\x00\x00\x00\x03\x00\x00\x00garbage!",  # malformed
            datagram(6)[:-3],  # truncated: malformed
            encode_packet(NoMoreDataPacket()),
            encode_packet(EventPacket(3)),  # valid, not data
            two_bodies,  # body count differs from the 6D parameters
            datagram(6),
        ]
        for data in sequence:
            sender.sendto(data, target)
            await asyncio.sleep(0.002)  # keep loopback ordering beyond doubt
        await wait_until(lambda: client.stats().datagrams == len(sequence))
        async with udp_sender("127.0.0.2") as stranger:  # another host on the loopback net
            stranger.sendto(datagram(7), target)
            await wait_until(lambda: client.stats().foreign_datagrams == 1)
        stats = client.stats()
        frames_received = client.drain()
    assert [f.frame_number for f in frames_received] == [1, 2, 5, 6]
    assert (stats.frames, stats.gaps, stats.frames_missed) == (4, 1, 2)
    assert (stats.out_of_order, stats.duplicates, stats.malformed) == (1, 1, 2)
    assert (stats.no_more_data, stats.ignored, stats.body_count_mismatches) == (1, 1, 1)
    assert stats.last_frame_number == 6 and stats.datagrams == len(sequence)


async def test_reconnects_after_the_server_restarts() -> None:
    first = QtmServer(NAMES, source, port=0, rate_hz=200.0)
    await first.start()
    port = first.port  # an OS-chosen port, reused by the restarted server
    async with QtmClient(
        LOCALHOST, port, reconnect_min_s=0.02, reconnect_max_s=0.1, keepalive_s=0.5
    ) as client:
        async with asyncio.timeout(5.0):
            await client.wait_frame()
        await first.close()
        await wait_until(lambda: not client.connected)
        await asyncio.sleep(0.15)  # a few failed attempts while the server is down
        failures = client.stats().connect_failures
        assert failures >= 1
        async with QtmServer(NAMES, source, port=port, rate_hz=200.0) as second:
            async with asyncio.timeout(5.0):
                await client.wait_connected()
                frame = await client.wait_frame()
            assert_matches_source(frame)
            stats = client.stats()
            assert second.clients == 1
    assert stats.sessions == 2 and stats.reconnects == 1
    assert stats.stream_restarts == 0  # the sequence was reset with the session


async def test_version_falls_back_to_what_the_server_supports() -> None:
    async with (
        QtmServer(NAMES, source, port=0, max_version=(1, 19)) as server,
        QtmClient(LOCALHOST, server.port) as client,
    ):
        async with asyncio.timeout(5.0):
            await client.wait_frame()
        assert client.stats().protocol_version == "1.19"
    versions = [c for c in server.commands if c.startswith("Version")]
    assert versions == [f"Version 1.{m}" for m in range(25, 18, -1)]


async def test_no_common_version_is_a_connect_failure() -> None:
    async with (
        QtmServer(NAMES, source, port=0, min_version=(1, 26), max_version=(1, 28)) as server,
        QtmClient(LOCALHOST, server.port, reconnect_min_s=0.01, reconnect_max_s=0.02) as client,
    ):
        await wait_until(lambda: client.stats().connect_failures >= 2)
        stats = client.stats()
    assert not stats.connected and stats.sessions == 0
    assert stats.last_error is not None and "no common protocol version" in stats.last_error
    assert "Version 1.8" in server.commands  # went all the way down, never below


async def test_a_silent_server_is_detected_by_the_keepalive() -> None:
    """Answers the set-up, then neither streams nor answers: the session must end."""
    sessions = 0

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        nonlocal sessions
        sessions += 1
        writer.write(encode_packet(CommandPacket(GREETING)))
        decoder = QtmStreamDecoder()
        with contextlib.suppress(ConnectionError):
            while data := await reader.read(4096):
                for packet in decoder.feed(data):
                    assert isinstance(packet, CommandPacket)
                    if packet.text.startswith("Version 1"):
                        writer.write(encode_packet(CommandPacket("Version set to 1.25")))
                    elif packet.text.startswith("GetParameters"):
                        writer.write(encode_packet(XmlPacket(build_6d_parameters_xml(NAMES))))
        writer.close()

    server = await asyncio.start_server(handle, LOCALHOST, 0)
    port = server.sockets[0].getsockname()[1]
    async with (
        server,
        QtmClient(
            LOCALHOST, port, keepalive_s=0.05, command_timeout_s=0.1, reconnect_min_s=0.01
        ) as client,
    ):
        await wait_until(lambda: sessions >= 2)
        stats = client.stats()
    assert stats.sessions >= 1 and stats.last_error is not None
    assert "TimeoutError" in stats.last_error


# --- FrameReceiver, sans-IO ------------------------------------------------------------------


def data(frame_number: int, names: tuple[str, ...] = NAMES) -> bytes:
    packet = packet_from_poses(frame_number, 0, names, source(0.0), [ComponentType.SIX_D])
    return encode_packet(packet)


def test_frame_numbers_wrap_around_uint32() -> None:
    receiver = FrameReceiver(NAMES)
    for n in (2**32 - 2, 2**32 - 1, 0, 1, 3):
        receiver.receive_datagram(data(n), 0.0)
    counts = receiver.counts
    assert counts["frames"] == 5 and counts["gaps"] == 1 and counts["frames_missed"] == 1
    assert counts["out_of_order"] == 0 and receiver.last_frame_number == 3


def test_a_restarted_measurement_is_not_out_of_order_forever() -> None:
    receiver = FrameReceiver(NAMES, restart_threshold_frames=1000, restart_after_backwards=5)
    for n in range(5000, 5010):
        receiver.receive_datagram(data(n), 0.0)
    assert receiver.receive_datagram(data(1), 0.0) is not None  # far behind: a new measurement
    assert receiver.counts["stream_restarts"] == 1
    # A short stream restarted: only a few frames back, so first taken as reordering …
    receiver.reset(NAMES, ComponentType.SIX_D)
    for n in range(100, 110):
        receiver.receive_datagram(data(n), 0.0)
    accepted = [receiver.receive_datagram(data(n), 0.0) is not None for n in range(1, 7)]
    # … until several in a row are behind: then the new numbering is adopted.
    assert accepted == [False, False, False, False, True, True]
    assert receiver.counts["out_of_order"] == 4 and receiver.counts["stream_restarts"] == 2


def test_store_is_bounded_and_latest_survives_drain() -> None:
    receiver = FrameReceiver(NAMES, max_queue=4)
    for n in range(1, 11):
        receiver.receive_datagram(data(n), float(n))
    assert receiver.counts["queue_overflows"] == 6
    drained = receiver.drain()
    assert [f.frame_number for f in drained] == [7, 8, 9, 10]
    assert receiver.drain() == []
    latest = receiver.latest()
    assert latest is not None and latest.frame_number == 10 and latest.receive_time_s == 10.0


def test_component_choice_and_frames_without_rigid_bodies() -> None:
    receiver = FrameReceiver(NAMES, ComponentType.SIX_D_EULER)
    both = packet_from_poses(
        1, 0, NAMES, source(0.0), [ComponentType.SIX_D, ComponentType.SIX_D_EULER]
    )
    frame = receiver.receive_datagram(encode_packet(both), 0.0)
    assert frame is not None and frame.bodies["uav1"].tracked
    # Another 6D-family component carries the same poses: used rather than dropped.
    assert receiver.receive_datagram(data(2), 0.0) is not None
    # A datagram without any rigid bodies (QTM may split a frame over datagrams) is skipped.
    markers_only = DataPacket(3, 3, (RawComponent(1, bytes(8)),))
    assert receiver.receive_datagram(encode_packet(markers_only), 0.0) is None
    assert receiver.counts["ignored"] == 1 and receiver.counts["malformed"] == 0


def test_frame_numbers_far_ahead_are_refused_and_the_real_stream_goes_on() -> None:
    """A sender raising the frame numbers by 50, between the real frames (10 ms apart), from
    the server's own port: each refused and counted, no real frame taken as out of order."""
    receiver = FrameReceiver(NAMES)
    accepted = []
    for k in range(1, 101):
        now_s = k * 0.01
        accepted.append(receiver.receive_datagram(data(k), now_s, 6000) is not None)
        assert receiver.receive_datagram(data(k + 50), now_s + 0.002, 6000) is None
    counts = receiver.counts
    assert all(accepted) and counts["frame_number_jumps"] == 100
    assert counts["out_of_order"] == counts["gaps"] == counts["stream_restarts"] == 0
    assert receiver.last_frame_number == 100


def test_frame_numbers_ahead_by_the_time_that_passed_are_a_gap() -> None:
    receiver = FrameReceiver(NAMES, max_frame_rate_hz=1000.0, frame_number_slack=10)
    receiver.receive_datagram(data(1), 0.0)
    assert receiver.receive_datagram(data(12), 0.0005) is None  # 11 ahead in 0.5 ms
    assert receiver.receive_datagram(data(11), 0.0005) is not None  # the slack
    assert receiver.receive_datagram(data(511), 5.0) is not None  # 5 s of silence
    assert receiver.counts["gaps"] == 2 and receiver.counts["frame_number_jumps"] == 1


def test_a_stream_renumbered_far_ahead_is_adopted_after_a_run() -> None:
    receiver = FrameReceiver(NAMES, restart_after_backwards=5)
    receiver.receive_datagram(data(1), 0.0)
    taken = [
        receiver.receive_datagram(data(n), 0.01 + 0.01 * (n - 900)) is not None
        for n in range(900, 906)
    ]
    assert taken == [False, False, False, False, True, True]
    assert receiver.counts["stream_restarts"] == 1 and receiver.counts["frame_number_jumps"] == 4


def test_only_the_servers_stream_port_is_heard() -> None:
    """Learned from the first frame of a session (forgotten with it), or configured."""
    receiver = FrameReceiver(NAMES)
    assert receiver.receive_datagram(b"junk", 0.0, 7000) is None  # not a frame: learns nothing
    assert receiver.receive_datagram(data(1), 0.01, 6000) is not None
    assert receiver.receive_datagram(data(2), 0.02, 7000) is None
    assert receiver.server_port == 6000 and receiver.counts["foreign_port_datagrams"] == 1
    receiver.reset(NAMES, ComponentType.SIX_D)
    assert receiver.receive_datagram(data(1), 0.03, 7000) is not None  # a new session's port
    configured = FrameReceiver(NAMES, server_port=6000)
    assert configured.receive_datagram(data(1), 0.0, 7000) is None
    assert configured.receive_datagram(data(1), 0.0, 6000) is not None
    configured.reset(NAMES, ComponentType.SIX_D)
    assert configured.server_port == 6000


def test_a_resumed_receiver_takes_and_refuses_as_the_original() -> None:
    original = FrameReceiver(NAMES, restart_after_backwards=3)
    for n in (10, 11, 13, 9):  # a gap and one behind: state in every counter of the sequence
        original.receive_datagram(data(n), n * 0.01)
    resumed = FrameReceiver(NAMES, restart_after_backwards=3)
    resumed.resume(json.loads(json.dumps(original.sequence())))
    for n in (8, 7, 14, 14, 2000, 15):
        a = original.receive_datagram(data(n), n * 0.01)
        b = resumed.receive_datagram(data(n), n * 0.01)
        assert (a is None) == (b is None), n
        assert original.last_frame_number == resumed.last_frame_number
    assert original.sequence() == resumed.sequence()


def test_the_tap_hears_every_datagram_of_the_stream_before_it_is_decoded() -> None:
    receiver = FrameReceiver(NAMES)
    heard: list[tuple[bytes, float]] = []
    receiver.tap = lambda datagram, t_s: heard.append((datagram, t_s))
    receiver.receive_datagram(data(1), 0.01, 6000)
    receiver.receive_datagram(b"junk", 0.02, 6000)  # the stream's, though malformed
    receiver.receive_datagram(data(2), 0.03, 7000)  # another port's: not the stream
    assert heard == [(data(1), 0.01), (b"junk", 0.02)]


async def test_the_client_records_the_stream_as_it_receives_it(tmp_path: Path) -> None:
    """From ``record(path)`` to ``record(None)``: every datagram the client took from the
    stream, with the receive time its frames carry; the sequence returned is where the
    receiver stood as the recording began."""
    times = itertools.count(1000.0, 0.001)
    async with (
        QtmServer(NAMES, source, port=0, rate_hz=200.0) as server,
        QtmClient(LOCALHOST, server.port, clock=lambda: next(times)) as client,
    ):
        await asyncio.wait_for(client.wait_frame(), 5.0)
        client.drain()
        address = f"{LOCALHOST}:{server.port}"
        sequence = client.record(tmp_path / "r.qtm.gz")
        assert sequence is not None and sequence["last_frame_number"] is not None
        received: list[MocapFrame] = []
        async with asyncio.timeout(10.0):
            while len(received) < 40:
                await client.wait_frame()
                received += client.drain()
        client.record(None)
        received += client.drain()
    recording = read_recording(tmp_path / "r.qtm.gz")
    assert recording.body_names == NAMES and recording.source == address
    frames = list(recording.frames())
    assert frames[0].frame_number == sequence["last_frame_number"] + 1
    assert [f.frame_number for f in frames] == [f.frame_number for f in received]
    for got, kept in zip(received, frames, strict=True):
        assert kept.receive_time_s + recording.clock_start_s == got.receive_time_s


def test_a_recording_cut_short_reads_up_to_its_last_flush(tmp_path: Path) -> None:
    """A flight process killed while recording leaves a gzip stream without its end: read
    up to the last flush (every half second of receive time)."""
    session = StreamSession("qtm:22223", "1.25", ComponentType.SIX_D, NAMES, "<xml/>")
    recorder = StreamRecorder(tmp_path / "r.qtm.gz", session, 100.0)
    for n in range(1, 71):  # flushed at 100.5 s, with the 50th
        recorder.packet(data(n), 100.0 + n * 0.01)
    cut = (tmp_path / "r.qtm.gz").read_bytes()  # as the disk held it at the kill
    recorder.close()
    (tmp_path / "cut.qtm.gz").write_bytes(cut)
    whole, kept = read_recording(tmp_path / "r.qtm.gz"), read_recording(tmp_path / "cut.qtm.gz")
    assert len(whole.packets) == 70 and kept.packets == whole.packets[:50]
    assert kept.packets[-1].arrival_s == pytest.approx(0.5)


async def test_over_tcp_nothing_is_recorded_and_the_caller_is_told(tmp_path: Path) -> None:
    async with (
        QtmServer(NAMES, source, port=0, rate_hz=200.0) as server,
        QtmClient(LOCALHOST, server.port, transport="tcp") as client,
    ):
        await asyncio.wait_for(client.wait_frame(), 5.0)
        assert client.record(tmp_path / "r.qtm.gz") is None
        await client.wait_frame()
        client.record(None)
    assert not (tmp_path / "r.qtm.gz").exists()
