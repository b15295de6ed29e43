"""`fbaconf check` on the command line: exit codes, text and JSON output, the JSON schema,
--max-issues / --only / --ignore / --smallest-claim, and the generated catalogue."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import jsonschema
import pytest

from fbaconf import rules as R
from fbaconf.bitstreams.bitedit import flip_bit
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.cli import main
from fbaconf.profiles import catalogue
from fbaconf.profiles.sample_streams import make_stream, smooth_frames

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def schema():
    text = resources.files("fbaconf.profiles").joinpath("data", "check-report.schema.json").read_text("utf-8")
    s = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(s)
    return s


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("streams")
    clean = make_stream(n=30, faps=range(3, 40))
    f = smooth_frames(60, 30.0, range(3, 40))
    f.values[:, 2] = -f.values[:, 2]
    warn = encode(f, EncoderOptions()).data
    at = decode(clean).planes[0].marker_offsets[0][0]
    out = {
        "clean": clean,
        "warn": warn,
        "broken": flip_bit(clean, at),
        "notface": b"hello world",
        "heavy": make_stream(n=60, rate=30.0, faps=range(3, 69), intra_period=10),
    }
    paths = {}
    for k, v in out.items():
        p = d / f"{k}.fba"
        p.write_bytes(v)
        paths[k] = str(p)
    paths["missing"] = str(d / "missing.fba")
    return paths


def run(capsys, *args):
    rc = main(["check", *args])
    return rc, capsys.readouterr().out


@pytest.mark.parametrize("name,rc", [("clean", 0), ("warn", 0), ("broken", 1), ("notface", 2), ("missing", 2)])
def test_exit_codes_and_schema(files, schema, capsys, name, rc):
    got, out = run(capsys, files[name], "--json")
    assert got == rc
    doc = json.loads(out)
    jsonschema.validate(doc, schema)
    assert doc["exit_code"] == rc
    got_text, text = run(capsys, files[name])
    assert got_text == rc and text.strip()


def test_json_issue_content(files, schema, capsys):
    rc, out = run(capsys, files["warn"], "--json", "--locations", "2")
    doc = json.loads(out)
    (issue,) = doc["issues"]
    assert issue["code"] == R.DECISION_UNIDIRECTIONAL_NEGATIVE and issue["severity"] == "warning"
    assert issue["count"] == 60 and len(issue["locations"]) == 2 and issue["omitted_locations"] == 58
    loc = issue["locations"][0]
    assert loc["fap"] == 3 and loc["plane"] == 0 and loc["byte_offset"] * 8 + loc["bit"] == loc["bit_offset"]
    assert doc["counts"] == {"error": 0, "warning": 60, "info": 0}


def test_claim_and_smallest_claim(files, schema, capsys):
    rc, out = run(capsys, files["heavy"], "--claim", "simple@1", "--json", "--smallest-claim")
    doc = json.loads(out)
    jsonschema.validate(doc, schema)
    assert rc == 1 and doc["claim"] == "simple@1" and doc["smallest_claim"] == "simple@2"
    assert [i["code"] for i in doc["issues"]] == [R.LEVEL_BITRATE]
    limits = {row["limit"]: row for row in doc["summary"]["limits"]}
    assert limits["bitrate"]["ok"] is False and limits["bitrate"]["provenance"] == "provisional"
    assert limits["coded_frame_rate"]["measured"] == 30 and limits["coded_frame_rate"]["ok"] is True
    assert limits["decode_rate"]["measured"] is None and "fit_nodes" not in limits
    rc, out = run(capsys, files["heavy"], "--claim", "simple@2")
    assert rc == 0 and "clean" in out
    rc, out = run(capsys, files["clean"], "--smallest-claim")
    assert rc == 0 and "smallest claim: simple@1" in out


def test_bad_claim_is_a_usage_error(files, capsys):
    assert main(["check", files["clean"], "--claim", "simple@9"]) == 2


def test_only_ignore_max_issues(files, schema, capsys):
    rc, out = run(capsys, files["warn"], "--json", "--ignore", "FAP-DECISION-*")
    doc = json.loads(out)
    assert rc == 0 and doc["issues"] == [] and doc["config"]["ignore"] == ["FAP-DECISION-*"]
    rc, out = run(capsys, files["broken"], "--json", "--ignore", R.SYNTAX_MARKER)
    assert rc == 0 and json.loads(out)["status"] == "clean"
    rc, out = run(capsys, files["warn"], "--json", "--only", R.SYNTAX_MARKER)
    assert json.loads(out)["issues"] == []
    rc, out = run(capsys, files["warn"], "--json", "--max-issues", "7")
    doc = json.loads(out)
    jsonschema.validate(doc, schema)
    assert doc["truncated"] and doc["issues"][0]["count"] == 7 and doc["counts"]["warning"] == 60


def test_text_report_folds(files, capsys):
    rc, out = run(capsys, files["warn"])
    assert "FAP-DECISION-002 (x60)" in out and "... and 55 more" in out and "clause:" in out


def test_catalogue_document_is_current():
    committed = (ROOT / "docs" / "ISSUES.md").read_text("utf-8")
    assert committed == catalogue.generate(), "regenerate: python -m fbaconf.profiles.catalogue --write docs/ISSUES.md"


def test_catalogue_lists_every_code_with_clause():
    text = catalogue.generate()
    for code, info in R.CODES.items():
        line = next(ln for ln in text.splitlines() if ln.startswith(f"| `{code}` |"))
        assert info.severity in line and info.clause.replace("|", "\\|") in line
