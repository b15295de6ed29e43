"""DCT segment coding mode (coding_type 1): tables, integer transform, VLCs, round trips,
mode switching, bad input. Tables come from bitstreams/data/dct_provisional.toml."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams import dct, tables
from fbaconf.bitstreams.bitio import FACE_OBJECT_START_CODE, BitReader, BitWriter
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames, first_difference
from fbaconf.errors import BitstreamError, EncodeError

T = dct.dct_tables()
QP = tables.quant_steps()
LIMIT = 1800  # |value| <= 1800 x QP: codable by the frame-based mode at every fap_quant 1..31 too


def _err(msg, rule, at=None, fap=None):
    return BitstreamError(msg, bit_offset=at if at is not None else -1, rule=rule, fap=fap)


# ---------------------------------------------------------------------------- the data file


def test_data_file_is_tagged_provisional_with_rationales():
    doc = dct.read_table_document()
    assert doc["provisional"] is True and T.provisional
    for section in ("segment", "transform", "quantiser", "dc", "ac", "high_level"):
        assert len(doc[section]["rationale"].split()) >= 10, section
    # both seed ratios recorded, one chosen
    q = doc["quantiser"]
    assert q["dc_step_ratio_ostermann_1998"] == [1, 4] and q["dc_step_ratio_ist"] == [1, 3]
    assert list(T.dc_ratio) in (q["dc_step_ratio_ostermann_1998"], q["dc_step_ratio_ist"])
    assert len(T.scale_factors) == 32 and all(b > a for a, b in zip(T.scale_factors, T.scale_factors[1:]))


def test_changed_tables_are_all_it_takes(monkeypatch):
    """Adopting other tables is a data change: IST's 1/3 ratio, another scale table, another
    transform precision -> the codec still round-trips."""
    doc = dct.read_table_document()
    doc["quantiser"]["dc_step_ratio"] = [1, 3]
    doc["quantiser"]["scale_factors"] = [3 * (i + 1) for i in range(32)]
    doc["transform"]["scale_bits"] = 13
    doc["transform"]["matrix"] = [[dct.rdiv(v, 2) for v in row] for row in doc["transform"]["matrix"]]
    alt = dct.parse_tables(doc)
    monkeypatch.setattr(dct, "dct_tables", lambda: alt)
    frames = _sequence(37, seed=5)
    res = encode(frames, EncoderOptions(coding="dct", fap_quant=4))
    assert first_difference(res.recon, decode(res.data).frames) is None
    _check_error_bound(frames, res.recon, 4, alt)


def test_invalid_data_file_is_refused():
    doc = dct.read_table_document()
    doc["ac"]["table"] = list(doc["ac"]["table"]) + [[14, 200, doc["ac"]["eob"] + "0"]]
    with pytest.raises(RuntimeError, match="prefix-free"):
        dct.parse_tables(doc)


# ---------------------------------------------------------------------------- integer transform


def test_matrix_matches_an_independent_float_dct_ii():
    S = 1 << T.scale_bits
    N = T.length
    n = np.arange(N)
    for k in range(N):
        ref = math.sqrt((1 if k == 0 else 2) / N) * np.cos(np.pi * (2 * n + 1) * k / (2 * N))
        assert np.abs(np.array(T.matrix[k]) / S - ref).max() <= 0.5 / S + 1e-12
    # orthonormal to fixed-point precision
    M = np.array(T.matrix, dtype=np.float64) / S
    assert np.abs(M @ M.T - np.eye(N)).max() < 2e-4


def _exact_limit() -> int:
    S = 1 << T.scale_bits
    M = np.array(T.matrix, dtype=np.float64)
    E = np.abs(M.T @ M / (S * S) - np.eye(T.length)).sum(axis=1).max()
    return int(0.49 / E)


@given(st.lists(st.integers(-_exact_limit(), _exact_limit()), min_size=16, max_size=16))
def test_fixed_point_pair_is_exactly_invertible(x):
    """inverse(forward(x)) == x for the unquantised fixed-point pair (|x| up to the limit where
    the matrix error stays below half a unit)."""
    S = 1 << T.scale_bits
    coeffs = [sum(m * v for m, v in zip(row, x)) for row in T.matrix]  # scaled by 2^s
    back = [dct.rdiv(sum(m * c for m, c in zip(col, coeffs)), S * S) for col in T.columns]
    assert back == x


@given(
    st.lists(st.integers(-LIMIT * 4, LIMIT * 4), min_size=16, max_size=16),
    st.sampled_from([3, 4, 19, 48, 47]),
    st.integers(0, 31),
)
def test_quantised_transform_error_within_bound(x, fap, index):
    step = T.ac_step(fap, index)
    y = dct.inverse(dct.forward_levels(x, step, T), step, T)
    bound = dct.error_bound(fap, index, max(abs(v) for v in x))
    assert max(abs(a - b) for a, b in zip(x, y)) <= bound


def test_rdiv_rounds_half_away_from_zero():
    assert [dct.rdiv(a, 4) for a in (-6, -5, -2, -1, 0, 1, 2, 5, 6)] == [-2, -1, -1, 0, 0, 0, 1, 1, 2]


# ---------------------------------------------------------------------------- VLCs


def test_vlc_table_prefix_free_and_every_entry_decodes():
    words = [T.eob, T.escape] + [c for *_, c in T.table]
    assert len(set(words)) == len(words)
    for a in words:
        for b in words:
            assert a == b or not b.startswith(a)
    assert sum(2.0 ** -len(c) for c in words) <= 1.0
    for run, level, _ in T.table:
        for sign in (1, -1):
            levels = [0] * T.length
            levels[1 + run] = sign * level
            w = BitWriter()
            dct.write_ac(w, levels, T)
            r = BitReader(w.getvalue())
            assert dct.read_ac(r, T, _err) == levels
            assert r.pos == w.position


@given(
    st.lists(st.integers(-T.ac_max_level, T.ac_max_level) | st.just(0), min_size=15, max_size=15),
    st.integers(-T.dc_max_level, T.dc_max_level),
    st.sampled_from([T.dc_intra_order, T.dc_pred_order]),
)
def test_segment_codes_round_trip(ac, dc, order):
    levels = [dc] + ac
    w = BitWriter()
    dct.write_se(w, dc, order)
    dct.write_ac(w, levels, T)
    r = BitReader(w.getvalue())
    assert dct.read_se(r, order, T.dc_max_prefix, "dc", _err) == dc
    got = dct.read_ac(r, T, _err)
    assert got[1:] == ac and r.pos == w.position


# ---------------------------------------------------------------------------- sequences


def _sequence(n: int, seed: int, *, hl: bool = True, gaps: bool = False, rate: float = 25.0) -> FapFrames:
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, rate)
    fn = np.arange(n)
    if gaps:
        fn = np.cumsum(rng.integers(1, 4, n)) - 1
    f.frame_number = fn.astype(np.int64)
    f.time_ms = fn * 1000.0 / rate
    coded = rng.random(68) < 0.5
    coded[:2] = hl
    t = np.arange(n)
    for i in range(2, 68):
        amp = rng.integers(1, 300) * QP[i]
        f.values[:, i] = np.clip(
            amp * np.sin(t / rng.uniform(2, 12) + rng.uniform(0, 6)), -LIMIT * QP[i], LIMIT * QP[i]
        ).astype(np.int32)
    f.status[:] = np.where(coded, SET, FREE)
    f.high[:, 0] = rng.integers(0, 15, n)
    f.high[:, 1] = rng.integers(0, 15, n)
    f.high[:, 2] = rng.integers(0, 64, n)
    f.high[:, 4] = np.repeat(rng.integers(0, 7, (n + 4) // 5), 5)[:n]
    f.high[:, 5] = rng.integers(0, 64, n)
    return f


@st.composite
def fap_sequences(draw):
    n = draw(st.integers(1, 40))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, draw(st.sampled_from([25.0, 10.0, 30.0])))
    if draw(st.booleans()):
        steps = rng.integers(1, 3, n)
        f.frame_number = (np.cumsum(steps) - steps[0] + draw(st.integers(0, 20))).astype(np.int64)
    # 1..3 mask epochs; each FAP coded / retained / free; viseme and expression FAPs too
    cuts = sorted(set(draw(st.lists(st.integers(1, max(n - 1, 1)), max_size=2)))) if n > 1 else []
    bounds = [0] + cuts + [n]
    for a, b in zip(bounds[:-1], bounds[1:]):
        kind = draw(st.sampled_from(["all", "none", "random", "groups"]))
        if kind == "all":
            coded = np.ones(68, bool)
        elif kind == "none":
            coded = np.zeros(68, bool)
        elif kind == "groups":
            coded = np.zeros(68, bool)
            for g in tables.groups():
                if rng.random() < 0.5:
                    coded[g.first_fap - 1 : g.last_fap] = True
        else:
            coded = rng.random(68) < rng.uniform(0.05, 0.95)
        free = rng.random(68) < 0.5
        f.status[a:b] = np.where(coded, SET, np.where(free, FREE, RETAINED))
    style = draw(st.sampled_from(["smooth", "noise", "steps", "extreme"]))
    t = np.arange(n)
    for i in range(2, 68):
        lim = LIMIT * int(QP[i])
        if style == "smooth":
            v = rng.uniform(0, lim) * np.sin(t / rng.uniform(1, 10) + rng.uniform(0, 6))
        elif style == "noise":
            v = rng.uniform(-lim, lim, n)
        elif style == "steps":
            v = np.repeat(rng.uniform(-lim / 4, lim / 4, (n + 6) // 7), 7)[:n]
        else:
            v = rng.choice([-lim, lim, 0], n)
        f.values[:, i] = np.round(v).astype(np.int32)
    f.high[:, 0] = rng.integers(0, 15, n)
    f.high[:, 1] = rng.integers(0, 15, n)
    f.high[:, 2] = np.repeat(rng.integers(0, 64, (n + 2) // 3), 3)[:n]
    f.high[:, 3] = rng.integers(0, 2, n)
    f.high[:, 4] = rng.integers(0, 7, n)
    f.high[:, 5] = rng.integers(0, 64, n)
    f.high[:, 6] = np.repeat(rng.integers(0, 7, (n + 3) // 4), 4)[:n]
    f.high[:, 7] = rng.integers(0, 64, n)
    f.high[:, 8] = rng.integers(0, 2, n)
    f.high[:, 9] = rng.integers(0, 2, n)
    return f


def _check_error_bound(src: FapFrames, recon: FapFrames, index: int, t=None):
    t = t or T
    coded = src.status == SET
    for i in range(2, 68):
        if not coded[:, i].any():
            continue
        bound = dct.error_bound(i + 1, index, int(np.abs(src.values[:, i]).max()), t)
        err = np.abs(recon.values[coded[:, i], i].astype(np.int64) - src.values[coded[:, i], i])
        assert err.max() <= bound, (i + 1, int(err.max()), bound)
    for j, name in enumerate(HIGH_LEVEL_FIELDS):  # high-level fields are exact in DCT mode
        fap = 0 if j < 4 else 1
        rows = coded[:, fap]
        assert (recon.high[rows, j] == src.high[rows, j]).all(), name


@settings(max_examples=60)
@given(
    fap_sequences(),
    st.integers(0, 31),
    st.sampled_from(["none", "intra", "all"]),
    st.sampled_from([None, 1, 2]),
    st.sampled_from([0, 0, 5, 20]),
    st.booleans(),
)
def test_round_trip_decoded_equals_recon(frames, index, start_codes, partial, intra_period, time_codes):
    opts = EncoderOptions(
        coding="dct",
        fap_quant=index,
        plane_start_codes=start_codes,
        partial_mask_type=partial,
        intra_period=intra_period,
        time_codes=time_codes,
    )
    res = encode(frames, opts)
    out = decode(res.data)
    got = out.frames
    assert first_difference(res.recon, got) is None
    assert len(got) == len(frames) and (got.frame_number == frames.frame_number).all()
    assert (got.coding_type == 1).all() and (got.fap_quant == index).all()
    assert np.allclose(got.time_ms, res.recon.time_ms)
    assert ((got.status == SET) == (frames.status == SET)).all()
    assert sum(p.segment_length for p in out.planes) == len(frames)
    assert all(1 <= p.segment_length <= T.length for p in out.planes)
    assert out.planes[0].is_intra and got.is_intra[0]
    _check_error_bound(frames, res.recon, index)
    if not time_codes:
        assert np.allclose(got.time_ms, got.frame_number * 1000.0 / frames.frame_rate)


@pytest.mark.parametrize("n", [1, 15, 16, 17, 31, 32, 33, 40])
def test_segment_lengths_not_multiple_of_16(n):
    frames = _sequence(n, seed=n)
    res = encode(frames, EncoderOptions(coding="dct", fap_quant=3))
    out = decode(res.data)
    assert first_difference(res.recon, out.frames) is None
    assert [p.segment_length for p in out.planes] == [16] * (n // 16) + ([n % 16] if n % 16 else [])
    assert [p.is_intra for p in out.planes] == [True] + [False] * (len(out.planes) - 1)
    _check_error_bound(frames, res.recon, 3)


def test_predicted_segments_reset_at_intra_group():
    frames = _sequence(64, seed=9)
    res = encode(frames, EncoderOptions(coding="dct", fap_quant=2, intra_period=32))
    out = decode(res.data)
    assert [p.is_intra for p in out.planes] == [True, False, True, False]
    assert first_difference(res.recon, out.frames) is None
    assert res.intra_frames == [0, 32]


def test_gaps_split_groups_and_keep_frame_numbers():
    frames = _sequence(30, seed=3, gaps=True)
    res = encode(frames, EncoderOptions(coding="dct", fap_quant=1))
    got = decode(res.data).frames
    assert first_difference(res.recon, got) is None
    assert (got.frame_number == frames.frame_number).all()


def test_uncodable_value_is_refused():
    frames = _sequence(5, seed=1, hl=False)
    frames.status[:] = FREE
    frames.status[:, 2] = SET
    frames.values[:, 2] = [0, 2**30, -(2**30), 0, 0]
    with pytest.raises(EncodeError) as ei:
        encode(frames, EncoderOptions(coding="dct", fap_quant=0))
    assert ei.value.rule == "value-range" and ei.value.fap == 3


# ---------------------------------------------------------------------------- mode switching


@pytest.mark.parametrize(
    "pattern",
    [
        ["arithmetic"] * 10 + ["dct"] * 20 + ["arithmetic"] * 7,
        ["dct"] * 17 + ["arithmetic"] * 3 + ["dct"] * 5,
        [1, 0] * 6,
    ],
)
def test_mode_switch_stream(pattern):
    n = len(pattern)
    frames = _sequence(n, seed=n)
    # a FAP coded only in the first section must be RETAINED (with its value) later
    frames.status[n // 2 :, 2] = RETAINED
    res = encode(frames, EncoderOptions(coding_per_frame=pattern, fap_quant=2))
    out = decode(res.data)
    assert first_difference(res.recon, out.frames) is None
    modes = np.array([1 if m in ("dct", 1) else 0 for m in pattern])
    assert (out.frames.coding_type == modes).all()
    switches = [k for k in range(n) if k == 0 or modes[k] != modes[k - 1]]
    assert all(out.frames.is_intra[k] for k in switches)
    assert (out.frames.values[n // 2 :, 2] == out.frames.values[n // 2 - 1, 2]).all()


@settings(max_examples=25)
@given(fap_sequences(), st.data())
def test_mode_switch_round_trip_property(frames, data):
    n = len(frames)
    pattern = data.draw(st.lists(st.sampled_from(["arithmetic", "dct"]), min_size=n, max_size=n))
    res = encode(frames, EncoderOptions(coding_per_frame=pattern, fap_quant=data.draw(st.integers(1, 31))))
    assert first_difference(res.recon, decode(res.data).frames) is None


def test_arithmetic_stream_unchanged_by_dct_option_absence():
    frames = _sequence(20, seed=4)
    a = encode(frames, EncoderOptions(fap_quant=3))
    b = encode(frames, EncoderOptions(fap_quant=3, coding_per_frame=["arithmetic"] * 20))
    assert a.data == b.data and first_difference(a.recon, b.recon) is None


# ---------------------------------------------------------------------------- bad input


def _hand_stream(segment_bits) -> bytes:
    """Object start code, an intra DCT plane coding only FAP 3, then ``segment_bits(w)``."""
    w = BitWriter()
    w.start_code(FACE_OBJECT_START_CODE)
    w.bit(1)
    w.write(1, 2)
    w.bit(0)  # no frame rate
    w.bit(0)  # no time code
    w.bit(0)  # no skip
    w.write(0, 5)  # scaling index 0
    for g in tables.groups():
        w.bit(1)
        if g.group == 2:
            w.write(1, 2)
            for fap in g.faps:
                w.bit(1 if fap == 3 else 0)
        else:
            w.write(0, 2)
    w.bit(0)  # gender
    w.bit(1)  # coding_type DCT
    sw = dct.StuffingWriter(w)  # the payload's emulation prevention (D9)
    sw.write(15, T.length_bits)
    segment_bits(sw)
    sw.end()
    return w.getvalue()


def _code(w, c):
    w.write(int(c, 2), len(c))


def test_hand_built_stream_decodes():
    def seg(w):
        dct.write_se(w, 8, T.dc_intra_order)
        _code(w, T.eob)

    out = decode(_hand_stream(seg)).frames
    assert len(out) == 16 and (out.coding_type == 1).all()
    assert (out.values[:, 2] == dct.inverse([8] + [0] * 15, T.ac_step(3, 0), T)).all()


@pytest.mark.parametrize(
    "rule,seg",
    [
        (
            "run-overflow",
            lambda w: (
                dct.write_se(w, 1, T.dc_intra_order),
                _code(w, T.escape),
                w.write(15, T.escape_run_bits),
                w.write(3, T.escape_level_bits),
                w.bit(0),
            ),
        ),
        (
            "invalid-vlc",
            lambda w: (
                dct.write_se(w, 1, T.dc_intra_order),
                _code(w, T.escape),
                w.write(0, T.escape_run_bits),
                w.write(0, T.escape_level_bits),
                w.bit(0),
            ),
        ),
        ("invalid-vlc", lambda w: w.write(0, T.dc_max_prefix + 1)),
        ("coefficient-overflow", lambda w: (dct.write_se(w, T.dc_max_level + 1, T.dc_intra_order), _code(w, T.eob))),
        ("truncated", lambda w: dct.write_se(w, 100000, T.dc_intra_order)),
    ],
)
def test_bad_segments_give_typed_errors(rule, seg):
    data = _hand_stream(seg)
    if rule == "truncated":  # cut inside the DC code (zero padding alone could read as EOB '0')
        data = data[:-2]
    with pytest.raises(BitstreamError) as ei:
        decode(data)
    assert ei.value.rule == rule
    assert 0 <= ei.value.bit_offset <= len(data) * 8


def test_missing_dct_stuffing_bit_is_an_error():
    """D9 in the DCT mode: after 22 consecutive zeros of a payload a '1' must follow."""

    def seg(w):
        w.w.write(0, 30)  # a DC prefix of 30 zeros straight into the stream, no stuffing bit

    with pytest.raises(BitstreamError) as ei:
        decode(_hand_stream(seg))
    assert ei.value.rule == "dct-stuffing"


def test_dct_payload_never_runs_23_zeros():
    """The stuffing writer by hand: 22 zeros, then its '1'; a payload ending in 20 zeros gets one."""
    w = BitWriter()
    sw = dct.StuffingWriter(w)
    sw.write(0, 22)
    assert w.position == 23 and w.getvalue()[:3] == bytes([0, 0, 0b00000010])
    sw.write(0, 20)
    sw.end()
    assert w.position == 23 + 21


def test_sixteen_coefficients_then_more_is_run_overflow():
    code11 = T.codes[(0, 1)]

    def seg(w):
        dct.write_se(w, 0, T.dc_intra_order)
        for _ in range(16):  # 15 AC coefficients fit, the 16th does not
            _code(w, code11)
            w.bit(0)
        _code(w, T.eob)

    with pytest.raises(BitstreamError) as ei:
        decode(_hand_stream(seg))
    assert ei.value.rule == "run-overflow"


def test_mutated_and_truncated_streams_only_raise_bitstream_errors():
    rng = random.Random(1234)
    seeds = []
    for k, (n, opts) in enumerate(
        [
            (20, EncoderOptions(coding="dct", fap_quant=0)),
            (33, EncoderOptions(coding="dct", fap_quant=7, plane_start_codes="all")),
            (40, EncoderOptions(coding_per_frame=["dct"] * 18 + ["arithmetic"] * 22, fap_quant=3)),
            (9, EncoderOptions(coding="dct", fap_quant=31, time_codes=True)),
        ]
    ):
        seeds.append(encode(_sequence(n, seed=100 + k), opts).data)
    count = 0
    for i in range(3200):
        data = bytearray(rng.choice(seeds))
        op = i % 4
        if op == 0:
            for _ in range(rng.randint(1, 6)):
                p = rng.randrange(len(data) * 8)
                data[p >> 3] ^= 0x80 >> (p & 7)
        elif op == 1:
            data = data[: rng.randrange(len(data))]
        elif op == 2:
            p = rng.randrange(len(data))
            data[p : p + rng.randint(1, 4)] = bytes(rng.randrange(256) for _ in range(rng.randint(0, 4)))
        else:
            p = rng.randrange(4, len(data))
            data = data[:p] + bytes([rng.choice([0, 255, rng.randrange(256)])]) * rng.randint(1, 8) + data[p:]
        try:
            decode(bytes(data))
        except BitstreamError as e:
            assert 0 <= e.bit_offset <= len(data) * 8 + 32
            count += 1
    assert count > 100


# ---------------------------------------------------------------------------- real files


def _read(path):
    return read_fap_file(path)[0]


@pytest.mark.external
def test_real_files_round_trip(real_files):
    for path in real_files:
        frames = _read(path)
        for index in (0, 9, 31):
            res = encode(frames, EncoderOptions(coding="dct", fap_quant=index))
            got = decode(res.data).frames
            assert first_difference(res.recon, got) is None, (path, index)
            _check_error_bound(frames, res.recon, index)
        n = len(frames)
        pattern = ["dct" if (k // 20) % 2 == 0 else "arithmetic" for k in range(n)]
        res = encode(frames, EncoderOptions(coding_per_frame=pattern, fap_quant=2))
        assert first_difference(res.recon, decode(res.data).frames) is None, path
