"""One stream (or scene) per diagnostic code that triggers exactly that code.

Streams come from the reference encoder (profiles.sample_streams), bit-edited where needed
(bitstreams/bitedit.py). ``CASES`` maps every registered code to its builder; a test fails when
a code has no case, so a new code cannot land untested.
"""

from __future__ import annotations

import json
import re
import sys
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from fbaconf import rules as R
from fbaconf.animation.faceparams import fp_index
from fbaconf.bitstreams import arith, decoder as decmod
from fbaconf.bitstreams.bitedit import end_stream, flip_bit, get_bits, remove_bits, set_bits, splice, truncate_bits
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import FREE, SET, FapFrames
from fbaconf.bitstreams.syntax import d5_alphabet_differs, intensity_bound, intensity_bound_ceil
from fbaconf.cli import main
from fbaconf.errors import BitstreamError
from fbaconf.generators.recipes import pred_beyond_intra_range
from fbaconf.profiles import checker, diagnostics as D
from fbaconf.profiles.checker import SceneSummary, analyse, check_stream, lookahead_stuffing
from fbaconf.profiles.model import load_profiles, parse_profiles
from fbaconf.profiles.sample_streams import (
    make_stream,
    smooth_frames,
    stuffing_positions,
    value_overflow_stream,
    zero_heavy_plane,
)

FEW = range(3, 40)  # no FAP 63 (its default range is not a multiple of 60: FAP-DECISION-003)


def codes(data, **kw) -> set[str]:
    return {d.code for d in check_stream(data, **kw)}


def base(n=20, **kw) -> bytes:
    kw.setdefault("plane_start_codes", "none")
    return make_stream(n=n, faps=kw.pop("faps", FEW), **kw)


def test_base_stream_is_clean():
    assert codes(base()) == set()
    assert codes(base(n=40, intra_period=10, time_codes=True, plane_start_codes="intra")) == set()
    assert codes(base(n=40, intra_period=7, plane_start_codes="all", fap_quant=3)) == set()
    with pytest.raises(ValueError):
        check_stream(base(), claim="simple@7")


# ---------------------------------------------------------------------------- builders
def _header(data, plane=0):
    return decode(data).planes[plane].header_offset


def case_too_short(**_):
    return b"\x00\x00\x01", {}


def case_not_face(**_):
    return b"\x00\x00\x01\xb6" + bytes(20), {}


def case_truncated(**_):
    data = base()
    p = decode(data).planes[5]
    return truncate_bits(data, p.bit_offset + 40), {}


def case_marker(**_):
    data = base()
    at = decode(data).planes[0].marker_offsets[0][0]
    return flip_bit(data, at), {}


def case_object_mask(**_):
    data = base()
    return set_bits(data, _header(data) + 1, 2, 0b11), {}


def case_first_predicted(**_):
    data = base()
    return flip_bit(data, _header(data)), {}


def case_stuffing(**_):
    data = zero_heavy_plane()
    _, start, length = decode(data).planes[0].blocks[-1]
    pos = stuffing_positions(data, start, length)
    assert pos, "test stream must contain a stuffing bit"
    return flip_bit(data, pos[0]), {}


def case_arith_state(monkeypatch, **_):
    """The reference decoder keeps low <= value <= high for any input bits, so this rule is
    defensive: simulated by making the block decoder report it."""

    def decode_sym(self, model):
        raise self.r.error("arithmetic decoder state out of range (corrupt block)", "arith-state")

    monkeypatch.setattr(arith.ArithDecoder, "decode", decode_sym)
    return base(), {}


def case_no_end_code(**_):
    return base(end_code=False), {}


def case_trailing(**_):
    return base() + b"\x00\x17", {}


def case_unexpected_start_code(**_):
    data = base()
    assert data[-4:] == b"\x00\x00\x01\xb1"
    return data[:-1] + b"\xb6", {}


def case_other(monkeypatch, **_):
    def boom(self, start, has_sc):
        raise self.err("synthetic failure", "synthetic-rule")

    monkeypatch.setattr(decmod._Decoder, "plane", boom)
    return base(), {}


