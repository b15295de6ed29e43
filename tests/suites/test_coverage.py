"""The coverage model (conformance/data/coverage.toml) and its extractors."""
from __future__ import annotations

import pytest

from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.cli import main
from fbaconf.conformance import coverage
from fbaconf.generators.content import make_content


def test_model_loads_with_unique_ids_and_clauses():
    pts = coverage.load_model()
    ids = [p.id for p in pts]
    assert len(ids) == len(set(ids)) > 250
    assert all(p.clause and p.description for p in pts)
    assert "fap.68" in ids and "viseme.14" in ids and "limit.mesh_vertices@2" in ids
    assert "fap.3.negative" not in ids  # open_jaw is unidirectional: no negative class


def _stream(**opts) -> bytes:
    c = make_content({"frames": 30, "rate": 12.5, "seed": 3, "visemes": True, "expressions": False,
                      "faps": [3, 4, 5]})
    return encode(c, EncoderOptions(**opts)).data


def test_stream_extractor_reads_the_content_not_labels():
    hits = coverage.stream_points(_stream(fap_quant=31, time_codes=True, intra_period=5))
    assert {"plane.intra", "plane.predicted", "fap_quant.31", "timecode.present", "timecode.nonzero",
            "rate.sixteenths", "fap.1", "fap.3", "mask.type-0", "stream.end-code"} <= hits
    assert "fap_quant.0" not in hits and "dct.segment" not in hits and "fap.6" not in hits
    hits = coverage.stream_points(_stream(fap_quant=0, coding="dct"))
    assert {"dct.segment", "dct.segment-short", "dct.highlevel"} <= hits


@pytest.fixture(scope="module")
def report():
    """The coverage of the committed suites, computed once for the module (it reads every case)."""
    return coverage.compute()


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


def test_coverage_verb(capsys, monkeypatch, report):
    """The verb prints the table of what ``coverage.compute`` found (computed once here)."""
    monkeypatch.setattr(coverage, "compute", lambda *a, **k: report)
    assert main(["suites", "coverage"]) == 0
    out = capsys.readouterr().out
    assert out.rstrip().splitlines()[-1] == f"coverage: {report['total']}/{report['total']} points"
