"""Differential tests: the native arithmetic coder (C extension bitstreams/_fastarith.c) against
the pure-Python reference (arith.py, decoder.py, encoder.py).

Both paths must produce identical streams, identical FapFrames and plane records, and
identical errors (type, message, bit offset, rule, plane, frame, FAP, partial frames) for
valid streams, mutated streams and random bytes. Skipped when the extension is not built.
"""

from __future__ import annotations

import contextlib
import os
import random

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams import arith, decoder, tables
from fbaconf.bitstreams.arith import PURE_PYTHON_ENV, ArithDecoder, ArithEncoder, FastModel, make_model
from fbaconf.bitstreams.bitio import BitReader, BitWriter
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import FREE, SET, FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import BitstreamError
from fbaconf.profiles.checker import analyse
from fbaconf.profiles.sample_streams import value_overflow_stream

from lib.codec import group_masks, high_fields

pytestmark = pytest.mark.skipif(
    not arith.native_available(), reason="native extension fbaconf.bitstreams._fastarith not built (no C compiler?)"
)

QP = tables.quant_steps()
FRAME_FIELDS = (
    "values",
    "status",
    "high",
    "frame_number",
    "time_ms",
    "is_intra",
    "fap_quant",
    "coding_type",
    "bit_offset",
)


NAT = arith._native_module  # the extension itself (whatever FBACONF_PURE_PYTHON says)


@contextlib.contextmanager
def _env(value: str | None):
    old = os.environ.get(PURE_PYTHON_ENV)
    if value is None:
        os.environ.pop(PURE_PYTHON_ENV, None)
    else:
        os.environ[PURE_PYTHON_ENV] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(PURE_PYTHON_ENV, None)
        else:
            os.environ[PURE_PYTHON_ENV] = old


def pure_python():
    return _env("1")


def fast_path():
    """The native path, also when the suite runs with FBACONF_PURE_PYTHON=1."""
    return _env(None)


def frames_key(f: FapFrames | None):
    if f is None:
        return None
    return tuple(getattr(f, k).tolist() for k in FRAME_FIELDS) + (f.frame_rate, f.gender)


def plane_key(p):
    return tuple((k, v.tolist() if isinstance(v, np.ndarray) else v) for k, v in sorted(vars(p).items()))


def outcome(data: bytes):
    """Everything the decoder returns or raises, as comparable plain values."""
    try:
        res = decode(data, file="t.fba")
    except BitstreamError as e:
        return (
            "error",
            type(e).__name__,
            e.message,
            e.bit_offset,
            e.rule,
            e.plane,
            e.frame,
            e.fap,
            e.file,
            str(e),
            frames_key(e.partial),
        )
    return (
        "ok",
        frames_key(res.frames),
        [plane_key(p) for p in res.planes],
        res.end_code,
        res.end_offset,
        res.used_default_frame_rate,
        res.notes,
    )


def both(data: bytes):
    with fast_path():
        fast = outcome(data)
    with pure_python():
        ref = outcome(data)
    assert fast == ref
    return fast


COUNTS = {"ok": 0, "error": 0}


def check(data: bytes) -> None:
    COUNTS[both(data)[0]] += 1


# ---------------------------------------------------------------------------- strategies


@st.composite
def sequences(draw):
    """Random FAP sequences (segments of mask/quantiser settings) and encoder options."""
    n_seg = draw(st.integers(1, 4))
    rows = []
    for _ in range(n_seg):
        seg_len = draw(st.integers(1, 12))
        q = draw(st.integers(0, 31))
        types, coded = group_masks(draw)
        rows += [(q, tuple(types), coded.copy())] * seg_len
    n = len(rows)
    frames = FapFrames.empty(n)
    frames.frame_number[:] = np.cumsum(draw(st.lists(st.sampled_from([1, 1, 2, 17]), min_size=n, max_size=n)))
    amp = draw(st.sampled_from([3, 60, 1200]))  # small values, or near the edges of wide ranges
    for k, (q, _, coded) in enumerate(rows):
        frames.status[k] = np.where(coded, SET, FREE)
        for f in np.nonzero(coded[2:])[0] + 3:
            unit = int(QP[f - 1]) if q else 1
            frames.values[k, f - 1] = draw(st.integers(-amp, amp)) * unit
        high_fields(draw, frames, k, coded)
    frames.frame_rate = draw(st.sampled_from([25.0, 30.0, 10.0]))
    opts = EncoderOptions(
        fap_quant_per_frame=np.array([r[0] for r in rows]),
        group_types=np.array([r[1] for r in rows]),
        intra_period=draw(st.sampled_from([0, 0, 1, 3])),
        time_codes=draw(st.booleans()),
        plane_start_codes=draw(st.sampled_from(["none", "intra", "all"])),
        ranges=draw(st.sampled_from(["auto", "persist"])),
    )
    return frames, opts