def case_dct_syntax(**_):
    data = make_stream(n=16, faps=range(3, 12), coding="dct", plane_start_codes="none")
    p = decode(data).planes[0]
    for _name, start, length in p.blocks:
        for b in range(start, start + length):
            bad = flip_bit(data, b)
            try:
                decode(bad)
            except BitstreamError as e:
                if R.code_for_rule(e.rule, R.SYNTAX_OTHER) == R.SYNTAX_DCT:
                    return bad, {}
    raise AssertionError("no single-bit corruption of the DCT data gives a FAP-SYNTAX DCT error")


def case_frame_rate_zero(**_):
    data = base()
    return set_bits(data, _header(data) + 4, 12, 0), {}


def case_time_code_range(**_):
    data = base(time_codes=True)
    h = _header(data)
    assert get_bits(data, h + 17, 1) == 1  # is_time_code
    return set_bits(data, h + 18, 5, 24), {}  # hours = 24


def case_time_backwards(**_):
    data = make_stream(n=30, rate=10.0, faps=FEW, time_codes=True, intra_period=10, plane_start_codes="none")
    p = decode(data).planes[20]
    assert p.is_intra and p.time_code is not None
    return set_bits(data, p.header_offset + 18 + 12, 6, 0), {}  # seconds 2 -> 0


def _hl_frames(n, fields: dict[int, list[int]], fap: int) -> FapFrames:
    f = FapFrames.empty(n, 30.0)
    f.status[:, fap - 1] = SET
    for col, vals in fields.items():
        f.high[:, col] = vals
    return f


def _splice_intra_then_p(a: bytes, b: bytes) -> bytes:
    """A's intra plane followed by B's predicted plane (same masks and quantiser)."""
    pa, pb = decode(a).planes, decode(b).planes
    assert not pb[1].is_intra
    joined = splice((a, 0, pa[0].end_offset), (b, pb[1].bit_offset, pb[1].end_offset))
    return end_stream(joined, pa[0].end_offset + pb[1].end_offset - pb[1].bit_offset)


def case_viseme_select(**_):
    opts = EncoderOptions(plane_start_codes="none")
    a = encode(_hl_frames(1, {0: [14]}, 1), opts).data
    b = encode(_hl_frames(2, {0: [0, 5]}, 1), opts).data
    return _splice_intra_then_p(a, b), {}


def case_expression_select(**_):
    opts = EncoderOptions(plane_start_codes="none")
    a = encode(_hl_frames(1, {4: [6]}, 2), opts).data
    b = encode(_hl_frames(2, {4: [0, 4]}, 2), opts).data
    return _splice_intra_then_p(a, b), {}


def case_intensity(**_):
    opts = EncoderOptions(plane_start_codes="none")
    a = encode(_hl_frames(1, {2: [63]}, 1), opts).data
    b = encode(_hl_frames(2, {2: [0, 30]}, 1), opts).data
    return _splice_intra_then_p(a, b), {}


def case_value_overflow(**_):
    return value_overflow_stream(), {}


def case_single_symbol(**_):
    f = smooth_frames(20, 30.0, FEW)
    f.values[:, 2] = 40  # FAP 3 constant: its predicted range lists are 0 -> one symbol
    return encode(f, EncoderOptions(plane_start_codes="none")).data, {}


def case_quant_no_lists(**_):
    q = np.array([1] * 10 + [2] * 10)
    data = make_stream(n=20, faps=FEW, ranges="persist", fap_quant_per_frame=q, plane_start_codes="none")
    planes = decode(data).planes
    p = planes[10]
    assert p.is_intra and len(p.new_lists) == 4 and not planes[0].new_lists
    group_markers = 10
    first_list = p.marker_offsets[group_markers][0]
    p_min_start = p.marker_offsets[group_markers + 3 * 18][0]
    block_start = p.blocks[0][1]
    removed = block_start - p_min_start
    edited = remove_bits(data, p_min_start, removed)
    edited = set_bits(edited, first_list - 1, 1, 0)  # is_p_new_min = 0
    return end_stream(edited, planes[-1].end_offset - removed), {}


def case_unidirectional_negative(**_):
    f = smooth_frames(20, 30.0, FEW)
    f.values[:, 2] = -f.values[:, 2]  # open_jaw (U) negative
    return encode(f, EncoderOptions(plane_start_codes="none")).data, {}


