"""Third-party implementations through fbaconf's adapters (docs/third-party.md); each test
of a program skips cleanly when it is not built (it is built outside the repository). The
expected results are what the programs' sources do (the behaviours docs/third-party.md lists,
read from their code): each case named here fails for one of them, and ``fbaconf explain`` names
each behaviour as one cause. Only what is defined is pinned: where a program's behaviour is
undefined (Xface's uninitialised count), only that the case does not pass. The docs' generated
tables are checked against the committed suites without the programs."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from fbaconf.cli import main
from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases

JVM = Path("/usr/lib/jvm")


def _adapter(env: str, how: str, sibling: str | None = None):
    m = os.environ.get(env)
    if m and sibling:
        m = str(Path(m).with_name(sibling))
    if not m or not Path(m).is_file():
        pytest.skip(f"adapter not built ({how}; set {env})")
    a = adapters.resolve(m)
    if hasattr(a, "lab_read_only") and JVM.is_dir():
        a.lab_read_only = [JVM]  # the lab shows the JVM (fbaconf run --sandbox-ro /usr/lib/jvm)
    return a


def _run(a, tmp_path, *ids):
    suites = load_suites(names=["simple-l1-core", "simple-l1-text"])
    cases = [c for s in suites for c in s.cases if c.id in ids]
    assert len(cases) == len(ids)
    return {
        r.case_id.split("/")[-1]: r
        for r in run_cases(a, cases, claim="simple@1", out_dir=tmp_path, jobs=2, progress=False)
    }


def test_greta_player_results_are_the_documented_ones(tmp_path):
    a = _adapter("FBACONF_GRETA_MANIFEST", "examples/third-party/greta/build.sh")
    res = _run(
        a,
        tmp_path,
        "range-extremes",
        "no-frame-rate",
        "header-2-0",
        "viseme-def",
        "wrapped-values",
        "comment-between-frames",
        "frame-repeated",
        "frames-out-of-order",
        "value-out-of-range",
    )
    assert res["range-extremes"].outcome == Outcome.PASS
    assert res["no-frame-rate"].outcome == Outcome.PASS  # the player holds values
    assert res["header-2-0"].outcome == Outcome.FAIL and "got 25 Hz" in res["header-2-0"].message
    assert "FAP 1 viseme" in res["viseme-def"].message  # one integer, not the viseme fields
    assert "rejected" in res["wrapped-values"].message  # lines read in pairs
    assert "frame count: expected 3, got 1" in res["comment-between-frames"].message
    assert "expected -40, got -60" in res["frame-repeated"].message  # frames of one number blended
    assert "expected 120, got 100" in res["frames-out-of-order"].message  # played in number order
    invalid = res["value-out-of-range"]  # no validation: an invalid file read as far as it goes
    assert invalid.outcome == Outcome.FAIL and "without complaint" in invalid.message


def test_greta_parser_alone_holds_nothing(tmp_path):
    a = _adapter("FBACONF_GRETA_MANIFEST", "examples/third-party/greta/build.sh", sibling="greta-parser.toml")
    res = _run(a, tmp_path, "range-extremes", "no-frame-rate")
    assert res["range-extremes"].outcome == Outcome.PASS
    assert res["no-frame-rate"].outcome == Outcome.FAIL and "got none" in res["no-frame-rate"].message


def test_xface_results_are_the_documented_ones(tmp_path):
    a = _adapter("FBACONF_XFACE_MANIFEST", "examples/third-party/xface/build.sh")
    res = _run(
        a,
        tmp_path,
        "range-extremes",
        "rate-fractional",
        "cr-line-ends",
        "lip-pairs",
        "numbered-from-one",
        "viseme-def",
        "comment-between-frames",
        "name-with-space",
        "greta-69-mask-one-word-name",
        "value-out-of-range",
    )
    assert res["range-extremes"].outcome == Outcome.PASS
    assert "got 12 Hz" in res["rate-fractional"].message  # frame rate kept in a short
    assert "got 0" in res["cr-line-ends"].message  # no hold (CR line ends themselves are fine)
    assert "lower_t_lip_lm: expected 0, got -80" in res["lip-pairs"].message  # inner/outer lip coupling
    assert res["numbered-from-one"].outcome == Outcome.CRASH  # frame number at the count
    assert "viseme_def" in res["viseme-def"].message  # read and dropped
    # a comment after the header: the stream reader fails, the file is rejected
    assert res["comment-between-frames"].outcome == Outcome.FAIL and "rejected" in res["comment-between-frames"].message
    # four header tokens: the rate is read from the name, and what follows reads an uninitialised
    # count (undefined behaviour: a rejection or a crash, by build and by run): only that it fails is pinned
    assert res["name-with-space"].outcome in (Outcome.FAIL, Outcome.CRASH)
    one_word = res["greta-69-mask-one-word-name"]  # the 69-entry mask misread, not a rejection
    assert one_word.outcome == Outcome.FAIL and "close_t_l_eyelid: expected 100, got 0" in one_word.message
    assert "without complaint" in res["value-out-of-range"].message  # atof: an invalid file accepted


DOC = Path(__file__).resolve().parents[2] / "docs" / "third-party.md"


def test_the_docs_tables_count_the_committed_suites():
    text = DOC.read_text(encoding="utf-8")
    blocks = re.findall(r"<!-- explain: (\S+): generated.*?-->\n(.*?)<!-- /explain: \1 -->", text, re.S)
    assert {name for name, _ in blocks} == {"xface-fapfile", "greta-player"}
    total = sum(len(s.cases) for s in load_suites())
    for name, body in blocks:
        m = re.search(r"\*\*\S+\*\*: (\d+) cases run \(([^)]*)\); (\d+) causes? explain (\d+) of (\d+) failures", body)
        assert m, f"{name}: no summary line in its block"
        assert int(m.group(1)) == total, (
            f"{name}: the table counts {m.group(1)} cases, the suites hold {total}: run examples/third-party/tables.sh"
        )
        assert sum(int(n) for n in re.findall(r"(\d+) \w+", m.group(2))) == total
        rows = re.findall(r"^\| \d+ \| .*? \| (\d+): ", body, re.M)
        assert len(rows) == int(m.group(3)) and sum(map(int, rows)) == int(m.group(4)) == int(m.group(5))


# what each program's source does (docs/third-party.md), as the cause explain names for it
XFACE_BEHAVIOURS = {
    "content.rate-fractional",  # the rate in a short
    "content.held",  # no hold
    "content.lip-pair",  # adjustFAPs
    "content.frame-past-count",  # rows indexed by frame number, unbounded
    "content.viseme_def",  # read and dropped
    "text.comment",  # a comment only at the start
    "text.name-spaces",  # four header tokens
    "text.mask-69",  # 68 entries and a frame number
    "kind.error",  # atof, no validation
}
GRETA_BEHAVIOURS = {
    "content.rate-not-25",  # the header skipped: 25 Hz
    "content.high-level",  # FAP 1/2 one integer each
    "text.comment",  # lines in pairs, no comments...
    "text.wrapped",  # ... nor wrapped values
    "text.mask-69",  # Greta's own 69-entry form
    "kind.error",  # no validation
    "content.frame-order",  # frames of one number blended, played in number order
}


@pytest.mark.parametrize(
    "env,how,behaviours,ro",
    [
        ("FBACONF_XFACE_MANIFEST", "examples/third-party/xface/build.sh", XFACE_BEHAVIOURS, []),
        ("FBACONF_GRETA_MANIFEST", "examples/third-party/greta/build.sh", GRETA_BEHAVIOURS, ["--sandbox-ro", str(JVM)]),
    ],
)
def test_explain_names_each_behaviour_of_the_program_as_one_cause(env, how, behaviours, ro, tmp_path, capsys):
    a = _adapter(env, how)
    run = tmp_path / "run"
    main(["run", "--decoder", str(a.manifest_path), "-j", "2", "-o", str(run), *(ro if JVM.is_dir() else [])])
    capsys.readouterr()
    assert main(["explain", str(run), "--json", *(ro if JVM.is_dir() else [])]) == 0
    doc = json.loads(capsys.readouterr().out)
    features = {c["feature"] for c in doc["causes"]} - {"undefined-behaviour"}
    assert features == behaviours, doc["headline"]
    assert doc["explained"] == doc["failing"] and doc["runs"] <= doc["bound"]
    for c in doc["causes"]:
        if c["feature"] != "kind.error":  # an invalid input has no variant without its fault
            assert c["confirmed"] or c["feature"] == "undefined-behaviour", c
