"""Any byte string given to the decoder ends as FapFrames or a typed BitstreamError."""

from __future__ import annotations

import random

import numpy as np
from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import BitstreamError

N_INPUTS = 10_500


def seed_corpus() -> list[bytes]:
    out = []
    cases = [
        (synthetic_sequence(12, 25.0, faps=[3, 4, 5, 19, 20, 48]), EncoderOptions(fap_quant=1, intra_period=4)),
        (
            synthetic_sequence(10, 30000 / 1001),
            EncoderOptions(fap_quant=0 + 2, plane_start_codes="all", time_codes=True),
        ),
        (
            synthetic_sequence(8, 10.0, visemes=True, expressions=False, faps=[6, 7, 31, 32]),
            EncoderOptions(fap_quant=31, ranges="persist", plane_start_codes="none"),
        ),
        (
            synthetic_sequence(8, 12.5, visemes=False, expressions=True, faps=list(range(3, 19))),
            EncoderOptions(fap_quant=5, partial_mask_type=2),
        ),
    ]
    for frames, opts in cases:
        out.append(encode(frames, opts).data)
    f = synthetic_sequence(6, 25.0, faps=[3])
    f.frame_number[:] = [0, 100, 101, 400, 401, 402]  # long skip chains
    out.append(encode(f, EncoderOptions()).data)
    return out


def mutate(rnd: random.Random, data: bytes, corpus: list[bytes]) -> bytes:
    b = bytearray(data)
    kind = rnd.randrange(6)
    if kind == 0 and b:  # truncation
        return bytes(b[: rnd.randrange(len(b))])
    if kind == 1 and b:  # bit flips
        for _ in range(rnd.randint(1, 8)):
            i = rnd.randrange(len(b) * 8)
            b[i // 8] ^= 0x80 >> (i % 8)
        return bytes(b)
    if kind == 2:  # byte insertions / deletions
        for _ in range(rnd.randint(1, 4)):
            i = rnd.randrange(len(b) + 1)
            if rnd.random() < 0.5 and b:
                del b[min(i, len(b) - 1)]
            else:
                b.insert(i, rnd.choice([0x00, 0x01, 0xBB, 0xB1, 0xFF, 0x7F, rnd.randrange(256)]))
        return bytes(b)
    if kind == 3:  # splice two streams
        other = rnd.choice(corpus)
        return bytes(b[: rnd.randrange(len(b) + 1)] + other[rnd.randrange(len(other)) :])
    if kind == 4:  # random bytes after a valid start code
        return b"\x00\x00\x01\xba" + bytes(rnd.randrange(256) for _ in range(rnd.randrange(64)))
    # random bytes, any length
    return bytes(rnd.randrange(256) for _ in range(rnd.randrange(48)))


def test_ten_thousand_malformed_inputs_give_only_typed_errors():
    rnd = random.Random(20261121)
    corpus = seed_corpus()
    outcomes = {"ok": 0, "error": 0}
    rules = set()
    for i in range(N_INPUTS):
        data = mutate(rnd, rnd.choice(corpus), corpus)
        try:
            res = decode(data)
        except BitstreamError as e:
            outcomes["error"] += 1
            rules.add(e.rule)
            assert e.bit_offset >= 0 and e.byte_offset <= max(len(data), 1)
            assert e.rule != "internal", f"input #{i} hit an internal failure: {e}"
        else:
            outcomes["ok"] += 1
            fr = res.frames
            assert fr.values.dtype == np.int32 and len(fr) == len(res.planes)
            assert np.isfinite(fr.time_ms).all()
    assert sum(outcomes.values()) == N_INPUTS
    assert outcomes["ok"] > 100 and outcomes["error"] > 1000  # both paths really exercised
    assert {"truncated", "marker", "object-mask"} <= rules


@settings(max_examples=300)
@given(st.binary(max_size=200))
def test_arbitrary_bytes(data):
    try:
        decode(b"\x00\x00\x01\xba" + data)
    except BitstreamError as e:
        assert e.rule != "internal"


def test_every_truncation_point_of_a_stream():
    data = seed_corpus()[0]
    for n in range(len(data)):
        try:
            decode(data[:n])
        except BitstreamError as e:
            assert e.rule != "internal"