def case_default_rounding(**_):
    return make_stream(n=20, faps=[61, 62, 63, 64], ranges="persist", plane_start_codes="none"), {}


def case_no_frame_rate(**_):
    data = base()
    h = _header(data)
    planes = decode(data).planes
    assert sum(p.is_intra for p in planes) == 1
    edited = set_bits(remove_bits(data, h + 4, 13), h + 3, 1, 0)
    return end_stream(edited, planes[-1].end_offset - 13), {}


# viseme block whose flush leaves a long zero run, followed by viseme_def = 0 and a
# low-level block that starts with zeros: a stuffing position falls in the look-ahead.
LOOKAHEAD_VISEME = (0, 3, 32)


def _lookahead_stream() -> bytes:
    b = np.zeros((68, 4), dtype=np.int64)
    b[:, 0], b[:, 1], b[:, 2], b[:, 3] = 1860, -1860, 1860, -1860
    f = FapFrames.empty(1, 30.0)
    f.status[0, 0] = f.status[0, 2] = f.status[0, 3] = SET
    f.high[0, :3] = LOOKAHEAD_VISEME
    f.values[0, 2], f.values[0, 3] = 1860 * 4, 1860 * 2
    return encode(f, EncoderOptions(fap_quant=1, bounds=b, plane_start_codes="none")).data


def case_lookahead(**_):
    return _lookahead_stream(), {}


def case_mask_interpolate(**_):
    f = smooth_frames(20, 30.0, range(3, 11))
    f.status[10:, 3] = FREE  # FAP 4 set in frames 0-9, then left to the decoder (type 10)
    return encode(f, EncoderOptions(plane_start_codes="none")).data, {}


def _high_level_stream(quants, blend=40) -> bytes:
    """Visemes alone coded at fap_quant ``quants[k]`` in frame k."""
    f = FapFrames.empty(len(quants), 30.0)
    f.status[:, 0] = SET
    f.high[:, 0], f.high[:, 1], f.high[:, 2] = 3, 5, blend
    return encode(f, EncoderOptions(fap_quant_per_frame=np.array(quants), plane_start_codes="none")).data


def case_high_level_quant(**_):
    return _high_level_stream([10] * 10), {}


def case_intensity_d5(**_):
    # fap_quant 10: D5's alphabet 0..6 (top 60, so 63 bounds the values), the other reading's 0..7 (70);
    # intra 60 (A), then B's predicted +1 level: 70 is out of range only under D5 (and the stream
    # depends on D5: FAP-DECISION-007 too)
    opts = EncoderOptions(fap_quant=10, plane_start_codes="none")
    a = encode(_hl_frames(1, {2: [60]}, 1), opts).data
    b = encode(_hl_frames(2, {2: [0, 10]}, 1), opts).data
    return _splice_intra_then_p(a, b), {}


def case_pred_outside_intra(**_):
    return pred_beyond_intra_range(), {}


def case_profile_tool(**_):
    return base(), {"claim": "simple@1", "scene": SceneSummary(faces=1, tools={"fit": "Face.fit.FIT"})}


def _scene(measure: str, value: float) -> SceneSummary:
    s = SceneSummary(faces=1, tools={"fdp_feature_points": "FDP", "downloaded_model": "FDP.faceSceneGraph"})
    s.measure(measure, value, f"FDP.{measure}")
    return s


def case_bitrate(**_):
    return make_stream(n=90, intra_period=10), {"claim": "simple@1"}


def case_frame_rate(**_):
    return make_stream(n=60, rate=60.0, faps=range(3, 12)), {"claim": "simple@1"}


def case_faces(**_):
    return base(), {"claim": "simple@1", "scene": SceneSummary(faces=2)}


LEVEL_SCENE = {
    R.LEVEL_FDP_POINTS: ("fdp_feature_points", 85),
    R.LEVEL_FIT_NODES: ("fit_nodes", 17),
    R.LEVEL_FIT_LINKS: ("fit_links", 33),
    R.LEVEL_FIT_TERMS: ("fit_terms", 9),
    R.LEVEL_TEXTURE: ("texture_width", 1024),
    R.LEVEL_MESH_VERTICES: ("mesh_vertices", 5001),
    R.LEVEL_FDT_ENTRIES: ("facedeftables_entries", 201),
    R.LEVEL_INTERVALS: ("intervals_per_facedefmesh", 9),
}


