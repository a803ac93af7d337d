"""A few thousand fuzz cases of the QTM RT decoders (the full run: benchmarks/fuzz_qtm.py)."""

from __future__ import annotations

from benchmarks.fuzz_qtm import MUTATIONS, run_fuzz


def test_fuzzed_packets_only_raise_the_codecs_error() -> None:
    counts = run_fuzz(3000, seed=11)
    assert counts.escaped == 0, counts.examples
    assert counts.inconsistent == 0, counts.examples  # byte-at-a-time == whole
    assert set(counts.by_mutation) == set(MUTATIONS)
    # Both verdicts occur, so the fuzzer reaches the decoder's accepting and refusing paths.
    assert counts.accepted > 100 and counts.rejected > 100
    assert counts.frames_converted > 10
