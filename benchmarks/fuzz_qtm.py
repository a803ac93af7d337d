"""Fuzz the QTM RT decoders with random and mutated packets; print what happened.

    python benchmarks/fuzz_qtm.py --count 100000 [--seed 0]

Each case is a valid packet (every packet type, 6D/6DRes/6DEuler/6DEulerRes components,
tracked and NaN bodies, unknown components) passed through one mutation: none, byte flips,
truncation, trailing bytes, a lying size field (packet, component, component count, body
count), a changed packet or component type, random bytes, or two packets spliced. Each
case goes to

* ``decode_datagram`` (UDP): accepted, or rejected with ``QtmProtocolError``;
* ``QtmStreamDecoder`` (TCP), between two valid packets, fed whole and fed in random
  chunks (byte at a time for one case in eight): both must give the same packets and the
  same error;
* for accepted data packets, ``frame_from_packet`` (mm → m, rotations), which may also
  only raise ``QtmProtocolError``; every accepted packet must re-encode.

Anything else raised is *escaped*; a whole/chunked disagreement is *inconsistent*. The
script exits with status 1 if either count is non-zero. The core, ``run_fuzz``, is what
the test suite calls with a few thousand cases (docs/reference/qtm-rt.md §1.4 for the layouts).
"""

from __future__ import annotations

import argparse
import math
import random
import struct
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from mocap.qtm_protocol import (
    COMPONENT_HEADER,
    DATA_HEADER,
    HEADER,
    SIX_D_TYPES,
    CommandPacket,
    ComponentType,
    DataComponent,
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
    XmlPacket,
    build_6d_parameters_xml,
    decode_datagram,
    encode_packet,
    frame_from_packet,
)

MUTATIONS = (
    "none",
    "flip",
    "truncate",
    "extend",
    "size_lie",
    "type_change",
    "component_lie",
    "random_bytes",
    "splice",
)


@dataclass
class FuzzCounts:
    """What the decoders did with the cases. ``accepted``/``rejected`` are for the
    datagram decoder; ``stream_*`` for the TCP stream decoder fed the case whole."""

    packets: int = 0
    accepted: int = 0
    rejected: int = 0
    stream_accepted: int = 0
    stream_rejected: int = 0
    stream_incomplete: int = 0
    frames_converted: int = 0
    frames_rejected: int = 0
    escaped: int = 0
    inconsistent: int = 0
    by_mutation: dict[str, int] = field(default_factory=dict)
    examples: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """No exception but ``QtmProtocolError`` escaped and whole == chunked everywhere."""
        return self.escaped == 0 and self.inconsistent == 0


def _float(rng: random.Random) -> float:
    roll = rng.random()
    if roll < 0.05:
        return math.nan
    if roll < 0.08:
        return rng.choice((math.inf, -math.inf, 0.0, -0.0, 3.4e38, -3.4e38, 1e-45))
    return rng.uniform(-5000.0, 5000.0)


def _six_d_body(rng: random.Random, kind: ComponentType) -> SixDBody:
    if rng.random() < 0.2:
        return SixDBody.untracked(kind)
    position = (_float(rng), _float(rng), _float(rng))
    rotation: tuple[float, ...] | None = None
    euler: tuple[float, float, float] | None = None
    if kind not in (ComponentType.SIX_D, ComponentType.SIX_D_RES):
        euler = (rng.uniform(-180, 180), rng.uniform(-90, 90), _float(rng))
    elif rng.random() < 0.7:  # a real rotation (column-major): exercises the tracked path
        a, b = rng.uniform(-math.pi, math.pi), rng.uniform(-math.pi, math.pi)
        ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
        rotation = (ca * cb, sa * cb, -sb, -sa, ca, 0.0, ca * sb, sa * sb, cb)
    else:
        rotation = tuple(rng.uniform(-1.5, 1.5) for _ in range(9))
    residual = (
        rng.uniform(0, 5)
        if kind in (ComponentType.SIX_D_RES, ComponentType.SIX_D_EULER_RES)
        else None
    )
    return SixDBody(position, rotation, euler, residual)