def _level_scene_case(code):
    def build(**_):
        key, value = LEVEL_SCENE[code]
        return base(), {"claim": "predictable@1", "scene": _scene(key, value)}

    return build


def case_claim_none(**_):
    return make_stream(n=60, rate=60.0, faps=range(3, 69), intra_period=1), {"smallest_claim": True}


def case_scene_unavailable(monkeypatch, tmp_path, **_):
    monkeypatch.setitem(sys.modules, "fbaconf.scenes.bt", None)  # import fails
    p = tmp_path / "s.bt"
    p.write_text("Face {}\n")
    return base(), {"scene": str(p)}


def case_scene_invalid(tmp_path, **_):
    return base(), {"scene": str(tmp_path / "missing.bt")}


def case_scene_interop(tmp_path, **_):
    # the seed's FaceDefMesh: faceSceneGraphNode is a USE of the IndexedFaceSet it deforms
    p = tmp_path / "fdm.bt"
    p.write_text("""DEF FACE Face { fdp FDP {
  faceSceneGraph [ Shape { geometry DEF MESH IndexedFaceSet {
    coord Coordinate { point [ 0 0 0, 1 0 0, 0 1 0 ] } coordIndex [ 0 1 2 -1 ] } } ]
  faceDefTables [ FaceDefTables { fapID 3 highLevelSelect 0
    faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE MESH intervalBorders [ 0 1024 ]
      coordIndex [ 0 ] displacements [ 0 -1 0 ] } ] } ] } }
""")
    return base(), {"scene": str(p)}


def case_scene_ill_conditioned(tmp_path, **_):
    # three feature points sent (3.5, 3.6, 2.1) whose orthographic texture projections are nearly
    # collinear (2.1 is 1e-5 off the line through the eyes): the uv map's system has a condition
    # number of ~1e13, above the bound 1e8 (animation/rbf.py)
    sent = {fp_index("3.5"): "30 40 50", fp_index("3.6"): "-30 40 50", fp_index("2.1"): "0 40.00001 80"}
    pts = ", ".join(sent.get(k, "3.4e38 3.4e38 3.4e38") for k in range(84))
    uv = ", ".join("0.5 0.5" for _ in range(84))
    p = tmp_path / "fdp.bt"
    p.write_text(
        f"Face {{ fdp FDP {{ featurePointsCoord Coordinate {{ point [ {pts} ] }} "
        f"textureCoord TextureCoordinate {{ point [ {uv} ] }} useOrthoTexture TRUE }} }}\n"
    )
    return base(), {"scene": str(p)}


def case_check_dct(monkeypatch, **_):
    real = decmod._Decoder.intra_header

    def intra_header(self, info):
        real(self, info)
        raise self.err("coding_type 1 (DCT segment mode) is not supported by this decoder", "dct-unsupported")

    monkeypatch.setattr(decmod._Decoder, "intra_header", intra_header)
    return base(), {}


def case_internal(monkeypatch, **_):
    def boom(*a, **k):
        raise RuntimeError("synthetic checker bug")

    monkeypatch.setattr(checker, "_semantics", boom)
    return base(), {}


def case_emulation(**_):
    # fbaconf's encoding of VREng's eyes.fap at fap_quant 1 written without the encoder's D9
    # prevention: a byte-aligned 0x000001 at byte 132 (tests/data/emulation/PROVENANCE.md)
    return (Path(__file__).parents[1] / "data" / "emulation" / "emulating.fba").read_bytes(), {}


