"""Every case's stream tools are the ones its streams use (the tools a decoder may decline).

A decoder that does not declare a tool gets NotSupported on the cases tagged with it
(harness/selection.py), so a case must carry exactly the stream tools its streams use: a DCT
plane -> ``dct``, a frame-based (arithmetic) plane -> ``arithmetic``, FAP 1 or 2 coded ->
``high_level_faps``. The tools are derived here from the case's own stream(s) with the
reference parser, independently of suites.toml; for an invalid stream from the planes the
parser read before the error, the plane it stopped in included as far as it got (a plane cut
short before its coding_type says nothing of its mode).
"""

from __future__ import annotations

import pytest

from fbaconf.bitstreams.decoder import _Decoder
from fbaconf.bitstreams.syntax import CODING_DCT
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import BitstreamError

STREAM_TOOLS = {"arithmetic", "dct", "high_level_faps"}


def stream_tools(data: bytes) -> set[str]:
    d = _Decoder(data, None)
    try:
        d.run()
    except BitstreamError:
        pass
    planes = list(d.planes) + ([d.current] if d.current is not None else [])
    out: set[str] = set()
    for p in planes:
        if not p.coding_known:
            continue
        out.add("dct" if p.coding_type == CODING_DCT else "arithmetic")
        if p.coded is not None and (p.coded[0] or p.coded[1]):
            out.add("high_level_faps")
    return out


def _stream_cases():
    for s in load_suites():
        for c in s.cases:
            paths = ([c.input_path("fba")] if c.inputs.get("fba") else []) + c.face_paths()
            if paths:
                yield c, paths


CASES = list(_stream_cases())


def test_the_derivation_reads_a_plane_cut_short():
    """dct-bad-vlc breaks inside its first (DCT) plane group; too-short has no plane at all."""
    by_id = {c.full_id: paths for c, paths in CASES}
    (bad_vlc,) = by_id["simple-l1-error/dct-bad-vlc"]
    assert stream_tools(bad_vlc.read_bytes()) == {"dct"}
    (too_short,) = by_id["simple-l1-error/too-short"]
    assert stream_tools(too_short.read_bytes()) == set()


@pytest.mark.parametrize("case,paths", CASES, ids=[c.full_id for c, _ in CASES])
def test_stream_tools_match_the_streams(case, paths):
    derived = set().union(*(stream_tools(p.read_bytes()) for p in paths))
    assert set(case.tools) & STREAM_TOOLS == derived, (sorted(case.tools), sorted(derived))
