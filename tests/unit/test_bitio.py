"""BitReader's run readers against reading bit by bit / chunk by chunk (property tests)."""

from __future__ import annotations

from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams.bitio import BitReader
from fbaconf.errors import BitstreamError

# bytes rich in 0xff (long chains) with a few others
_bytes = st.lists(
    st.sampled_from([0xFF, 0xFF, 0xFF, 0xFE, 0x7F, 0xF0, 0x0F, 0x00]) | st.integers(0, 255), max_size=40
).map(bytes)


def _chunkwise(r: BitReader) -> int:
    """number_of_frames_to_skip as the spec notes state it: 15 continues the chain."""
    total = 0
    while True:
        v = r.read(4, "number_of_frames_to_skip")
        total += v
        if v != 15:
            return total


def _outcome(fn, r: BitReader):
    try:
        return "ok", fn(r), r.pos
    except BitstreamError as e:
        return "error", str(e), e.bit_offset, e.rule


@settings(max_examples=400, deadline=None)
@given(_bytes, st.integers(0, 400))
def test_skip_chain_equals_reading_chunk_by_chunk(data, at):
    at = min(at, len(data) * 8)
    a, b = BitReader(data), BitReader(data)
    a.pos = b.pos = at
    assert _outcome(BitReader.skip_chain, a) == _outcome(_chunkwise, b)


@settings(max_examples=300, deadline=None)
@given(_bytes, st.integers(0, 400))
def test_ones_run_counts_bit_by_bit(data, at):
    at = min(at, len(data) * 8)
    bits = [(data[i >> 3] >> (7 - (i & 7))) & 1 for i in range(len(data) * 8)]
    k = 0
    while at + k < len(bits) and bits[at + k]:
        k += 1
    assert BitReader(data).ones_run(at) == k


def test_a_long_chain_by_hand():
    # 1,000 chunks of 15 then 0111 = 7: 15,007 frames; the next field starts after it
    data = b"\xff" * 500 + b"\x7a"
    r = BitReader(data)
    assert r.skip_chain() == 15 * 1000 + 7 and r.pos == 4004
    assert r.read(4) == 0xA
    r = BitReader(b"\xff" * 3 + b"\xf0")  # seven chunks of 15, then 0000
    assert r.skip_chain() == 15 * 7 and r.pos == 32
    r = BitReader(b"\xff\xff")  # never ends: truncated at bit 16, where the fifth chunk would start
    try:
        r.skip_chain()
    except BitstreamError as e:
        assert e.rule == "truncated" and e.bit_offset == 16
    else:
        raise AssertionError("a chain running off the end must be a truncation error")
