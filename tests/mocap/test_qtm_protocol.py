"""QTM RT codec: documented layouts, round trips, the SDK as an oracle, chunking, fuzzing."""

from __future__ import annotations

import contextlib
import math
import random
import struct
import xml.etree.ElementTree as ET
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from qtm_rt.packet import QRTComponentType, QRTPacket

from benchmarks.fuzz_qtm import run_fuzz
from geometry import frames
from mocap.qtm_protocol import (
    SIX_D_RECORD_SIZE_B,
    BodyPose,
    CommandPacket,
    ComponentType,
    DataPacket,
    ErrorPacket,
    EventPacket,
    NoMoreDataPacket,
    OtherPacket,
    Packet,
    PacketType,
    QtmProtocolError,
    QtmStreamDecoder,
    RawComponent,
    SixDBody,
    SixDComponent,
    StreamFramesRequest,
    XmlPacket,
    body_from_pose,
    build_6d_parameters_xml,
    decode_datagram,
    decode_packet,
    encode_packet,
    frame_from_packet,
    packet_from_poses,
    parse_6d_parameters,
    parse_stream_frames,
    parse_version,
    pose_from_body,
    stream_frames_command,
)

SIX_D_KINDS = sorted(SIX_D_RECORD_SIZE_B)
MATRIX_KINDS = {ComponentType.SIX_D, ComponentType.SIX_D_RES}
RESIDUAL_KINDS = {ComponentType.SIX_D_RES, ComponentType.SIX_D_EULER_RES}
ALL_ONES_NAN = b"\xff\xff\xff\xff"


def same_floats(a: Any, b: Any) -> bool:
    """Equality of nested float tuples where NaN equals NaN."""
    if isinstance(a, tuple) and isinstance(b, tuple):
        return len(a) == len(b) and all(same_floats(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float):
        return (math.isnan(a) and math.isnan(b)) or a == b
    return bool(a == b)


def decode_data(data: bytes) -> DataPacket:
    packet = decode_datagram(data)
    assert isinstance(packet, DataPacket)
    return packet


def body_values(body: SixDBody) -> tuple[Any, ...]:
    return (body.position_mm, body.rotation, body.euler_deg, body.residual_mm)


# --- Strategies ------------------------------------------------------------------------------

f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)


@st.composite
def six_d_bodies(draw: st.DrawFn, kind: ComponentType) -> SixDBody:
    if draw(st.booleans()) and draw(st.booleans()):
        return SixDBody.untracked(kind)
    position = (draw(f32), draw(f32), draw(f32))
    rotation = tuple(draw(f32) for _ in range(9)) if kind in MATRIX_KINDS else None
    euler = (draw(f32), draw(f32), draw(f32)) if kind not in MATRIX_KINDS else None
    residual = draw(f32) if kind in RESIDUAL_KINDS else None
    return SixDBody(position, rotation, euler, residual)


@st.composite
def six_d_components(draw: st.DrawFn) -> SixDComponent:
    kind = draw(st.sampled_from(SIX_D_KINDS))
    bodies = draw(st.lists(six_d_bodies(kind), max_size=4))
    rates = st.integers(0, 0xFFFF)
    return SixDComponent(kind, tuple(bodies), draw(rates), draw(rates))


