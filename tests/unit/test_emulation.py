"""D9: the encoder never emulates a start code; the scan finds what it must."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.emulation import find_emulations
from fbaconf.bitstreams.encoder import EncoderOptions, _encode_once, encode
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "fap"
SET_ = settings(max_examples=60, deadline=None, suppress_health_check=list(HealthCheck))


def test_scan_by_hand():
    # object start code at 0, a plane start code after stuffing, an emulation, the end code
    data = b"\x00\x00\x01\xba" + b"\x80\x7f\x00\x00\x01\xbb" + b"\x12\x00\x00\x01\x44" + b"\x7f\x00\x00\x01\xb1"
    assert find_emulations(data, start_codes=[0, 6, 16]) == [11]
    assert find_emulations(data, start_codes=[0, 6, 11, 16]) == []


@st.composite
def zero_heavy(draw):
    n = draw(st.integers(2, 24))
    faps = draw(st.lists(st.integers(3, 68), min_size=1, max_size=12, unique=True))
    f = FapFrames.empty(n, draw(st.sampled_from([2.0, 10.0, 25.0, 30.0])))
    for fap in faps:
        f.status[:, fap - 1] = SET
    zero_p = draw(st.floats(0.5, 1.0))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    vals = rng.integers(-300, 301, size=(n, len(faps)))
    vals[rng.random((n, len(faps))) < zero_p] = 0
    f.values[:, [x - 1 for x in faps]] = np.cumsum(vals, axis=0).clip(-1800, 1800)
    return f


@SET_
@given(
    zero_heavy(), st.integers(0, 31), st.sampled_from(["arithmetic", "dct"]), st.sampled_from(["none", "intra", "all"])
)
def test_no_emulation_in_any_encoding(frames, q, coding, psc):
    try:
        r = encode(frames, EncoderOptions(fap_quant=q, coding=coding, plane_start_codes=psc))
    except FbaconfInputError as e:
        assert e.rule in ("value-range", "value-overflow"), e
        return
    assert find_emulations(r.data) == []
    assert find_emulations(r.data, start_codes=r.start_codes) == []
    got = decode(r.data).frames
    np.testing.assert_array_equal(got.values[:, 2:], r.recon.values[:, 2:])


def test_prevention_is_what_removed_the_emulation():
    """The committed emulating stream is the prevention-free encoding; encode() of the same
    content adds plane start codes and decodes to the same frames."""
    path = REAL / "vreng" / "eyes.fap"
    if not path.is_file():
        pytest.skip(f"{path} not present (../shared/data)")
    fr = read_fap_file(path)[0]
    raw = _encode_once(fr, EncoderOptions(fap_quant=1, plane_start_codes="none"))
    assert raw.data == (Path(__file__).parents[1] / "data" / "emulation" / "emulating.fba").read_bytes()
    assert find_emulations(raw.data) == [132]
    fixed = encode(fr, EncoderOptions(fap_quant=1, plane_start_codes="none"))
    assert find_emulations(fixed.data) == [] and len(fixed.start_codes) > len(raw.start_codes)
    np.testing.assert_array_equal(decode(fixed.data).frames.values, decode(raw.data).frames.values)


@pytest.mark.external
def test_no_emulation_in_any_encoding_of_the_real_files():
    files = sorted(REAL.glob("*/*.fap"))
    if not files:
        pytest.skip(f"no real .fap files under {REAL}")
    n = 0
    for f in files:
        fr = read_fap_file(f)[0]
        for coding, qs in (("arithmetic", (1, 8, 22, 31)), ("dct", (0, 9, 31))):
            for q in qs:
                try:
                    r = encode(fr, EncoderOptions(fap_quant=q, coding=coding, plane_start_codes="none"))
                except FbaconfInputError:
                    continue
                assert find_emulations(r.data) == [], (f.name, coding, q)
                n += 1
    assert n > 100


def test_no_valid_suite_stream_emulates():
    n = 0
    for s in load_suites():
        for c in s.cases:
            paths = ([c.input_path("fba")] if c.inputs.get("fba") else []) + c.face_paths()
            for p in paths:
                if c.kind == "error":
                    continue
                assert find_emulations(p.read_bytes()) == [], c.full_id
                n += 1
    assert n > 40