def _component(rng: random.Random) -> DataComponent:
    if rng.random() < 0.15:
        kind = rng.choice((1, 2, 3, 17, 18, 19, 99))
        return RawComponent(kind, rng.randbytes(rng.randrange(0, 40)))
    six_d_kind = rng.choice(sorted(SIX_D_TYPES))
    bodies = tuple(_six_d_body(rng, six_d_kind) for _ in range(rng.randrange(0, 6)))
    return SixDComponent(six_d_kind, bodies, rng.randrange(0, 1000), rng.randrange(0, 1000))


def random_packet(rng: random.Random) -> Packet:
    """A valid packet of a random type, weighted towards data packets."""
    roll = rng.random()
    if roll < 0.55:
        components = tuple(_component(rng) for _ in range(rng.choice((0, 1, 1, 1, 2, 3))))
        return DataPacket(rng.randrange(-(2**40), 2**62), rng.randrange(0, 2**32), components)
    if roll < 0.65:
        return CommandPacket(rng.choice(("QTM RT Interface connected", "Version set to 1.25", "")))
    if roll < 0.72:
        return ErrorPacket(rng.choice(("Parse Error", "Version NOT supported")))
    if roll < 0.80:
        names = [f"body{i}" for i in range(rng.randrange(0, 4))]
        return XmlPacket(build_6d_parameters_xml(names))
    if roll < 0.88:
        return EventPacket(rng.randrange(0, 256))
    if roll < 0.95:
        return NoMoreDataPacket()
    kind = rng.choice((PacketType.C3D_FILE, PacketType.DISCOVER, PacketType.QTM_FILE))
    return OtherPacket(kind, rng.randbytes(rng.randrange(0, 30)))


def _put_u32(data: bytearray, offset: int, value: int) -> None:
    if offset + 4 <= len(data):
        struct.pack_into("<I", data, offset, value & 0xFFFFFFFF)


def _lie(rng: random.Random, true_value: int) -> int:
    return rng.choice(
        (0, 1, 7, 8, true_value - 1, true_value + 1, true_value * 2, rng.randrange(0, 2**32))
    )


def mutate(rng: random.Random, data: bytes, mutation: str) -> bytes:
    """One named mutation of a packet's bytes (see ``MUTATIONS``)."""
    out = bytearray(data)
    if mutation == "flip":
        for _ in range(rng.randint(1, 8)):
            if out:
                out[rng.randrange(len(out))] ^= rng.randint(1, 255)
    elif mutation == "truncate":
        del out[rng.randrange(len(out) + 1) :]
    elif mutation == "extend":
        out += rng.randbytes(rng.randint(1, 16))
    elif mutation == "size_lie":
        _put_u32(out, 0, _lie(rng, len(out)))
    elif mutation == "type_change":
        _put_u32(out, 4, rng.choice((*range(0, 12), rng.randrange(0, 2**32))))
    elif mutation == "component_lie":
        # Lie in the data-frame component count, a component size or a 6D body count.
        offset = HEADER.size + DATA_HEADER.size
        target = rng.choice(("count", "size", "bodies"))
        if target == "count":
            _put_u32(out, HEADER.size + 12, _lie(rng, 1))
        elif target == "size":
            _put_u32(out, offset, _lie(rng, 8))
        else:
            _put_u32(out, offset + COMPONENT_HEADER.size, _lie(rng, 2))
    elif mutation == "random_bytes":
        out = bytearray(rng.randbytes(rng.randrange(0, 200)))
        if rng.random() < 0.5 and len(out) >= 8:  # a plausible header on random content
            struct.pack_into("<II", out, 0, len(out), rng.randrange(0, 9))
    elif mutation == "splice":
        other = encode_packet(random_packet(rng))
        out = out[: rng.randrange(len(out) + 1)] + other[rng.randrange(len(other) + 1) :]
    return bytes(out)


def _stream_run(decoder_input: bytes, chunks: Sequence[int]) -> tuple[list[bytes], str | None, int]:
    """Feed ``decoder_input`` in chunks of the given sizes: (re-encoded packets, error, left)."""
    decoder = QtmStreamDecoder()
    packets: list[bytes] = []
    position = 0
    try:
        for size in chunks:
            for packet in decoder.feed(decoder_input[position : position + size]):
                packets.append(encode_packet(packet))
            position += size
    except QtmProtocolError as error:
        packets += [encode_packet(packet) for packet in error.packets]
        return packets, str(error), decoder.buffered
    return packets, None, decoder.buffered