raw_components = st.builds(
    RawComponent, st.sampled_from([1, 2, 3, 17, 18, 19, 1000]), st.binary(max_size=24)
)
data_packets = st.builds(
    DataPacket,
    st.integers(-(2**63), 2**63 - 1),
    st.integers(0, 2**32 - 1),
    st.lists(st.one_of(six_d_components(), raw_components), max_size=3).map(tuple),
)
# The SDK maps component types through an Enum: unknown ids (1000) would make it raise.
sdk_data_packets = st.builds(
    DataPacket,
    st.integers(-(2**63), 2**63 - 1),
    st.integers(0, 2**32 - 1),
    st.lists(
        st.one_of(six_d_components(), raw_components.filter(lambda c: c.component_type < 20)),
        max_size=3,
    ).map(tuple),
)
texts = st.text(st.characters(codec="ascii", exclude_characters="\0"), max_size=40)
packets: st.SearchStrategy[Packet] = st.one_of(
    data_packets,
    st.builds(CommandPacket, texts),
    st.builds(ErrorPacket, texts),
    st.builds(XmlPacket, texts),
    st.builds(EventPacket, st.integers(0, 255)),
    st.just(NoMoreDataPacket()),
    st.builds(
        OtherPacket,
        st.sampled_from([PacketType.C3D_FILE, PacketType.DISCOVER, PacketType.QTM_FILE]),
        st.binary(max_size=20),
    ),
)

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# --- The documented layout (docs/reference/qtm-rt.md §1.4), built by hand ----------------------


def test_hand_built_6deuler_packet_from_the_documented_layout() -> None:
    # "a frame with one 6DEuler component and 2 bodies is 8+16+8+8+2·24 = 88 bytes" (§1.4)
    bodies = struct.pack("<3f3f", 1000.0, -250.5, 1500.0, 10.0, -20.0, 170.0) + ALL_ONES_NAN * 6
    component = struct.pack("<IHH", 2, 5, 7) + bodies
    payload = struct.pack("<qII", 123_456_789, 4242, 1) + struct.pack("<II", 8 + len(component), 6)
    data = struct.pack("<II", 8 + len(payload) + len(component), 3) + payload + component
    assert len(data) == 88

    packet = decode_packet(data)
    assert isinstance(packet, DataPacket)
    assert (packet.timestamp_us, packet.frame_number) == (123_456_789, 4242)
    six_d = packet.six_d()
    assert six_d is not None and six_d.component_type == ComponentType.SIX_D_EULER
    assert (six_d.drop_rate_permille, six_d.out_of_sync_rate_permille) == (5, 7)
    first, second = six_d.bodies
    assert first.position_mm == (1000.0, -250.5, 1500.0) and first.euler_deg == (10.0, -20.0, 170.0)
    assert first.tracked and not second.tracked

    frame = frame_from_packet(packet, ["uav1", "bar"])
    uav1, bar = frame.bodies["uav1"], frame.bodies["bar"]
    np.testing.assert_allclose(uav1.position_m, [1.0, -0.2505, 1.5])
    # Qualisys standard: R = Rx(roll)·Ry(pitch)·Rz(yaw), angles in degrees.
    r, p, y = np.radians([10.0, -20.0, 170.0])
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    np.testing.assert_allclose(uav1.rotation(), Rx @ Ry @ Rz, atol=1e-6)
    assert not bar.tracked and np.isnan(bar.position_m).all() and np.isnan(bar.quaternion).all()
    # The SDK reads the same bytes the same way.
    sdk = QRTPacket(data[8:])
    assert sdk.framenumber == 4242 and sdk.timestamp == 123_456_789
    _, sdk_bodies = sdk.get_6d_euler()
    assert tuple(sdk_bodies[0][1]) == (10.0, -20.0, 170.0)


