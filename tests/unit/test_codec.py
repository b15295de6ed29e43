"""Reference encoder + decoder (frame-based arithmetic mode): property tests and rules."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.bitio import BitReader, BitWriter
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames, first_difference
from fbaconf.bitstreams.syntax import frame_rate_code, quantise
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import BitstreamError, EncodeError

from lib.codec import sequences

GROUPS = tables.groups()
QP = tables.quant_steps()


def step_of(fap: int, q: int) -> int:
    return int(QP[fap - 1]) * q if q else 1


def expected_status(frames: FapFrames, types: np.ndarray) -> np.ndarray:
    """D3, computed independently of the codec: SET if coded; not coded under 10 -> FREE;
    under 00/01 -> RETAINED if ever coded before, else FREE."""
    out = np.zeros_like(frames.status)
    ever = np.zeros(68, dtype=bool)
    for k in range(len(frames)):
        coded = frames.status[k] == SET
        ever |= coded
        for gi, g in enumerate(GROUPS):
            for fap in g.faps:
                if coded[fap - 1]:
                    out[k, fap - 1] = SET
                elif types[k, gi] == 2:
                    out[k, fap - 1] = FREE
                else:
                    out[k, fap - 1] = RETAINED if ever[fap - 1] else FREE
    return out


@settings(max_examples=150)
@given(sequences())
def test_round_trip_equals_encoder_reconstruction(case):
    frames, opts, types = case
    res = encode(frames, opts)
    dec = decode(res.data)
    got = dec.frames
    assert first_difference(res.recon, got) is None
    np.testing.assert_array_equal(res.recon.values, got.values)  # FREE values too (last value set)
    np.testing.assert_array_equal(res.recon.high, got.high)
    np.testing.assert_array_equal(res.recon.time_ms, got.time_ms)
    np.testing.assert_array_equal(res.recon.is_intra, got.is_intra)
    np.testing.assert_array_equal(got.frame_number, frames.frame_number)
    np.testing.assert_array_equal(got.status, expected_status(frames, types))
    assert got.gender == opts.gender
    assert [p.bit_offset for p in dec.planes] == res.plane_offsets
    # error bounded by half a quantiser step for every coded low-level FAP
    for k in range(len(frames)):
        q = int(opts.fap_quant_per_frame[k])
        for f in np.nonzero(frames.status[k, 2:] == SET)[0] + 3:
            assert abs(int(got.values[k, f - 1]) - int(frames.values[k, f - 1])) <= step_of(int(f), q) // 2
        qi = max(q, 1)
        top = 63 // qi * qi  # largest reconstructable intensity <= 63

        def intensity_ok(got_v: int, want: int) -> bool:
            return 0 <= got_v <= 63 and (abs(got_v - want) <= qi // 2 or (got_v == top and want > top))

        if frames.status[k, 0] == SET:
            assert list(got.high[k, [0, 1, 3]]) == list(frames.high[k, [0, 1, 3]])
            assert intensity_ok(int(got.high[k, 2]), int(frames.high[k, 2]))
        if frames.status[k, 1] == SET:
            assert list(got.high[k, [4, 6, 8, 9]]) == list(frames.high[k, [4, 6, 8, 9]])
            for j in (5, 7):
                assert intensity_ok(int(got.high[k, j]), int(frames.high[k, j]))


@settings(max_examples=40)
@given(sequences())
def test_encoding_is_deterministic(case):
    frames, opts, _ = case
    assert encode(frames, opts).data == encode(frames.copy(), opts).data


def test_plane_start_code_modes_decode_identically():
    f = synthetic_sequence(60, 25.0)
    outs = [
        decode(encode(f, EncoderOptions(plane_start_codes=m, intra_period=10)).data).frames
        for m in ("none", "intra", "all")
    ]
    assert first_difference(outs[0], outs[1]) is None and first_difference(outs[0], outs[2]) is None


def test_large_prediction_error_forces_an_intra_plane():
    f = FapFrames.empty(3)
    f.status[:, 2] = SET  # open_jaw, QP 4
    # 0 -> 1850 steps: a delta within the largest P range (1860); 1850 -> -1850: a delta of
    # 3700 steps that only an intra plane can code
    f.values[:, 2] = [0, 1850 * 4, -1850 * 4]
    res = encode(f, EncoderOptions(fap_quant=1))
    assert res.intra_frames == [0, 2]
    assert first_difference(res.recon, decode(res.data).frames) is None


def test_lossless_refuses_values_outside_the_codable_range():
    f = FapFrames.empty(2)
    f.status[:, 47] = SET  # head_pitch
    f.values[:, 47] = [100, 1861]
    with pytest.raises(EncodeError) as e:
        encode(f, EncoderOptions(fap_quant=0, intra_period=1))
    assert (e.value.fap, e.value.frame, e.value.value) == (48, 1, 1861)
    assert "FAP 48" in str(e.value) and "1861" in str(e.value)
    f.values[1, 47] = 1860
    assert decode(encode(f, EncoderOptions(fap_quant=0)).data).frames.values[1, 47] == 1860


def test_quantiser_matches_spec_rule():
    # spec notes 3.4: 0 if |x| <= floor(step/2) else floor((|x| + floor(step/2)) / step), sign of x
    for step in (1, 2, 3, 4, 170, 512):
        for x in range(-3 * step, 3 * step + 1):
            h = step // 2
            exp = 0 if abs(x) <= h else (abs(x) + h) // step
            assert quantise(x, step) == (exp if x >= 0 else -exp)


@pytest.mark.parametrize(
    "text,expected",
    [
        ("25", (25, 0, False)),
        ("30", (30, 0, False)),
        ("29.97", (30, 0, True)),
        ("30000/1001", (30, 0, True)),
        ("12.5", (12, 8, False)),
        ("0.5", (0, 8, False)),
        ("24000/1001", (24, 0, True)),
        ("255.9375", (255, 15, False)),
    ],
)
def test_frame_rate_codes(text, expected):
    c = frame_rate_code(text)
    assert (c.frame_rate, c.seconds, c.frequency_offset) == expected


@pytest.mark.parametrize("rate", ["0", "256", "-1", "7.01"])
def test_uncodable_frame_rates(rate):
    with pytest.raises(ValueError):
        frame_rate_code(rate)


def test_next_start_code_stuffing():
    w = BitWriter()
    w.next_start_code()  # aligned: the byte 0x7F
    w.write(0b101, 3)
    w.next_start_code()  # '0' then ones to the byte boundary
    assert w.getvalue() == bytes([0x7F, 0b10101111])
    r = BitReader(bytes([0x7F, 0x00, 0x00, 0x01, 0xBB]))
    assert r.start_code_ahead() == (0x000001BB, 40)


def test_skip_chains_and_time():
    f = synthetic_sequence(4, 10.0, visemes=False, expressions=False, faps=[3])
    f.frame_number[:] = [0, 15, 16, 60]  # skips of 14, 0, 43 (chunks 15,15,13)
    res = encode(f, EncoderOptions())
    got = decode(res.data).frames
    np.testing.assert_array_equal(got.frame_number, [0, 15, 16, 60])
    np.testing.assert_allclose(got.time_ms, [0, 1500, 1600, 6000])


def test_time_codes_set_the_plane_time():
    f = synthetic_sequence(30, 10.0, visemes=False, expressions=False, faps=[3, 4])
    f.frame_number[:] = np.arange(30) + 35  # starts at 3.5 s
    res = encode(f, EncoderOptions(time_codes=True, intra_period=10))
    got = decode(res.data)
    tc = [p.time_code for p in got.planes if p.time_code]
    assert tc[0] == (0, 0, 1, 3)  # floor(3.5 s)
    assert got.frames.time_ms[0] == 3000.0 and got.frames.time_ms[1] == 3100.0


# ------------------------------------------------------------------------ decoder error rules


def _stream(bits: str) -> bytes:
    bits = bits + "0" * (-len(bits) % 8)
    return int(bits, 2).to_bytes(len(bits) // 8, "big") if bits else b""


START = f"{0x000001BA:032b}"


@pytest.mark.parametrize(
    "bits,rule,offset",
    [
        ("", "truncated", 0),
        (f"{0x000001BB:032b}", "start-code", 0),
        (START + "1" + "11", "object-mask", 33),
        (START + "0" + "01" + "0", "first-plane-intra", 32),
        (START + "1" + "01" + "1" + "00000000" + "0000" + "0", "frame-rate-zero", 36),
        (START + "1" + "01" + "0" + "1" + "00000" + "000000" + "0", "marker", 48),
        (START + "1" + "01" + "0" + "0" + "0" + "00001" + "0", "marker", 43),
        (START + "1" + "01" + "0" + "0", "truncated", 38),  # fap_quant starts at 38
    ],
)
def test_decoder_rules(bits, rule, offset):
    with pytest.raises(BitstreamError) as e:
        decode(_stream(bits))
    assert e.value.rule == rule
    assert e.value.bit_offset == offset


def test_decoder_error_names_plane_and_keeps_partial_frames_apart():
    data = encode(synthetic_sequence(20, 25.0), EncoderOptions(intra_period=5)).data
    with pytest.raises(BitstreamError) as e:
        decode(data[: len(data) // 2], file="half.fba")
    err = e.value
    assert err.rule == "truncated" and err.plane is not None and err.plane > 0
    assert "half.fba" in str(err) and f"plane {err.plane}" in str(err)
    assert err.partial is not None and len(err.partial) == err.plane


def test_stream_without_end_code_decodes():
    f = synthetic_sequence(5, 25.0)
    res = encode(f, EncoderOptions(plane_start_codes="none"))
    trimmed = encode(f, EncoderOptions(plane_start_codes="none", end_code=False)).data
    out = decode(trimmed)
    assert out.end_code is None
    assert first_difference(res.recon, out.frames) is None


def test_reconstruction_metadata():
    f = synthetic_sequence(12, 25.0)
    res = encode(f, EncoderOptions(intra_period=4, fap_quant=3))
    got = decode(res.data).frames
    assert list(np.nonzero(got.is_intra)[0]) == [0, 4, 8]
    assert (got.fap_quant == 3).all() and (got.coding_type == 0).all()


@settings(max_examples=150, deadline=None)
@given(st.integers(1, 31), st.integers(0, 63))
@example(2, 63)  # 64: past 63, inside D5's alphabet
@example(2, 1)  # the dead zone
def test_full_intensity_alphabet_reaches_d5_end(q, v):
    """D5: blend/intensity levels 0..floor((63 + floor(q/2)) / q), times q. With the whole
    alphabet the reconstruction is the nearest multiple of q (it may pass 63: 64 at q = 2);
    without it, the largest multiple of q <= 63 when the nearest would pass 63."""
    fr = synthetic_sequence(2, 25.0, seed=1, visemes=True, expressions=False, faps=[3])
    col = HIGH_LEVEL_FIELDS.index("viseme_blend")
    fr.high[:, col] = v
    top = (63 + q // 2) // q * q  # D5's largest value, by hand from the spec notes
    h = q // 2  # spec notes 3.4: a dead zone of floor(q/2), then round half up
    nearest = min((0 if v <= h else (v + h) // q) * q, top)
    full = decode(encode(fr, EncoderOptions(fap_quant=q, full_intensity_alphabet=True)).data).frames
    assert int(full.high[0, col]) == nearest
    capped = decode(encode(fr, EncoderOptions(fap_quant=q)).data).frames
    assert int(capped.high[0, col]) == (nearest if nearest <= 63 else 63 // q * q)
