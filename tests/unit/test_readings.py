"""The other readings of fbaconf's provisional decisions (bitstreams/readings.py,
bitstreams/data/readings.toml): each does what its line of the spec notes says, is off unless
asked for, and changes a stream's decoding only where the checker warns that it may."""

from __future__ import annotations

import tomllib
from importlib import resources

import numpy as np
import pytest
from hypothesis import given, settings

from fbaconf.bitstreams import readings, syntax, tables
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.frames import FREE, RETAINED
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.profiles.checker import check_stream
from fbaconf.rules import CODES

from lib.cases import case
from lib.codec import sequences


def decoded(data: bytes):
    try:
        return decode(data).frames
    except FbaconfInputError as e:
        return e.rule


def same(a, b) -> bool:
    """Equal for every comparison a verdict makes: any two rejections are alike, as are two
    decodings with the same values, statuses, high-level fields, frame numbers, times and rate."""
    if isinstance(a, str) or isinstance(b, str):
        return isinstance(a, str) and isinstance(b, str)
    return (
        a.frame_rate == b.frame_rate
        and len(a) == len(b)
        and all(
            np.array_equal(getattr(a, k), getattr(b, k))
            for k in ("values", "status", "high", "frame_number", "time_ms")
        )
    )


def test_the_catalogue_names_known_decisions_and_checker_codes():
    decisions = {
        r["id"]
        for r in tomllib.loads(
            resources.files("fbaconf.conformance").joinpath("data/provisional.toml").read_text("utf-8")
        )["rule"]
    }
    cat = readings.catalogue()
    assert set(cat) == {
        "D3:type10-keeps",
        "D4:keep-scaling",
        "D4:defaults-unrounded",
        "D4:value-range-enforced",
        "D5:blend-ceil",
        "D6:default-30hz",
        "D7:rewind-14",
    }
    for r in cat.values():
        assert r.id.startswith(r.decision + ":") and r.decision in decisions
        assert r.warning in CODES and r.decision in CODES[r.warning].clause
        assert readings.by_slug(r.slug) is r
    with pytest.raises(readings.ReadingError):
        readings.get("D8:iso-tables")


def test_blend_ceil_is_ceil_63_over_q_and_differs_exactly_where_the_policy_review_counted():
    d5 = {q: syntax.intensity_bound(q) for q in range(32)}
    with readings.using(readings.BLEND_CEIL):
        ceil = {q: syntax.intensity_bound(q) for q in range(32)}
    assert syntax.intensity_bound(10) == 6  # floor((63 + 5) / 10), back to D5 after the block
    for q in range(32):
        d = max(q, 1)
        assert ceil[q] == -(-63 // d) and d5[q] == (63 + d // 2) // d
    assert sorted(q for q in range(32) if ceil[q] != d5[q]) == [10, 12, 15, 19, 20, 26, 27, 28, 29, 30, 31]


def test_defaults_unrounded_use_the_tables_numbers():
    # open_jaw (FAP 3): intra 1080, predicted 360 in fap_table.csv
    assert list(tables.default_bounds()[2]) == [1080, -1080, 360, -360]  # multiples of 60 already
    rows = {f.number: f for f in tables.fap_table()}
    odd = next(n for n, f in rows.items() if n > 2 and f.intra_range % 60)
    with readings.using(readings.DEFAULTS_UNROUNDED):
        assert tables.default_bounds()[odd - 1][0] == rows[odd].intra_range
    assert tables.default_bounds()[odd - 1][0] % 60 == 0 and tables.default_bounds()[odd - 1][0] > rows[odd].intra_range


def test_default_30hz_times_a_stream_without_a_rate_at_30_hz():
    data = case("simple-l1-core/no-frame-rate").input_path("fba").read_bytes()
    at25 = decode(data).frames
    with readings.using(readings.DEFAULT_30HZ):
        at30 = decode(data).frames
    assert at25.frame_rate == 25.0 and at30.frame_rate == 30.0
    # plane time = frame number / rate (no time codes in this stream): hand formula, both readings
    np.testing.assert_allclose(at25.time_ms, at25.frame_number * 1000.0 / 25.0)
    np.testing.assert_allclose(at30.time_ms, at30.frame_number * 1000.0 / 30.0)
    np.testing.assert_array_equal(at25.values, at30.values)


def test_type10_keeps_holds_what_d3_frees_and_changes_nothing_else():
    data = case("simple-l1-core/arith-mask-interpolate").input_path("fba").read_bytes()
    d3 = decode(data).frames
    with readings.using(readings.TYPE10_KEEPS):
        s1 = decode(data).frames
    changed = d3.status != s1.status
    assert changed.any()
    assert set(d3.status[changed]) == {FREE} and set(s1.status[changed]) == {RETAINED}
    np.testing.assert_array_equal(d3.values, s1.values)


def test_rewind_14_reads_the_lookahead_cases_otherwise_and_needs_the_pure_decoder():
    data = case("simple-l1-core/lookahead-stuffing").input_path("fba").read_bytes()
    with readings.using(readings.REWIND_14):
        assert readings.pure_required()
        other = decoded(data)
    assert not readings.pure_required()
    assert not same(other, decoded(data))


def test_readings_switch_on_only_inside_the_block_and_nest():
    assert not readings.active(readings.REWIND_14)
    with readings.using(readings.REWIND_14):
        with readings.using(readings.BLEND_CEIL):
            assert readings.active(readings.REWIND_14) and readings.active(readings.BLEND_CEIL)
        assert readings.active(readings.REWIND_14) and not readings.active(readings.BLEND_CEIL)
    assert not readings.active(readings.REWIND_14)


@settings(max_examples=60, deadline=None)
@given(sequences())
def test_a_reading_changes_a_decoding_only_where_the_checker_warns(seq):
    """The checker's FAP-DECISION warnings are what a vendor sees of a stream's dependence on a
    decision: a reading may change a stream's decoding only when its warning is among them."""
    frames, opts, _types = seq
    data = encode(frames, opts).data
    warned = {d.code for d in check_stream(data)}
    base = decoded(data)
    for r in readings.catalogue().values():
        if r.warning in warned:
            continue
        with readings.using(r.id):
            assert same(decoded(data), base), r.id


def test_every_suite_case_a_reading_changes_carries_its_warning():
    """Over the committed suites: where a reading's goldens exist the checker warned, and a
    reading's goldens exist exactly where its decoding differs (conformance/golden.py)."""
    from fbaconf.conformance.golden import reading_goldens  # noqa: PLC0415

    for s in load_suites():
        for c in s.cases:
            fba = c.input_path("fba")
            if fba is None:
                continue
            data = fba.read_bytes()
            warned = {d.code for d in check_stream(data)}
            base = decoded(data)
            have = reading_goldens(c)
            for r in readings.catalogue().values():
                with readings.using(r.id):
                    differs = not same(decoded(data), base)
                assert differs == (r.id in have), (c.full_id, r.id)
                if differs:
                    assert r.warning in warned or c.kind.value == "error", (c.full_id, r.id)