def test_hand_built_6d_packet_column_major_rotation() -> None:
    # 90° about z: body x → global y. Column-major: m0..m2 is the first column (§1.4).
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    matrix = R.flatten(order="F")
    component = struct.pack("<IHH", 1, 0, 0) + struct.pack("<12f", 10.0, 20.0, 30.0, *matrix)
    payload = struct.pack("<qII", 0, 1, 1) + struct.pack("<II", 8 + len(component), 5) + component
    data = struct.pack("<II", 8 + len(payload), 3) + payload
    assert len(data) == 8 + 16 + 8 + 8 + 48
    pose = frame_from_packet(decode_data(data), ["b"]).bodies["b"]
    np.testing.assert_allclose(pose.rotation() @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(pose.euler_zyx_rad, [0.0, 0.0, math.pi / 2], atol=1e-12)
    np.testing.assert_allclose(pose.position_m, [0.01, 0.02, 0.03])


def test_text_and_event_packets_by_hand() -> None:
    greeting = b"QTM RT Interface connected\0"
    assert decode_packet(struct.pack("<II", 8 + len(greeting), 1) + greeting) == CommandPacket(
        "QTM RT Interface connected"
    )
    assert decode_packet(struct.pack("<IIB", 9, 6, 3)) == EventPacket(3)
    assert decode_packet(struct.pack("<II", 8, 4)) == NoMoreDataPacket()
    assert encode_packet(CommandPacket("Version 1.25")) == (
        struct.pack("<II", 8 + 13, 1) + b"Version 1.25\0"
    )


# --- Round trips -----------------------------------------------------------------------------


@pytest.mark.parametrize("kind", SIX_D_KINDS)
def test_every_component_round_trips(kind: ComponentType) -> None:
    rng = random.Random(int(kind))
    n_floats = SIX_D_RECORD_SIZE_B[kind] // 4
    bodies = []
    for _ in range(3):
        values = [struct.unpack("<f", struct.pack("<f", rng.uniform(-3000, 3000)))[0]]
        values += [
            struct.unpack("<f", struct.pack("<f", rng.uniform(-1, 1)))[0] for _ in range(n_floats)
        ]
        rotation = tuple(values[3:12]) if kind in MATRIX_KINDS else None
        euler = (values[3], values[4], values[5]) if kind not in MATRIX_KINDS else None
        residual = values[-1] if kind in RESIDUAL_KINDS else None
        bodies.append(SixDBody((values[0], values[1], values[2]), rotation, euler, residual))
    bodies.append(SixDBody.untracked(kind))
    packet = DataPacket(987_654, 2**32 - 1, (SixDComponent(kind, tuple(bodies), 3, 4),))
    data = encode_packet(packet)
    assert len(data) == 8 + 16 + 8 + 8 + 4 * SIX_D_RECORD_SIZE_B[kind]
    decoded = decode_packet(data)
    assert isinstance(decoded, DataPacket)
    component = decoded.six_d()
    assert component is not None
    assert component.component_type == kind and component.drop_rate_permille == 3
    for got, want in zip(component.bodies, bodies, strict=True):
        assert same_floats(body_values(got), body_values(want))
    assert data[-SIX_D_RECORD_SIZE_B[kind] :] == ALL_ONES_NAN * n_floats  # QTM's NaN bits
    assert encode_packet(decoded) == data


@FAST
@given(packets)
def test_encode_decode_encode_is_stable(packet: Packet) -> None:
    data = encode_packet(packet)
    decoded = decode_packet(data)
    assert type(decoded) is type(packet)
    assert encode_packet(decoded) == data
    assert decode_datagram(data) is not None


@FAST
@given(sdk_data_packets)
def test_sdk_parser_agrees_with_ours(packet: DataPacket) -> None:
    data = encode_packet(packet)
    ours = decode_packet(data)
    assert isinstance(ours, DataPacket)
    sdk = QRTPacket(data[8:])  # qtm-rt expects the bytes after the RT header (§1.4)
    assert (sdk.timestamp, sdk.framenumber) == (ours.timestamp_us, ours.frame_number)
    getters = {
        ComponentType.SIX_D: sdk.get_6d,
        ComponentType.SIX_D_RES: sdk.get_6d_residual,
        ComponentType.SIX_D_EULER: sdk.get_6d_euler,
        ComponentType.SIX_D_EULER_RES: sdk.get_6d_euler_residual,
    }
    for kind, getter in getters.items():
        ours_of_kind = [
            c for c in ours.components if isinstance(c, SixDComponent) and c.component_type == kind
        ]
        if not ours_of_kind:
            assert QRTComponentType(kind) not in sdk.components
            continue
        component = ours_of_kind[-1]  # the SDK keeps only the last component of each type
        info, sdk_bodies = getter()
        assert info.body_count == len(component.bodies)
        for body, sdk_body in zip(component.bodies, sdk_bodies, strict=True):
            assert same_floats(body.position_mm, tuple(sdk_body[0]))
            if kind in MATRIX_KINDS:
                assert same_floats(body.rotation, tuple(sdk_body[1].matrix))
            else:
                assert same_floats(body.euler_deg, tuple(sdk_body[1]))
            if kind in RESIDUAL_KINDS:
                assert same_floats(body.residual_mm, sdk_body[2].residual)


# --- Untracked bodies ------------------------------------------------------------------------


@pytest.mark.parametrize("kind", SIX_D_KINDS)
def test_untracked_bodies_are_never_zeros(kind: ComponentType) -> None:
    names = ["uav1", "uav2", "bar"]
    tracked = BodyPose.from_rotation("uav1", np.array([0.1, 0.2, 0.3]), np.eye(3))
    packet = packet_from_poses(
        5, 0, names, {"uav1": tracked, "uav2": BodyPose.untracked("uav2")}, [kind]
    )
    frame = frame_from_packet(decode_data(encode_packet(packet)), names)
    assert frame.bodies["uav1"].tracked
    for name in ("uav2", "bar"):  # explicitly untracked, and missing from the source
        pose = frame.bodies[name]
        assert not pose.tracked
        for array in (pose.position_m, pose.quaternion, pose.euler_zyx_rad):
            assert np.isnan(array).all()


def test_any_nan_value_or_nan_residual_means_untracked() -> None:
    good = SixDBody((1.0, 2.0, 3.0), None, (0.0, 0.0, 0.0), 0.4)
    assert good.tracked
    assert not SixDBody((1.0, 2.0, 3.0), None, (0.0, 0.0, 0.0), math.nan).tracked
    assert not SixDBody((1.0, math.nan, 3.0), None, (0.0, 0.0, 0.0), None).tracked
    assert not SixDBody((1.0, 2.0, math.inf), None, (0.0, 0.0, 0.0), None).tracked
    # Other NaN encodings than QTM's all-ones, e.g. the positive quiet NaN 0x7fc00000.
    record = struct.pack("<3f3f", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0)
    record = b"\x00\x00\xc0\x7f" + record[4:]
    component = struct.pack("<IHH", 1, 0, 0) + record
    data = struct.pack("<qII", 0, 1, 1) + struct.pack("<II", 8 + len(component), 6) + component
    packet = decode_packet(struct.pack("<II", 8 + len(data), 3) + data)
    assert isinstance(packet, DataPacket)
    six_d = packet.six_d()
    assert six_d is not None
    assert not pose_from_body("b", six_d.bodies[0]).tracked


# --- Poses -----------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", SIX_D_KINDS)
def test_poses_survive_the_wire_within_float32(kind: ComponentType) -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        euler = rng.uniform([-math.pi, -1.5, -math.pi], [math.pi, 1.5, math.pi])
        R = frames.rotation_from_euler_zyx(*euler)
        position = rng.uniform(-4.0, 4.0, 3)
        pose = BodyPose.from_rotation("b", position, R)
        body = body_from_pose(pose, kind)
        decoded = decode_data(encode_packet(DataPacket(0, 1, (SixDComponent(kind, (body,)),))))
        back = frame_from_packet(decoded, ["b"]).bodies["b"]
        np.testing.assert_allclose(back.position_m, position, atol=1e-6)
        np.testing.assert_allclose(back.rotation(), R, atol=2e-6)
        q_err = frames.rotation_vector_from_quaternion(
            frames.quaternion_multiply(
                frames.quaternion_conjugate(pose.quaternion), back.quaternion
            )
        )
        assert np.linalg.norm(q_err) < 2e-6


def test_qtm_euler_convention_examples() -> None:
    # Roll +90° (about x): the body's y axis points up the global z axis.
    np.testing.assert_allclose(
        frames.rotation_from_qtm_euler_deg(90, 0, 0) @ [0, 1, 0], [0, 0, 1], atol=1e-12
    )
    # Roll then pitch about the *rotated* y: equals Rx·Ry, not Ry·Rx.
    R = frames.rotation_from_qtm_euler_deg(90, 90, 0)
    np.testing.assert_allclose(
        R,
        frames.rotation_from_qtm_euler_deg(90, 0, 0) @ frames.rotation_from_qtm_euler_deg(0, 90, 0),
        atol=1e-12,
    )
    np.testing.assert_allclose(frames.qtm_euler_deg_from_rotation(R) @ [0, 1, 0], 90.0)


def test_corrupt_rotation_matrix_is_a_protocol_error() -> None:
    body = SixDBody((0.0, 0.0, 0.0), (2.0,) + (0.0,) * 8)
    with pytest.raises(QtmProtocolError):
        pose_from_body("b", body)
    mirror = SixDBody((0.0, 0.0, 0.0), (-1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0))
    with pytest.raises(QtmProtocolError):
        pose_from_body("b", mirror)
    packet = DataPacket(0, 1, (SixDComponent(ComponentType.SIX_D, (body,)),))
    with pytest.raises(QtmProtocolError, match="bodies in the data"):
        frame_from_packet(packet, ["a", "b"])
    with pytest.raises(QtmProtocolError, match="without a 6D"):
        frame_from_packet(DataPacket(0, 1, ()), [])


# --- Streams: byte at a time == whole --------------------------------------------------------


def stream_events(data: bytes, chunks: list[int]) -> tuple[list[bytes], bool]:
    decoder = QtmStreamDecoder()
    out: list[bytes] = []
    position = 0
    try:
        for size in chunks:
            decoder.receive_data(data[position : position + size])
            position += size
            while (packet := decoder.next_packet()) is not None:
                out.append(encode_packet(packet))
    except QtmProtocolError:
        return out, True
    return out, False


@FAST
@given(st.lists(packets, max_size=6), st.randoms(use_true_random=False))
def test_byte_at_a_time_equals_whole(sequence: list[Packet], rnd: random.Random) -> None:
    data = b"".join(encode_packet(p) for p in sequence)
    expected = [encode_packet(p) for p in sequence]
    assert stream_events(data, [len(data)]) == (expected, False)
    assert stream_events(data, [1] * len(data)) == (expected, False)
    sizes = [rnd.randint(1, 30) for _ in range(len(data))]
    assert stream_events(data, sizes) == (expected, False)
    decoder = QtmStreamDecoder()
    assert [encode_packet(p) for p in decoder.feed(data)] == expected and decoder.buffered == 0


def test_stream_decoder_fails_for_good_and_keeps_earlier_packets() -> None:
    good = encode_packet(EventPacket(1)) + encode_packet(NoMoreDataPacket())
    bad = struct.pack("<II", 4, 1)  # size smaller than the header
    decoder = QtmStreamDecoder()
    with pytest.raises(QtmProtocolError) as raised:
        decoder.feed(good + bad + encode_packet(EventPacket(2)))
    assert raised.value.packets == (EventPacket(1), NoMoreDataPacket())
    assert decoder.failed
    with pytest.raises(QtmProtocolError):
        decoder.feed(encode_packet(EventPacket(3)))
    with pytest.raises(QtmProtocolError):
        decoder.next_packet()


def test_stream_decoder_waits_for_more_and_caps_sizes() -> None:
    data = encode_packet(CommandPacket("Version set to 1.25"))
    decoder = QtmStreamDecoder()
    assert decoder.feed(data[:-1]) == [] and decoder.buffered == len(data) - 1
    assert decoder.feed(data[-1:]) == [CommandPacket("Version set to 1.25")]
    with pytest.raises(QtmProtocolError, match="exceeds"):
        QtmStreamDecoder(max_packet_size=1000).feed(struct.pack("<II", 1001, 2))


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"", "cannot hold"),
        (struct.pack("<II", 7, 1) + b"\0", "smaller"),
        (struct.pack("<II", 8, 9), "unknown packet type"),
        (struct.pack("<II", 12, 1) + b"ab", "header says"),
        (struct.pack("<II", 8, 4) + b"x", "header says"),
        (struct.pack("<II", 10, 6) + b"\1\2", "event"),
        (struct.pack("<II", 9, 4) + b"\0", "no-more-data"),
        (struct.pack("<II", 20, 3) + bytes(12), "no frame header"),
        (struct.pack("<II", 24, 3) + struct.pack("<qII", 0, 1, 1), "cannot fit"),
        (
            struct.pack("<II", 32, 3) + struct.pack("<qII", 0, 1, 1) + struct.pack("<II", 4, 5),
            "does not fit",
        ),
        (
            struct.pack("<II", 40, 3)
            + struct.pack("<qII", 0, 1, 1)
            + struct.pack("<II", 16, 5)
            + struct.pack("<IHH", 1, 0, 0),
            "cannot hold 1 bodies",
        ),
        (
            struct.pack("<II", 36, 3)
            + struct.pack("<qII", 0, 1, 1)
            + struct.pack("<II", 8, 99)
            + b"zzzz",
            "after the last component",
        ),
    ],
)
def test_malformed_packets_raise_the_codec_error(data: bytes, reason: str) -> None:
    with pytest.raises(QtmProtocolError, match=reason):
        decode_datagram(data)


