"""Localising a failure by its first difference: the stream points a case has up to a frame (a
stream made here, where each point's frame is chosen by hand), which first differences name a
frame of the FAP sequence, and the ranking of a run whose failing cases differ before their
common point (the point is no longer their cause) or at it (it still is)."""

from __future__ import annotations

import numpy as np
import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.conformance.coverage import stream_points, stream_points_through
from fbaconf.conformance.coverage_table import points_of
from fbaconf.conformance.suite import load_suites
from fbaconf.explain.causes import explain
from fbaconf.explain.localise import first_frame
from fbaconf.harness.results import CaseResult, Outcome, RunRecord, StageResult


def _stream() -> bytes:
    # six frames of FAP 3 at 10 Hz; the last comes 16 frames after the fifth: a skip of 15, one
    # full chunk and a chain, in the plane of output frame 5 and in no other
    f = synthetic_sequence(6, 10.0, visemes=False, expressions=False, faps=[3])
    f.frame_number[:] = [0, 1, 2, 3, 4, 20]
    return encode(f, EncoderOptions()).data


def test_the_points_up_to_a_frame_are_those_its_planes_hit():
    data = _stream()
    full = stream_points(data)
    assert {"skip.frames", "skip.chain", "stream.end-code"} <= full
    early = stream_points_through(data, 2)
    assert early is not None and "plane.intra" in early and "fap.3" in early
    assert not {"skip.frames", "skip.chain", "stream.end-code"} & early
    last = stream_points_through(data, 5)
    assert last is not None and {"skip.frames", "skip.chain"} <= last
    # the cut stream has every plane, and no end code
    assert last - {"stream.no-end-code"} == full - {"stream.end-code"}
    assert stream_points_through(data, 6) is None and stream_points_through(data, -1) is None
    assert stream_points_through(data[:3], 0) is None  # no face object start code: nothing decodes


def _case(stage: str, fd: dict | None) -> CaseResult:
    r = CaseResult("s/c", "s", "simple@1", Outcome.FAIL)
    r.stages = [StageResult("process", Outcome.PASS), StageResult(stage, Outcome.FAIL, first_difference=fd)]
    return r


@pytest.mark.parametrize(
    ("stage", "fd", "frame"),
    [
        ("faps", {"frame": 4, "fap": 3, "what": "value"}, 4),
        ("effective_faps", {"frame": 2, "fap": 19}, 2),
        ("vertices", {"frame": 7, "vertex": 12}, 7),
        ("vertices[feature_points]", {"frame": 1, "vertex": 0}, 1),
        ("images", {"frame": 3, "pixel": [1, 2]}, None),  # rendered frames are labels, not FAP rows
        ("faps", {"what": "frame rate", "expected": 25, "got": 30}, None),  # a header difference
        ("faps", {"frame": True}, None),
        ("faps", None, None),
    ],
)
def test_which_first_differences_name_a_frame(stage, fd, frame):
    assert first_frame(_case(stage, fd)) == frame


@pytest.fixture(scope="module")
def core_cases():
    return {c.full_id: c for s in load_suites(names=["simple-l1-core"]) for c in s.cases}


def _chain_row(case) -> int | None:
    """The output frame of the first plane with a skip chain, from the reference decoder's parse."""
    res = decode(case.input_path("fba").read_bytes())
    plane = next((p for p in res.planes if p.skip >= 15), None)
    if plane is None:
        return None
    return int(np.flatnonzero(res.frames.bit_offset == plane.bit_offset)[0])


def _run(core_cases, at: dict[str, int]) -> RunRecord:
    results = []
    for cid, c in core_cases.items():
        r = CaseResult(cid, c.suite, c.claim, Outcome.FAIL if cid in at else Outcome.PASS, kind=c.kind.value)
        if cid in at:
            fd = {"frame": at[cid], "fap": 3, "what": "value", "expected": 0, "got": 1}
            r.stages = [StageResult("faps", Outcome.FAIL, first_difference=fd)]
        results.append(r)
    return RunRecord(decoder={"name": "d", "inputs": ["fba"]}, claim="simple@2", suites=[], system={}, results=results)


def test_a_point_after_the_first_difference_is_not_the_cause_one_at_it_is(core_cases):
    rows = {cid: _chain_row(c) for cid, c in core_cases.items() if "skip.chain" in points_of(c)}
    rows = {cid: r for cid, r in rows.items() if r}  # cases whose chain is not in their first plane
    assert len(rows) >= 2, rows
    at_chain = explain(_run(core_cases, rows), core_cases).causes[0]
    assert "skip.chain" in (at_chain.feature, *at_chain.aliases, *at_chain.tied)
    before = explain(_run(core_cases, {cid: 0 for cid in rows}), core_cases)
    assert all("skip.chain" not in (c.feature, *c.aliases, *c.tied) for c in before.causes)
    assert before.explained == before.failing == len(rows)
