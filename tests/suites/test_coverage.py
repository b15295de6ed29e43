"""The coverage model (conformance/data/coverage.toml) and its extractors."""

from __future__ import annotations

import copy
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import FREE, RETAINED, SET, FapFrames
from fbaconf.cli import main
from fbaconf.conformance import coverage, coverage_scene, coverage_table
from fbaconf.conformance.suite import load_suites
from fbaconf.generators.content import make_content


def test_model_loads_with_unique_ids_and_clauses():
    pts = coverage.load_model()
    ids = [p.id for p in pts]
    assert len(ids) == len(set(ids)) > 250
    assert all(p.clause and p.description for p in pts)
    assert "fap.68" in ids and "viseme.14" in ids and "limit.mesh_vertices@2" in ids
    assert "fap.3.negative" not in ids  # open_jaw is unidirectional: no negative class


def _stream(**opts) -> bytes:
    c = make_content({"frames": 30, "rate": 12.5, "seed": 3, "visemes": True, "expressions": False, "faps": [3, 4, 5]})
    return encode(c, EncoderOptions(**opts)).data


def test_stream_extractor_reads_the_content_not_labels():
    hits = coverage.stream_points(_stream(fap_quant=31, time_codes=True, intra_period=5))
    assert {
        "plane.intra",
        "plane.predicted",
        "fap_quant.31",
        "timecode.present",
        "timecode.nonzero",
        "rate.sixteenths",
        "fap.1",
        "fap.3",
        "mask.type-0",
        "stream.end-code",
    } <= hits
    assert "fap_quant.0" not in hits and "dct.segment" not in hits and "fap.6" not in hits
    hits = coverage.stream_points(_stream(fap_quant=0, coding="dct"))
    assert {"dct.segment", "dct.segment-short", "dct.highlevel"} <= hits


def _frames(values: list[list[int]], status: list[list[int]]) -> FapFrames:
    """Frames of FAPs 3 and 4 (open_jaw, lower_t_midlip: one group) as given, no high-level FAPs."""
    fr = FapFrames.empty(len(values))
    fr.values[:, 2:4] = values
    fr.status[:, 2:4] = status
    return fr


def _group_types(n: int, later: int) -> np.ndarray:
    """No group coded (00) but FAPs 3 and 4's, coded with a mask (01) in the first two frames and
    of type ``later`` after."""
    t = np.zeros((n, tables.NUM_GROUPS), dtype=np.int64)
    g = int(tables.group_of_fap()[2]) - 1
    t[:2, g], t[2:, g] = 1, later
    return t


@pytest.mark.parametrize(
    ("later", "status_later", "set_before", "hit"),
    [
        (1, [SET, RETAINED], True, True),  # 01 leaves out FAP 4, set at frame 0: it keeps its value
        (2, [SET, FREE], True, True),  # 10 leaves it out: FREE — the other answer, so the types differ here
        (1, [SET, FREE], False, False),  # never set: FREE under 01 and 10 alike (D3)
        (0, [RETAINED, RETAINED], True, False),  # 00 leaves out the whole group: held, not one of the two
    ],
)
def test_keep_or_free_is_where_mask_types_01_and_10_decode_differently(later, status_later, set_before, hit):
    first = [SET, SET if set_before else FREE]
    fr = _frames([[10, 20]] * 4, [first] * 2 + [status_later] * 2)
    data = encode(fr, EncoderOptions(intra_at=frozenset({0, 2}), group_types=_group_types(4, later))).data
    assert decode(data).planes[2].group_types[int(tables.group_of_fap()[2]) - 1] == later
    assert ("mask.keep-or-free" in coverage.stream_points(data)) is hit