# --- Fuzzing ---------------------------------------------------------------------------------


def test_fuzz_core_finds_no_escapes() -> None:
    counts = run_fuzz(3000, seed=20240611)
    assert counts.packets == 3000
    assert counts.escaped == 0, counts.examples
    assert counts.inconsistent == 0, counts.examples
    # The mutations really exercise both outcomes of both decoders.
    assert counts.accepted > 300 and counts.rejected > 300
    assert counts.stream_rejected > 300 and counts.stream_incomplete > 30
    assert counts.frames_converted > 30 and counts.frames_rejected > 10


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200))
def test_random_bytes_raise_only_the_codec_error(data: bytes) -> None:
    with contextlib.suppress(QtmProtocolError):
        decode_datagram(data)
    decoder = QtmStreamDecoder()
    try:
        for i in range(0, len(data), 7):
            decoder.feed(data[i : i + 7])
    except QtmProtocolError:
        assert decoder.failed


@settings(max_examples=300, deadline=None)
@given(data_packets, st.integers(0, 10_000), st.integers(0, 255))
def test_single_byte_corruption_of_data_packets(packet: DataPacket, where: int, value: int) -> None:
    data = bytearray(encode_packet(packet))
    data[where % len(data)] = value
    try:
        decoded = decode_datagram(bytes(data))
    except QtmProtocolError:
        return
    component = decoded.six_d() if isinstance(decoded, DataPacket) else None
    if isinstance(decoded, DataPacket) and component is not None:
        with contextlib.suppress(QtmProtocolError):
            frame_from_packet(decoded, [str(i) for i in range(len(component.bodies))])


