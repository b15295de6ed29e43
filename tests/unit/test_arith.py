"""The adaptive arithmetic coder: round trips, stuffing, and the end-of-block rule (D7)."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, strategies as st

from fbaconf.bitstreams import arith
from fbaconf.bitstreams.arith import (
    LOOKAHEAD,
    MAX_FREQUENCY,
    ZERO_RUN_LIMIT,
    ArithDecoder,
    ArithEncoder,
    FastModel,
    Model,
    UniformModel,
    make_model,
)
from fbaconf.bitstreams.bitio import BitReader, BitWriter
from fbaconf.bitstreams.decoder import decode
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import BitstreamError


def code_block(prefix_bits: int, blocks, trailer: tuple[int, int]):
    """Write a prefix, then blocks of (alphabet, symbols, adaptive), then a raw trailer.

    Returns (bytes, positions after each block)."""
    w = BitWriter()
    w.write((1 << prefix_bits) - 1 if prefix_bits else 0, prefix_bits)
    ends = []
    for n, syms, adaptive in blocks:
        enc = ArithEncoder(w)
        m = make_model(n, adaptive)
        for s in syms:
            enc.encode(m, s)
        enc.flush()
        ends.append(w.position)
    w.write(*trailer)
    return w.getvalue(), ends


def decode_blocks(data: bytes, prefix_bits: int, blocks):
    r = BitReader(data)
    r.read(prefix_bits)
    outs, ends = [], []
    for n, syms, adaptive in blocks:
        dec = ArithDecoder(r)
        m = make_model(n, adaptive)
        outs.append([dec.decode(m) for _ in syms])
        dec.finish()
        ends.append(r.pos)
    return outs, ends, r


@st.composite
def blocks_strategy(draw):
    out = []
    for _ in range(draw(st.integers(1, 3))):
        n = draw(st.sampled_from([1, 2, 3, 15, 29, 64, 65, 127, 361, 3721]))
        mode = draw(st.sampled_from(["random", "last", "first", "runs"]))
        k = draw(st.integers(0, 120))
        if mode == "random":
            syms = draw(st.lists(st.integers(0, n - 1), min_size=k, max_size=k))
        elif mode == "last":  # the bottom of the interval: long runs of '0' output bits -> stuffing
            syms = [n - 1] * k
        elif mode == "first":
            syms = [0] * k
        else:
            syms = [draw(st.sampled_from([0, n - 1])) for _ in range(k)]
        out.append((n, syms, draw(st.booleans())))
    return out


@given(
    blocks=blocks_strategy(),
    prefix=st.integers(0, 15),
    trailer_bits=st.integers(1, 40),
    trailer_kind=st.sampled_from(["zeros", "ones", "random"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_blocks_round_trip_and_reposition(blocks, prefix, trailer_bits, trailer_kind, seed):
    rnd = random.Random(seed)
    tv = {"zeros": 0, "ones": (1 << trailer_bits) - 1, "random": rnd.getrandbits(trailer_bits)}[trailer_kind]
    data, ends = code_block(prefix, blocks, (tv, trailer_bits))
    outs, dends, r = decode_blocks(data, prefix, blocks)
    assert outs == [syms for _, syms, _ in blocks]
    assert dends == ends  # each block ends exactly where the encoder's block ended (D7)
    assert r.read(trailer_bits) == tv


def _encoder_bits(symbols, n):
    """Code with a uniform (non-adaptive) model: symbol n-1 of 2 costs one '0' bit each."""
    w = BitWriter()
    enc = ArithEncoder(w)
    m = make_model(n, adaptive=False)
    for s in symbols:
        enc.encode(m, s)
    enc.flush()
    return w, enc


def test_encoder_stuffs_after_22_zeros():
    # Symbol n-1 of a 2-symbol alphabet sits at the bottom of the interval: zeros.
    w, enc = _encoder_bits([1] * 200, 2)
    bits = "".join(f"{b:08b}" for b in w.getvalue())[: w.position]
    assert "0" * (ZERO_RUN_LIMIT + 1) not in bits
    assert ("0" * ZERO_RUN_LIMIT + "1") in bits


def test_stuffing_violation_inside_block_is_an_error():
    w, _ = _encoder_bits([1] * 200, 2)
    bits = list("".join(f"{b:08b}" for b in w.getvalue())[: w.position])
    i = "".join(bits).index("0" * ZERO_RUN_LIMIT + "1") + ZERO_RUN_LIMIT
    bits[i] = "0"  # the stuffing '1' becomes '0'
    s = "".join(bits) + "1" * 32
    data = (
        int(s, 2).to_bytes((len(s) + 7) // 8, "big")
        if len(s) % 8 == 0
        else int(s + "0" * (8 - len(s) % 8), 2).to_bytes((len(s) + 7) // 8, "big")
    )
    r = BitReader(data)
    dec = ArithDecoder(r)
    m = make_model(2, adaptive=False)
    with pytest.raises(BitstreamError) as e:
        for _ in range(200):
            dec.decode(m)
        dec.finish()
    assert e.value.rule == "stuffing"
    assert e.value.bit_offset == i


def _find_lookahead_stuffing_case():
    """A block whose decoder look-ahead crosses a stuffing event that lies after the block's end."""
    rnd = random.Random(7)
    for _ in range(20000):
        n = rnd.choice([2, 3, 5, 15])
        syms = [rnd.choice([n - 1, n - 1, n - 1, 0]) for _ in range(rnd.randint(1, 40))]
        w = BitWriter()
        enc = ArithEncoder(w)
        m = make_model(n)
        for s in syms:
            enc.encode(m, s)
        enc.flush()
        end = w.position
        w.write(0, 30)  # the next fields are zeros: the look-ahead sees a long zero run
        w.write(0b1011, 4)
        data = w.getvalue()
        r = BitReader(data)
        dec = ArithDecoder(r)
        m2 = make_model(n)
        out = [dec.decode(m2) for _ in syms]
        used = dec.count - LOOKAHEAD
        if any(c > used for c in dec.stuffing) and out == syms:
            return data, syms, n, end
    raise AssertionError("no look-ahead stuffing case found")