def test_list_points_read_the_ranges_a_decoder_needs():
    # FAPs 3 and 4 rising 0, 10, .. 60 (fap_quant 1, tight lists): values and differences both in
    # 0..60, so each FAP's I and P lists are min 0, max 1 (bounds 0 and 60, notes §1.4): one
    # alphabet, no min below zero
    fr = _frames([[10 * k, 10 * k] for k in range(7)], [[SET, SET]] * 7)
    hits = coverage.stream_points(encode(fr, EncoderOptions(fap_quant=1)).data)
    assert {"lists.i_min", "lists.p_min"} <= hits
    assert not {"lists.min-below-zero", "lists.i-not-p", "lists.p-not-i"} & hits
    # falling instead: differences down to -10 need P min 1 (bound -60), values stay >= 0 (I min 0)
    fr = _frames([[60 - 10 * k, 10 * k] for k in range(7)], [[SET, SET]] * 7)
    hits = coverage.stream_points(encode(fr, EncoderOptions(fap_quant=1)).data)
    assert {"lists.min-below-zero", "lists.i-not-p", "lists.p-not-i"} <= hits


@pytest.mark.parametrize(
    ("fap", "value", "quant", "hit"),
    [
        (3, 40, 1, True),  # open_jaw: QP 4 (the FAP table), so a nonzero symbol s decodes to 4 s
        (14, 40, 1, False),  # thrust_jaw: QP 1, the step is fap_quant whether the QP is read or not
        (3, 0, 1, False),  # every symbol 0: 0 at any step
        (3, 40, 0, False),  # fap_quant 0: step 1, no QP (notes §3.4)
    ],
)
def test_qp_step_is_where_a_low_level_step_is_more_than_fap_quant(fap, value, quant, hit):
    fr = FapFrames.empty(3)
    fr.values[:, fap - 1] = value
    fr.status[:, fap - 1] = SET
    hits = coverage.stream_points(encode(fr, EncoderOptions(fap_quant=quant)).data)
    assert f"fap.{fap}" in hits  # coded, 0 or not
    assert ("fap_quant.qp-step" in hits) is hit


GRID = Path(__file__).resolve().parents[2] / "conformance" / "suites" / "predictable-l1-core" / "grid-transforms.bt"


@pytest.mark.parametrize(
    ("fap", "value", "status", "driven"),
    [
        # the scene's FaceDefTables (its BT text): FAPs 48 and 50 rotate (fieldId 1), 6 scales (2),
        # 14 translates (3) the node Inner
        (48, 100, SET, {"rotation"}),
        (6, 100, SET, {"scale"}),
        (14, -100, SET, {"translation"}),
        (48, 0, SET, set()),  # set, but at 0: no angle, nothing moves
        (3, 100, SET, set()),  # a FaceDefMesh's FAP, no transform
        (48, 100, FREE, set()),  # a FREE FAP's value is no one's
    ],
)
def test_a_transform_is_driven_where_its_fap_moves_the_model(fap, value, status, driven):
    fr = FapFrames.empty(2)
    fr.values[1, fap - 1] = value
    fr.status[1, fap - 1] = status
    hits = coverage_scene.scene_points(GRID, fr)
    assert {"facedef.transform.rotation", "facedef.transform.scale", "facedef.transform.translation"} <= hits
    assert {h.split(".")[2] for h in hits if h.endswith(".driven")} == driven


@pytest.fixture(scope="module")
def computed(made_once):
    """(case, coverage) of every committed case, computed once per session (it reads every case)
    and shared by the workers that run this module's tests."""

    def make(root):
        (root / "computed.pickle").write_bytes(pickle.dumps(coverage.case_coverages()))

    return pickle.loads((made_once("fbaconf-coverage", make) / "computed.pickle").read_bytes())  # noqa: S301 - this session's own file, written just before


@pytest.fixture(scope="module")
def report(computed):
    return coverage.compute(computed=computed)


def test_every_emitted_point_is_defined(report):
    """The extractors emit no id outside the model's families (typos would hide coverage); the
    generic families (every diagnostic code, a negative value of any FAP) may go beyond the model."""
    rep = report
    assert [k for k in rep["unknown"] if not k.startswith(("diag.", "error.", "fap."))] == []
    assert not [c for c in rep["cases"] if c["problems"]]