# --- Commands and XML ------------------------------------------------------------------------


def test_stream_frames_commands() -> None:
    command = stream_frames_command([ComponentType.SIX_D_EULER], udp_port=6734)
    assert command == "StreamFrames AllFrames UDP:6734 6DEuler"
    request = parse_stream_frames(command.split(" ", 1)[1])
    assert request == StreamFramesRequest(False, "allframes", None, None, 6734, ("6deuler",))
    assert parse_stream_frames("stop") == StreamFramesRequest(stop=True)
    request = parse_stream_frames("FrequencyDivisor:4 UDP:10.0.0.2:5000 6D 6dres")
    assert (request.rate, request.rate_value, request.udp_address, request.udp_port) == (
        "frequencydivisor",
        4,
        "10.0.0.2",
        5000,
    )
    assert request.components == ("6d", "6dres")
    assert parse_stream_frames("allframes 6d").udp_port is None  # TCP streaming (qtm-rt)
    for bad in (
        "",
        "Sometimes 6D",
        "Frequency:0 6D",
        "AllFrames UDP:0 6D",
        "AllFrames UDP:x 6D",
        "AllFrames",
    ):
        with pytest.raises(QtmProtocolError):
            parse_stream_frames(bad)
    assert parse_version("Version set to 1.25") == (1, 25)
    with pytest.raises(QtmProtocolError):
        parse_version("Version NOT supported")


