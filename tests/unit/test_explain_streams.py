"""The stream edits that confirm a cause: coded again as the original was, a stream decodes to the
original's frames (quantiser, coding, start codes, time codes, gender and end code too), and a FAP
dropped from it is the only change (random sequences and encoder options, as the codec's
property tests draw them)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import encode
from fbaconf.bitstreams.encoder_options import EncoderOptions
from fbaconf.bitstreams.frames import FREE, FapFrames
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.explain import edits, streams

from lib.codec import sequences


def _same_frames(a: FapFrames, b: FapFrames, *, but: tuple[int, ...] = ()) -> None:
    keep = [j for j in range(68) if j + 1 not in but]
    np.testing.assert_array_equal(a.status[:, keep], b.status[:, keep])
    held = a.status[:, keep] != FREE
    np.testing.assert_array_equal(a.values[:, keep][held], b.values[:, keep][held])
    np.testing.assert_array_equal(a.frame_number, b.frame_number)
    np.testing.assert_array_equal(a.fap_quant, b.fap_quant)
    np.testing.assert_array_equal(a.coding_type, b.coding_type)
    assert a.frame_rate == b.frame_rate and a.gender == b.gender


@settings(max_examples=60, deadline=None)
@given(seq=sequences())
def test_coded_again_as_it_was_coded_a_stream_decodes_as_it_did(seq):
    frames, opts, _ = seq
    data = encode(frames, opts).data
    variant = streams.stream_variant(data, edits.nothing, streams.as_coded)
    assert variant is not None
    a, b = decode(data), decode(variant)
    _same_frames(a.frames, b.frames)
    for fap, cols in ((1, slice(0, 4)), (2, slice(4, 10))):  # the high-level fields where FAP 1/2 hold
        rows = a.frames.status[:, fap - 1] != FREE
        np.testing.assert_array_equal(a.frames.high[rows, cols], b.frames.high[rows, cols])
    assert [p.start_code for p in a.planes] == [p.start_code for p in b.planes]
    assert {p.time_code is not None for p in a.planes if p.is_intra} == {
        p.time_code is not None for p in b.planes if p.is_intra
    }
    assert (a.end_code is None) == (b.end_code is None)


@settings(max_examples=60, deadline=None)
@given(seq=sequences(), pick=st.integers(0, 67))
def test_a_dropped_fap_is_the_only_change(seq, pick):
    frames, opts, _ = seq
    data = encode(frames, opts).data
    original = decode(data).frames
    coded = [j + 1 for j in range(2, 68) if (original.status[:, j] != FREE).any()]
    if not coded:
        return
    fap = coded[pick % len(coded)]
    variant = streams.stream_variant(data, edits.drop(fap), streams.as_coded)
    assert variant is not None
    got = decode(variant).frames
    assert (got.status[:, fap - 1] == FREE).all()
    _same_frames(original, got, but=(fap,))


def test_a_stream_coded_with_lists_only_where_needed_is_coded_again_so():
    """The encoder's "persist" range mode sends a list only where a value needs one: here FAP 19
    at 1,500 in the first plane needs a new i_max list, and no later intra plane sends any. Read
    as the "auto" mode (all four lists in every intra plane) because some plane had a list, the
    stream came back longer, with other bits (and, once, a start code the original did not
    have). Coded again as it was coded, it is the same stream, byte for byte; and so is one coded
    with all four lists in every intra plane."""
    for ranges, value in (("persist", 1500), ("auto", 0)):
        frames = synthetic_sequence(6, 25.0, visemes=False, expressions=False, faps=[3, 19, 48], seed=4)
        frames.values[0, 18] = value
        data = encode(frames, EncoderOptions(ranges=ranges, intra_period=1)).data
        lists = [sorted(p.new_lists) for p in decode(data).planes]
        if ranges == "persist":
            assert lists == [["i_max"]] + [[]] * 5  # the case this test is about
        else:
            assert all(len(x) == 4 for x in lists)
        assert streams.stream_variant(data, edits.nothing, streams.as_coded) == data, ranges