def encode_both(frames, opts) -> bytes:
    with fast_path():
        fast = encode(frames, opts)
    with pure_python():
        ref = encode(frames, opts)
    assert fast.data == ref.data
    assert fast.plane_offsets == ref.plane_offsets
    assert frames_key(fast.recon) == frames_key(ref.recon)
    return fast.data


def mutate(rnd: random.Random, data: bytes) -> bytes:
    b = bytearray(data)
    kind = rnd.randrange(4)
    if kind == 0:  # truncation
        return bytes(b[: rnd.randrange(len(b) + 1)])
    if kind == 1:  # bit flips
        for _ in range(rnd.randint(1, 6)):
            i = rnd.randrange(len(b) * 8)
            b[i // 8] ^= 0x80 >> (i % 8)
        return bytes(b)
    if kind == 2:  # a run of zero bytes (long zero runs: stuffing)
        i = rnd.randrange(len(b) + 1)
        b[i : i + rnd.randint(1, 6)] = bytes(rnd.randint(1, 6))
        return bytes(b)
    i = rnd.randrange(len(b) + 1)  # random bytes spliced in
    b[i:i] = bytes(rnd.randrange(256) for _ in range(rnd.randint(1, 8)))
    return bytes(b)


# ---------------------------------------------------------------------------- stream-level differential tests


@settings(max_examples=60)
@given(sequences(), st.randoms(use_true_random=False))
def test_encoder_and_decoder_agree_on_random_sequences_and_their_mutants(case, rnd):
    frames, opts = case
    data = encode_both(frames, opts)
    assert both(data)[0] == "ok"
    for _ in range(6):
        check(mutate(rnd, data))


@settings(max_examples=200)
@given(st.binary(max_size=200), st.booleans())
def test_random_bytes(data, with_start_code):
    check((b"\x00\x00\x01\xba" if with_start_code else b"") + data)


def _wide_range_stream(n: int = 6, seed: int = 0, visemes: bool = True) -> bytes:
    """FAPs at the edges of the widest ranges: long zero runs, so blocks contain stuffing bits."""
    b = np.zeros((68, 4), dtype=np.int64)
    b[:, 0], b[:, 1], b[:, 2], b[:, 3] = 1860, -1860, 1860, -1860
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, 30.0)
    faps = list(range(3, 20))
    f.status[:, [x - 1 for x in faps]] = SET
    if visemes:
        f.status[:, 0] = f.status[:, 1] = SET
        f.high[:, 0] = rng.integers(0, 15, n)
        f.high[:, 2] = 63
    for k in range(n):
        for x in faps:
            f.values[k, x - 1] = int(rng.choice([1860, -1860, 1859, 0])) * int(QP[x - 1])
    return encode(f, EncoderOptions(bounds=b, fap_quant=1, plane_start_codes="none")).data