XML_1_20 = """<QTM_Parameters_Ver_1.20><The_6D><Bodies>2</Bodies>
<Body><Name>uav1</Name><RGBColor>255</RGBColor><Point><X>1</X><Y>2</Y><Z>3</Z></Point></Body>
<Body><Name> bar </Name><RGBColor>0</RGBColor></Body>
<Euler><First>Roll</First><Second>Pitch</Second><Third>Yaw</Third></Euler></The_6D>
</QTM_Parameters_Ver_1.20>"""

XML_1_25 = """<QTM_Parameters_Ver_1.25>
    <The_6D>
        <Body>
            <Name>uav1</Name><Enabled>true</Enabled><Color R="0" G="255" B="0"/>
            <MaximumResidual>20.000000</MaximumResidual><Filter Preset="No filter"/>
            <Points><Point X="-67.9" Y="29.8" Z="-1.5" Virtual="0" Name="m1"/></Points>
            <Data_origin X="0.0" Y="0.0" Z="0.0" Relative_body="1">0</Data_origin>
        </Body>
        <Body><Name>uav2</Name><Enabled>false</Enabled></Body>
        <Body><Name>bar</Name><Enabled>true</Enabled></Body>
    </The_6D>
</QTM_Parameters_Ver_1.25>"""


def test_6d_parameters_in_both_layouts() -> None:
    assert parse_6d_parameters(XML_1_20).names == ("uav1", "bar")
    parameters = parse_6d_parameters(XML_1_25)
    assert parameters.names == ("uav1", "uav2", "bar")
    assert parameters.enabled == (True, False, True)  # disabled bodies keep their index
    # Qualisys' own example reads the names with findall("*/Body/Name").
    assert [e.text for e in ET.fromstring(XML_1_25).findall("*/Body/Name")] == [
        "uav1",
        "uav2",
        "bar",
    ]
    for version in ((1, 20), (1, 25)):
        assert parse_6d_parameters(build_6d_parameters_xml(["a", "b c", "ü"], version)).names == (
            "a",
            "b c",
            "ü",
        )