CASES = {
    R.SYNTAX_TOO_SHORT: case_too_short,
    R.SYNTAX_NOT_FACE: case_not_face,
    R.SYNTAX_TRUNCATED: case_truncated,
    R.SYNTAX_MARKER: case_marker,
    R.SYNTAX_OBJECT_MASK: case_object_mask,
    R.SYNTAX_FIRST_PREDICTED: case_first_predicted,
    R.SYNTAX_STUFFING: case_stuffing,
    R.SYNTAX_ARITH_STATE: case_arith_state,
    R.SYNTAX_NO_END_CODE: case_no_end_code,
    R.SYNTAX_TRAILING: case_trailing,
    R.SYNTAX_UNEXPECTED_START_CODE: case_unexpected_start_code,
    R.SYNTAX_OTHER: case_other,
    R.SYNTAX_DCT: case_dct_syntax,
    R.SYNTAX_EMULATION: case_emulation,
    R.SCENE_INTEROP_FDM: case_scene_interop,
    R.SCENE_ILL_CONDITIONED: case_scene_ill_conditioned,
    R.SEM_FRAME_RATE_ZERO: case_frame_rate_zero,
    R.SEM_TIME_CODE_RANGE: case_time_code_range,
    R.SEM_TIME_BACKWARDS: case_time_backwards,
    R.SEM_VISEME_SELECT: case_viseme_select,
    R.SEM_EXPRESSION_SELECT: case_expression_select,
    R.SEM_INTENSITY: case_intensity,
    R.SEM_INTENSITY_D5: case_intensity_d5,
    R.SEM_VALUE_OVERFLOW: case_value_overflow,
    R.SEM_SINGLE_SYMBOL: case_single_symbol,
    R.DECISION_QUANT_NO_LISTS: case_quant_no_lists,
    R.DECISION_UNIDIRECTIONAL_NEGATIVE: case_unidirectional_negative,
    R.DECISION_DEFAULT_ROUNDING: case_default_rounding,
    R.DECISION_NO_FRAME_RATE: case_no_frame_rate,
    R.DECISION_LOOKAHEAD_STUFFING: case_lookahead,
    R.DECISION_MASK_INTERPOLATE: case_mask_interpolate,
    R.DECISION_HIGH_LEVEL_QUANT: case_high_level_quant,
    R.DECISION_PRED_OUTSIDE_INTRA: case_pred_outside_intra,
    R.PROFILE_TOOL: case_profile_tool,
    R.LEVEL_BITRATE: case_bitrate,
    R.LEVEL_FRAME_RATE: case_frame_rate,
    R.LEVEL_FACES: case_faces,
    **{code: _level_scene_case(code) for code in LEVEL_SCENE},
    R.CLAIM_NONE: case_claim_none,
    R.SCENE_UNAVAILABLE: case_scene_unavailable,
    R.SCENE_INVALID: case_scene_invalid,
    R.CHECK_DCT: case_check_dct,
    R.CHECK_INTERNAL: case_internal,
}
# codes that cannot occur alone: a blend out of range only under D5 is one of a stream that depends on D5
# and prediction that pushes a value past 32 bits takes it out of the intra range first
ALSO = {R.SEM_INTENSITY_D5: {R.DECISION_HIGH_LEVEL_QUANT}, R.SEM_VALUE_OVERFLOW: {R.DECISION_PRED_OUTSIDE_INTRA}}
CLI_ONLY = {R.INPUT_UNREADABLE}
TEXT = {c for c in R.CODES if c.startswith("FAP-TEXT-")}  # .fap text: one case each in tests/unit/test_check_text.py


def test_every_code_has_a_case():
    assert set(R.CODES) == set(CASES) | CLI_ONLY | TEXT


@pytest.mark.parametrize("code", sorted(CASES))
def test_case_triggers_exactly_its_code(code, monkeypatch, tmp_path):
    data, kw = CASES[code](monkeypatch=monkeypatch, tmp_path=tmp_path)
    smallest = kw.pop("smallest_claim", False)
    rep = analyse(data, smallest_claim=smallest, **kw)
    got = {d.code for d in rep.diagnostics}
    assert got == {code} | ALSO.get(code, set()), [str(d) for d in rep.diagnostics]
    for d in rep.diagnostics:
        assert d.severity == R.CODES[d.code].severity and d.clause == R.CODES[d.code].clause