def test_exhaustive_truncations_and_bit_flips_of_small_streams():
    """Every truncation and every single bit flip of a small stream (every 3rd bit of the
    stuffing-heavy ones, to keep the suite fast)."""
    streams = [
        (
            encode(
                synthetic_sequence(5, 25.0, faps=[3, 4, 5, 48], visemes=True, expressions=True),
                EncoderOptions(fap_quant=2, plane_start_codes="none"),
            ).data,
            1,
        ),
        (_wide_range_stream(2), 3),
        (_wide_range_stream(2, seed=3, visemes=False), 3),
    ]
    n = 0
    for data, stride in streams:
        assert both(data)[0] == "ok"
        for cut in range(len(data)):
            check(data[:cut])
            n += 1
        for i in range(0, len(data) * 8, stride):
            b = bytearray(data)
            b[i // 8] ^= 0x80 >> (i % 8)
            check(bytes(b))
            n += 1
    assert n > 1500
    assert COUNTS["error"] > 0


def test_stuffing_errors_are_located_identically():
    data = _wide_range_stream()
    res = decode(data)
    rules = set()
    for _, start, length in [blk for p in res.planes for blk in p.blocks]:
        zeros, pos = 0, start
        while pos < start + length:  # clear every stuffing bit inside the block in turn
            bit = (data[pos >> 3] >> (7 - (pos & 7))) & 1
            pos += 1
            zeros = zeros + 1 if bit == 0 else 0
            if zeros == arith.ZERO_RUN_LIMIT:
                b = bytearray(data)
                b[pos >> 3] &= ~(0x80 >> (pos & 7)) & 0xFF
                out = both(bytes(b))
                rules.add(out[4] if out[0] == "error" else "ok")
                pos += 1
                zeros = 0
    assert "stuffing" in rules


def test_value_overflow_is_reported_identically():
    out = both(value_overflow_stream())
    assert out[0] == "error" and out[4] == "value-overflow" and out[7] == 47


def test_lookahead_and_large_streams_agree():
    check(_wide_range_stream(40, seed=7))
    frames = synthetic_sequence(200, 30.0)
    for opts in (
        EncoderOptions(fap_quant=1),
        EncoderOptions(fap_quant=5, intra_period=50),
        EncoderOptions(fap_quant=31, ranges="persist", plane_start_codes="all"),
    ):
        data = encode_both(frames, opts)
        assert both(data)[0] == "ok"


# ---------------------------------------------------------------------------- block-level differential tests


@settings(max_examples=80)
@given(st.lists(st.integers(1, 40), min_size=1, max_size=6), st.booleans(), st.data())
def test_blocks_with_adaptive_and_uniform_models(alphabets, adaptive, data):
    k = data.draw(st.integers(0, 200))
    rows = data.draw(st.lists(st.integers(0, len(alphabets) - 1), min_size=k, max_size=k))
    skew = data.draw(st.booleans())
    syms = [0 if skew and data.draw(st.integers(0, 9)) else data.draw(st.integers(0, alphabets[r] - 1)) for r in rows]
    # pure
    w = BitWriter()
    enc = ArithEncoder(w)
    models = [make_model(n, adaptive) for n in alphabets]
    for r, s in zip(rows, syms):
        enc.encode(models[r], s)
    enc.flush()
    ref = w.getvalue()
    # native: one spec row per symbol, rows of the same model share its pool table
    spec, pool = arith.block_spec(alphabets, 0, adaptive=adaptive)
    bspec = spec[rows] if k else np.zeros((0, 5), np.int32)
    st_, out, nbits = NAT.encode_block(bspec, pool, np.array(syms, dtype=np.int32))
    assert st_ == 0 and out == ref[: len(out)] and (nbits + 7) // 8 == len(ref) and nbits == w.position
    # decode both ways from an offset, with trailing bits
    pre = data.draw(st.integers(0, 7))
    tail = data.draw(st.binary(max_size=4))
    w2 = BitWriter()
    if pre:
        w2.write(0, pre)
    arith.append_bits(w2, out, nbits)
    stream = w2.getvalue() + tail
    r = BitReader(stream)
    r.pos = pre
    dec = ArithDecoder(r)
    models = [make_model(n, adaptive) for n in alphabets]
    got_ref = [dec.decode(models[rr]) for rr in rows]
    length = dec.finish()
    _, pool2 = arith.block_spec(alphabets, 0, adaptive=adaptive)
    st_, end, got = NAT.decode_block(stream, len(stream) * 8, pre, bspec, pool2, 0, None)
    assert st_ == 0 and got == got_ref == syms and end - pre == length == nbits
    if adaptive:
        assert pool2.tolist() == pool.tolist()  # both sides adapted their models identically


def test_model_halving_matches():
    """Enough symbols in one adaptive model to reach the maximum frequency several times."""
    rnd = random.Random(5)
    for n in (1, 2, 7, 300):
        syms = [min(int(rnd.expovariate(0.5)), n - 1) for _ in range(40_000)]
        w = BitWriter()
        enc = ArithEncoder(w)
        m = make_model(n)
        for s in syms:
            enc.encode(m, s)
        enc.flush()
        spec, _ = arith.block_spec([n] * len(syms), 0)
        spec[:, 1] = 0  # every row uses the one table at offset 0
        _, pool = arith.block_spec([n], 0, adaptive=True)
        st_, out, nbits = NAT.encode_block(spec, pool, np.array(syms, np.int32))
        assert st_ == 0 and out == w.getvalue() and nbits == w.position
        neg = m.arr.tolist() if isinstance(m, FastModel) else m.neg
        assert pool.tolist() == [-v for v in neg]
        _, pool2 = arith.block_spec([n], 0, adaptive=True)
        st_, end, got = NAT.decode_block(out, nbits, 0, spec, pool2, 0, None)
        assert st_ == 0 and got == syms


def test_corrupt_model_state_reports_arith_state_like_the_reference():
    """The reference keeps low <= value <= high, so 'arith-state' needs a broken model: total 0."""
    data = bytes([0xA5, 0x5A, 0xFF, 0x00, 0x12, 0x34])
    r = BitReader(data)
    dec = ArithDecoder(r)
    m = make_model(3)
    m.neg[:] = [0, 0, 0, 0]
    with pytest.raises(BitstreamError) as e:
        dec.decode(m)
    spec, pool = arith.block_spec([3], 0, adaptive=True)
    pool[:] = 0
    assert NAT.decode_block(data, len(data) * 8, 0, spec, pool, 0, None) == (1, e.value.bit_offset, 0)
    assert e.value.rule == "arith-state"


def test_encoder_refuses_out_of_range_symbols_like_the_reference():
    spec, pool = arith.block_spec([5, 5], 0)
    assert NAT.encode_block(spec, pool, np.array([1, 5], np.int32)) == (1, 1, 5)
    with pytest.raises(ValueError, match="outside alphabet of 5"):
        ArithEncoder(BitWriter()).encode(make_model(5), 5)


def test_bad_arguments_raise_python_errors():
    nat = NAT
    spec, pool = arith.block_spec([5], 0, adaptive=True)
    with pytest.raises(ValueError):
        nat.decode_block(b"\x00", 8, 0, spec, None, 0, None)  # adaptive row without a pool
    with pytest.raises(ValueError):
        nat.decode_block(b"\x00", 9, 0, spec, pool, 0, None)  # nbits beyond the data
    with pytest.raises(TypeError):
        nat.decode_block(b"\x00", 8, 0, spec, pool, 2, None)  # mode 2 needs cur
    with pytest.raises(ValueError):
        nat.encode_block(np.zeros((1, 4), np.int32), None, np.zeros(1, np.int32))


# ---------------------------------------------------------------------------- switches


def test_env_var_and_patched_classes_select_the_pure_path(monkeypatch):
    data = _wide_range_stream()
    monkeypatch.delenv(PURE_PYTHON_ENV, raising=False)
    assert decoder._Decoder(data, None).native is not None
    assert arith.native_encoder() is not None
    monkeypatch.setenv(PURE_PYTHON_ENV, "1")
    assert decoder._Decoder(data, None).native is None and arith.native_encoder() is None
    monkeypatch.setenv(PURE_PYTHON_ENV, "0")
    assert decoder._Decoder(data, None).native is not None
    monkeypatch.delenv(PURE_PYTHON_ENV)

    def patched(self, model):
        raise self.r.error("synthetic", "arith-state")

    monkeypatch.setattr(arith.ArithDecoder, "decode", patched)
    assert decoder._Decoder(data, None).native is None
    with pytest.raises(BitstreamError) as e:
        decode(data)
    assert e.value.message == "synthetic"


def test_checker_reports_identically():
    for data in (
        _wide_range_stream(),
        value_overflow_stream(),
        _wide_range_stream()[:-9],
        encode(synthetic_sequence(60, 30.0), EncoderOptions(fap_quant=1, intra_period=20)).data,
    ):
        with fast_path():
            fast = analyse(data, claim="simple@1")
        with pure_python():
            ref = analyse(data, claim="simple@1")
        assert [d.to_dict() if hasattr(d, "to_dict") else repr(d) for d in fast.diagnostics] == [
            d.to_dict() if hasattr(d, "to_dict") else repr(d) for d in ref.diagnostics
        ]
        assert fast.summary == ref.summary