def test_committed_suites_cover_every_point(report):
    rep = report
    missing = [p["id"] for p in rep["points"] if not p["cases"]]
    assert missing == [], missing
    text = coverage.format_table(rep)
    assert text.splitlines()[-1] == f"coverage: {rep['total']}/{rep['total']} points"


def test_coverage_verb(capsys, monkeypatch, tmp_path, computed, report):
    """The verb prints the table of what ``coverage.compute`` found (computed once here), and
    ``--write`` writes the stored points."""
    monkeypatch.setattr(coverage, "case_coverages", lambda *a, **k: computed)
    monkeypatch.setattr(coverage_table, "TABLE_PATH", tmp_path / "case-points.json")
    assert main(["suites", "coverage", "--write"]) == 0
    out, err = capsys.readouterr()
    assert out.rstrip().splitlines()[-1] == f"coverage: {report['total']}/{report['total']} points"
    assert f"wrote the points of {len(computed)} case(s)" in err
    written = json.loads((tmp_path / "case-points.json").read_text("utf-8"))["cases"]
    assert {k: set(v["points"]) for k, v in written.items()} == {c.full_id: cc.points for c, cc in computed}


def test_the_stored_points_are_what_a_fresh_computation_gives(tmp_path, computed):
    """``data/case-points.json`` (what certify reads) is byte for byte what ``suites coverage
    --write`` writes now: every committed case, its key, its points. Stale after a change to the
    extractors? Run ``fbaconf suites coverage --write``."""
    fresh, n = coverage_table.write(computed, tmp_path / "case-points.json")
    assert n == len(computed)
    committed = coverage_table.TABLE_PATH.read_text("utf-8")
    assert fresh.read_text("utf-8") == committed, "stale: run `fbaconf suites coverage --write`"
    assert len(json.loads(committed)["cases"]) == len(computed) > 150
    for case, cc in computed:
        assert coverage_table.stored_points(case) == cc.points, case.full_id


def test_a_case_not_as_committed_is_computed_not_looked_up(tmp_path):
    """The key covers the bytes of every input, the case's kind and stages and the model: a changed
    stream, another kind, or a table whose key does not match all fall back to computing."""
    suite = next(s for s in load_suites() if s.name == "simple-l1-core")
    case = next(c for c in suite.cases if c.id == "arith-q1-all-faps")
    assert coverage_table.stored_points(case) is not None  # as committed: looked up
    shutil.copytree(suite.path, tmp_path / suite.name)
    moved = copy.copy(case)
    moved.suite_dir = tmp_path / suite.name
    assert coverage_table.stored_points(moved) == coverage_table.stored_points(case)  # same bytes, same key
    other = next(c for c in suite.cases if c.id == "arith-q31-timecodes")
    (tmp_path / suite.name / case.inputs["fba"]).write_bytes(other.input_path("fba").read_bytes())
    assert coverage_table.stored_points(moved) is None
    got = coverage_table.points_of(moved)
    assert got == coverage.case_points(moved).points
    assert "fap_quant.31" in got and "fap_quant.1" not in got  # the timecodes stream's, not the stored ones
    relabelled = copy.copy(case)
    relabelled.stages = [*case.stages, "vertices"]
    assert coverage_table.stored_points(relabelled) is None
    # a table read: its points are used when the key matches, ignored when it does not
    key = coverage_table.case_key(case)
    table = tmp_path / "t.json"
    for k, expect in ((key, {"planted"}), ("0" * 64, None)):
        table.write_text(
            json.dumps(
                {"format": coverage_table.TABLE_FORMAT, "cases": {case.full_id: {"key": k, "points": ["planted"]}}}
            )
        )
        assert coverage_table.stored_points(case, table) == expect
    table.write_text("{not json")
    assert coverage_table.stored_points(case, table) is None