def test_input_unreadable_via_cli(tmp_path, capsys):

    rc = main(["check", str(tmp_path / "missing.fba"), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 2 and doc["status"] == "unreadable"
    assert [i["code"] for i in doc["issues"]] == [R.INPUT_UNREADABLE]


# ---------------------------------------------------------------------------- details of some checks
def test_parse_errors_carry_the_offset_where_parsing_stopped():
    data = base()
    at = decode(data).planes[0].marker_offsets[3][0]
    (d,) = check_stream(flip_bit(data, at))
    assert d.code == R.SYNTAX_MARKER and d.location.bit_offset == at and d.location.plane == 0
    assert d.location.byte_offset == at // 8


def test_lookahead_warning_matches_a_real_disagreement(monkeypatch):
    """The D7 reading decodes the stream; a plain 14-bit rewind (S1) reads it differently."""
    data = _lookahead_stream()
    good = decode(data)
    hits = [(n, s, l) for n, s, l in good.planes[0].blocks if lookahead_stuffing(data, s, l) is not None]
    assert [n for n, _, _ in hits] == ["viseme"]

    def s1_finish(self):
        if self.bad_stuffing:
            self.r.pos = self.bad_stuffing[0][1]
            raise self.r.error("stuffing bit after 22 consecutive zeros is not '1'", "stuffing")
        self.r.pos -= arith.LOOKAHEAD
        return self.r.pos - self.start

    monkeypatch.setattr(arith.ArithDecoder, "finish", s1_finish)
    try:
        other = decode(data)
    except BitstreamError:
        return  # S1 rejects the stream
    assert not other.frames.normative_equal(good.frames) or other.planes[0].blocks != good.planes[0].blocks


def test_lookahead_detector_is_silent_on_ordinary_streams():
    for seed in range(3):
        data = make_stream(n=30, faps=range(3, 69), seed=seed)
        assert R.DECISION_LOOKAHEAD_STUFFING not in codes(data)


def test_default_rounding_only_for_fap_63():
    data = make_stream(n=20, faps=[61, 62, 64], ranges="persist", plane_start_codes="none")
    assert codes(data) == set()


def test_profile_tool_from_a_narrower_profile_data_file():
    """A stream tool outside the claimed profile (high-level FAPs) with profile data that
    leaves them out of Simple: the tool check is data-driven."""
    text = resources.files("fbaconf.profiles").joinpath("data", "profiles.toml").read_text("utf-8")
    narrow = parse_profiles(
        text.replace('tools = ["arithmetic", "dct", "high_level_faps"]', 'tools = ["arithmetic", "dct"]'), "narrow"
    )
    f = smooth_frames(10, 30.0, FEW, amplitude=3)
    f.status[:, 0] = SET
    f.high[:, 0] = 3
    data = encode(f, EncoderOptions()).data
    ds = check_stream(data, claim="simple@1", profiles=narrow)
    assert {d.code for d in ds} == {R.PROFILE_TOOL}
    assert ds[0].location.fap == 1 and ds[0].location.plane == 0
    assert codes(data, claim="simple@1") == set()  # real data: Simple includes visemes/expressions


def test_dct_is_a_simple_tool_and_measured_per_frame():
    data = make_stream(n=60, faps=FEW, coding="dct")
    rep = analyse(data, claim="simple@1")
    assert rep.diagnostics == []
    assert rep.summary["tools"] == ["dct"] and rep.summary["frames"] == 60
    assert rep.summary["peak_frame_rate_hz"] == 30


def test_time_code_minutes_and_seconds():
    data = base(time_codes=True)
    h = _header(data)
    for off, n, v in ((h + 23, 6, 60), (h + 30, 6, 61)):
        ds = check_stream(set_bits(data, off, n, v))
        assert [d.code for d in ds] == [R.SEM_TIME_CODE_RANGE]
        assert ds[0].location.bit_offset == h + 18


def test_trailing_after_end_code_counts_bytes():
    (d,) = check_stream(base() + bytes(5))
    assert d.code == R.SYNTAX_TRAILING and "5 byte" in d.message


def test_folding_of_repeated_diagnostics():
    f = smooth_frames(200, 30.0, FEW)
    f.values[:, 2] = -f.values[:, 2]
    ds = check_stream(encode(f, EncoderOptions()).data)
    assert len(ds) == 200
    (issue,) = D.fold(ds, first=3)
    assert issue.count == 200 and len(issue.locations) == 3
    assert [loc.frame for loc in issue.locations] == [0, 1, 2]


def test_select_only_ignore_prefix():
    ds = [D.diag(R.SYNTAX_TRUNCATED, "a"), D.diag(R.DECISION_NO_FRAME_RATE, "b"), D.diag(R.SEM_SINGLE_SYMBOL, "c")]
    assert [d.code for d in D.select(ds, only=["FAP-DECISION-*"])] == [R.DECISION_NO_FRAME_RATE]
    assert [d.code for d in D.select(ds, ignore=["FAP-SYNTAX-003", "FAP-SEM-*"])] == [R.DECISION_NO_FRAME_RATE]


def test_registry_codes_are_well_formed():
    for c, info in R.CODES.items():
        assert re.fullmatch(r"FAP-[A-Z]+-\d{3}", c) and info.description and info.clause
    load_profiles()  # data file valid


# ---------------------------------------------------------------------------- what depends on D5
# Hand computation of the two readings of the blend/intensity alphabet top, 0..floor((63 + floor(q/2))/q)
# (D5) and 0..ceil(63/q), for q = 1..31: 63/q = 6.3 (q 10): 6 vs 7; 5.25 (12): 5 vs 6; 4.2 (15): 4 vs 5;
# 3.32 (19) and 3.15 (20): 3 vs 4; 2.42 .. 2.03 (26..31): 2 vs 3. Everywhere else 63/q is whole or its
# fraction is at least one half (e.g. 15.75 at q 4: 16 and 16; 4.5 at q 14: 5 and 5), so both agree.
D5_DIFFERS = {
    10: (6, 7),
    12: (5, 6),
    15: (4, 5),
    19: (3, 4),
    20: (3, 4),
    26: (2, 3),
    27: (2, 3),
    28: (2, 3),
    29: (2, 3),
    30: (2, 3),
    31: (2, 3),
}


def test_the_quantisers_where_the_d5_readings_differ():
    assert {q for q in range(32) if d5_alphabet_differs(q)} == set(D5_DIFFERS)
    for q, (d5, other) in D5_DIFFERS.items():
        assert (intensity_bound(q), intensity_bound_ceil(q)) == (d5, other)
    assert intensity_bound(0) == intensity_bound_ceil(0) == intensity_bound(1) == 63


@pytest.mark.parametrize("q", [2, 3, 4, 5, 6, 8, 13, 14, 16, 22, 25])
def test_high_level_content_at_agreeing_quantisers_rests_on_no_decision(q):
    assert codes(_high_level_stream([q] * 6)) == set()


def test_high_level_content_across_agreeing_quantiser_changes_rests_on_no_decision():
    assert codes(_high_level_stream([0] * 3 + [4] * 3 + [13] * 3 + [1] * 3 + [22] * 3)) == set()


def test_fap_quant_0_after_a_coarser_one_depends_on_d5():
    """S1 recomputes the blend/intensity alphabet only at intra planes with fap_quant > 0: at 0 it
    keeps the previous plane's (0..16 after fap_quant 4), D5 gives 0..63."""
    ds = check_stream(_high_level_stream([4] * 3 + [0] * 3))
    assert [(d.code, d.location.plane) for d in ds] == [(R.DECISION_HIGH_LEVEL_QUANT, 3)]
    assert "0..16 in S1" in ds[0].message
    assert codes(_high_level_stream([1] * 3 + [0] * 3)) == set()  # fap_quant 1: 0..63 either way


def test_select_and_intensity_errors_name_no_decision():
    """A viseme/expression select outside 0..14/0..6 is an error whatever the D5 reading (the tables'
    sizes); so is a blend outside both readings' ranges."""
    for code in (R.SEM_VISEME_SELECT, R.SEM_EXPRESSION_SELECT, R.SEM_INTENSITY):
        assert "decision" not in R.CODES[code].clause
    assert "decision D5" in R.CODES[R.SEM_INTENSITY_D5].clause
    assert "decision D4" in R.CODES[R.DECISION_PRED_OUTSIDE_INTRA].clause


def test_predicted_values_outside_the_intra_range_are_decoded():
    """The range rule (D4): previous + difference, no check; the warning names FAP, plane and value."""
    data = pred_beyond_intra_range()
    fr = decode(data).frames
    assert fr.values[:, 3].tolist() == [120 + 80 * k for k in range(8)]  # FAP 4: QP 2, +40 levels a plane
    assert fr.values[:, 18].tolist() == [-60 - 30 * k for k in range(8)]  # FAP 19: QP 1, -30 levels
    ds = check_stream(data)
    assert {(d.location.plane, d.location.fap) for d in ds} == {(k, f) for k in range(1, 8) for f in (4, 19)}