def test_d7_stuffing_in_lookahead_is_not_part_of_the_block():
    data, syms, n, end = _find_lookahead_stuffing_case()
    r = BitReader(data)
    dec = ArithDecoder(r)
    m = make_model(n)
    assert [dec.decode(m) for _ in syms] == syms
    after_read = r.pos
    dec.finish()  # D7: no error although a '0' follows 22 zeros in the look-ahead
    assert r.pos == end
    assert r.read(30) == 0 and r.read(4) == 0b1011
    # S1's reading (rewind exactly 14 stream bits) lands elsewhere: the case the spec warns about.
    assert after_read - LOOKAHEAD != end


def test_stuffing_right_after_the_last_bit_belongs_to_the_block():
    # Middle symbols of a uniform 13-symbol model pile up 21 pending bits; the flush then
    # writes '1' + 22 zeros, so the block's last bit completes a 22-zero run (found by search).
    n, syms = 13, [6, 6, 6, 6, 3, 3]
    w = BitWriter()
    enc = ArithEncoder(w)
    m = make_model(n, adaptive=False)
    for s in syms:
        enc.encode(m, s)
    enc.flush()
    end = w.position
    bits = "".join(f"{b:08b}" for b in w.getvalue())[:end]
    assert bits.endswith("1" + "0" * ZERO_RUN_LIMIT + "1")  # the stuffing '1' is part of the block
    w.write(0b0011, 4)
    r = BitReader(w.getvalue())
    dec = ArithDecoder(r)
    m2 = make_model(n, adaptive=False)
    assert [dec.decode(m2) for _ in syms] == syms
    dec.finish()
    assert r.pos == end
    assert r.read(4) == 0b0011


def test_empty_block_costs_two_bits():
    w = BitWriter()
    ArithEncoder(w).flush()
    assert w.position == 2
    w.write(0b101, 3)
    r = BitReader(w.getvalue())
    ArithDecoder(r).finish()
    assert r.pos == 2 and r.read(3) == 0b101


@given(st.integers(1, 400), st.lists(st.integers(0, 399), max_size=3000))
def test_models_agree_and_adapt_with_halving(n, seq):
    a, b = Model(n), FastModel(n)
    for s in seq:
        s %= n
        assert a.bounds(s) == b.bounds(s)
        a.update(s)
        b.update(s)
        assert a.total() == b.total() <= MAX_FREQUENCY
    # frequencies stay >= 1 and the table stays descending
    neg = a.neg
    assert all(neg[k] < neg[k + 1] for k in range(n))


def test_halving_rule():
    m = Model(2)
    for _ in range(MAX_FREQUENCY - 2):
        m.update(0)
    assert m.total() == MAX_FREQUENCY
    # frequencies (16382, 1) -> halve with round-up -> (8191, 1) -> +1 on symbol 1
    m.update(1)
    assert m.bounds(0) == (8193, 2, 8193)
    assert m.bounds(1) == (2, 0, 8193)


def test_uniform_model_matches_table_model():
    for n in (1, 2, 7, 3721):
        u, t = UniformModel(n), Model(n, adaptive=True)
        for s in range(0, n, max(1, n // 50)):
            assert u.bounds(s) == t.bounds(s)
        for target in range(0, n, max(1, n // 50)):
            assert u.find(target) == t.find(target)


def test_a_predicted_model_is_halved_at_16383_in_the_suite():
    """simple-l1-stress/arith-model-rescale reaches the coder's limit (spec notes 3.2): FAP 3's
    P alphabet at fap_quant 2 is [-180, 180] (D4: the default P range +-360, truncating
    division), so its table starts at the total 361 and reaches 16,383 after 16,022 updates;
    the 16,023rd update halves it first, and 476 more symbols decode with the halved table."""
    (s,) = load_suites(names=["simple-l1-stress"])
    case = next(c for c in s.cases if c.id == "arith-model-rescale")
    seen = {"updates": 0, "halved_at": [], "sizes": set()}
    orig = arith.FastModel.update

    def spy(self, sym):
        if self.adaptive:
            seen["updates"] += 1
            seen["sizes"].add(self.n)
            if self.total() == arith.MAX_FREQUENCY:
                seen["halved_at"].append(seen["updates"])
        orig(self, sym)

    native = arith.native_decoder
    try:
        arith.native_decoder = lambda: None  # the pure decoder, whose models we can watch
        arith.FastModel.update = spy
        frames = decode(case.input_path("fba").read_bytes()).frames
    finally:
        arith.FastModel.update = orig
        arith.native_decoder = native
    assert len(frames) == 16500 and seen["sizes"] == {361}
    assert seen["updates"] == 16499 and seen["halved_at"] == [16023]