@pytest.mark.parametrize(
    "xml",
    [
        "",
        "<not xml",
        "<QTM_Parameters_Ver_1.25><General/></QTM_Parameters_Ver_1.25>",
        "<X><The_6D><Body><Enabled>true</Enabled></Body></The_6D></X>",
        "<X><The_6D><Body><Name>a</Name></Body><Body><Name>a</Name></Body></The_6D></X>",
        '<!DOCTYPE x [<!ENTITY a "aaaa">]><X><The_6D><Body><Name>&a;</Name></Body></The_6D></X>',
    ],
)
def test_bad_6d_parameters_raise_the_codec_error(xml: str) -> None:
    with pytest.raises(QtmProtocolError):
        parse_6d_parameters(xml)


def test_encoder_refuses_values_it_cannot_represent() -> None:
    with pytest.raises(ValueError, match="rotation"):
        encode_packet(
            DataPacket(0, 0, (SixDComponent(ComponentType.SIX_D, (SixDBody((0, 0, 0)),)),))
        )
    with pytest.raises(ValueError, match="float32"):
        body = SixDBody((1e39, 0.0, 0.0), None, (0.0, 0.0, 0.0))
        encode_packet(DataPacket(0, 0, (SixDComponent(ComponentType.SIX_D_EULER, (body,)),)))