def _chunk_sizes(rng: random.Random, length: int, byte_at_a_time: bool) -> list[int]:
    if byte_at_a_time:
        return [1] * length
    sizes: list[int] = []
    while sum(sizes) < length:
        sizes.append(rng.randint(1, 64))
    return sizes


def _check_case(rng: random.Random, case: bytes, counts: FuzzCounts) -> None:
    try:
        packet = decode_datagram(case)
    except QtmProtocolError:
        counts.rejected += 1
    else:
        counts.accepted += 1
        decode_datagram(encode_packet(packet))  # the encoder accepts whatever decodes
        if isinstance(packet, DataPacket) and packet.six_d() is not None:
            component = packet.six_d()
            assert component is not None
            names = [f"b{i}" for i in range(len(component.bodies))]
            try:
                frame_from_packet(packet, names, 0.0)
                counts.frames_converted += 1
            except QtmProtocolError:
                counts.frames_rejected += 1

    prefix = encode_packet(random_packet(rng)) if rng.random() < 0.3 else b""
    suffix = encode_packet(random_packet(rng)) if rng.random() < 0.3 else b""
    stream = prefix + case + suffix
    whole = _stream_run(stream, [len(stream)])
    chunked = _stream_run(stream, _chunk_sizes(rng, len(stream), rng.random() < 0.125))
    # Same packets and same verdict; after an error the two buffers legitimately differ.
    same_verdict = (whole[1] is None) == (chunked[1] is None)
    same_rest = whole[1] is not None or whole[2] == chunked[2]
    if whole[0] != chunked[0] or not same_verdict or not same_rest:
        counts.inconsistent += 1
        if len(counts.examples) < 5:
            counts.examples.append(f"inconsistent: {stream.hex()}")
    if whole[1] is not None:
        counts.stream_rejected += 1
    elif whole[2]:
        counts.stream_incomplete += 1
    else:
        counts.stream_accepted += 1


def run_fuzz(
    count: int, seed: int = 0, progress: Callable[[int], None] | None = None
) -> FuzzCounts:
    """Run ``count`` cases from ``seed``; deterministic for a given (count, seed)."""
    rng = random.Random(seed)
    counts = FuzzCounts()
    for index in range(count):
        mutation = MUTATIONS[index % len(MUTATIONS)]
        case = mutate(rng, encode_packet(random_packet(rng)), mutation)
        counts.packets += 1
        counts.by_mutation[mutation] = counts.by_mutation.get(mutation, 0) + 1
        try:
            _check_case(rng, case, counts)
        except Exception as error:  # counting escapes is the point
            counts.escaped += 1
            if len(counts.examples) < 5:
                counts.examples.append(f"{type(error).__name__}: {error}: {case.hex()}")
        if progress is not None and (index + 1) % 10000 == 0:
            progress(index + 1)
    return counts


def main(argv: Sequence[str] | None = None) -> int:
    """Command line: run the fuzzer, print the counts, exit 1 on any escape."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=100_000, help="cases (default 100000)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    counts = run_fuzz(args.count, args.seed)
    elapsed = time.perf_counter() - started
    print(f"packets            {counts.packets}")
    print(f"accepted           {counts.accepted}   (datagram decoder)")
    print(f"rejected           {counts.rejected}   (QtmProtocolError)")
    print(f"stream accepted    {counts.stream_accepted}")
    print(f"stream rejected    {counts.stream_rejected}")
    print(f"stream incomplete  {counts.stream_incomplete}   (waiting for more bytes)")
    print(f"frames converted   {counts.frames_converted}   rejected {counts.frames_rejected}")
    print(f"escaped exceptions {counts.escaped}")
    print(f"inconsistent       {counts.inconsistent}   (whole vs chunked)")
    print("mutations          " + ", ".join(f"{k} {v}" for k, v in counts.by_mutation.items()))
    print(f"time               {elapsed:.1f} s, seed {args.seed}")
    for example in counts.examples:
        print("example:", example[:400])
    return 0 if counts.ok else 1


if __name__ == "__main__":
    sys.exit(main())
