"""Baselines (harness/baseline.py): what ``--write-baseline`` records and keeps, how a file is
checked, and how results are classified against it. The expected files are written out by hand
below (the format of docs/harness.md, "Gating a project's CI")."""

from __future__ import annotations

import pytest

from fbaconf.harness import baseline as bl
from fbaconf.harness.results import CaseResult, Outcome, StageResult


def res(cid: str, outcome: Outcome, *, required: bool = True, fap: int | None = None, **kw) -> CaseResult:
    stages = []
    if fap is not None:
        stages = [
            StageResult(
                "faps", Outcome.FAIL, "FAP differs", first_difference={"frame": 0, "fap": fap, "expected": 1, "got": 2}
            )
        ]
    return CaseResult(
        case_id=cid, suite=cid.split("/")[0], claim="simple@1", outcome=outcome, required=required, stages=stages, **kw
    )


def run_results() -> list[CaseResult]:
    return [
        res("s/passes", Outcome.PASS),
        res("s/wrong-fap", Outcome.FAIL, fap=31),
        res("s/no-multi", Outcome.NOT_SUPPORTED, message="the decoder has no decode_multi command"),
        res("s/optional", Outcome.NOT_SUPPORTED, required=False),
        res("s/optional-fail", Outcome.FAIL, required=False, fap=3),
        res("s/segv", Outcome.CRASH, signal="SIGSEGV"),
        res("s/hang", Outcome.TIMEOUT),
    ]


def test_write_records_every_required_case_that_did_not_pass(tmp_path):
    f = tmp_path / "b.txt"
    rep = bl.write(run_results(), f)
    entries = [ln for ln in f.read_text().splitlines() if not ln.startswith("#")]
    assert entries == [
        "s/hang,Timeout",
        "s/no-multi,NotSupported",
        "s/segv,Crash,crash:SIGSEGV",
        "s/wrong-fap,Fail,faps:31",
    ]
    assert sorted(rep.added) == ["s/hang", "s/no-multi", "s/segv", "s/wrong-fap"]
    # read back, the unchanged results are all known: nothing new, the run passes
    again = run_results()
    s = bl.classify(again, bl.load(f))
    assert s.line() == "0 new, 4 known, 0 fixed, 0 flaky" and s.failing() == []
    # and writing again changes nothing
    before = f.read_text()
    rep = bl.write(again, f)
    assert f.read_text() == before and rep.added == rep.updated == rep.removed == [] and rep.kept == 4


HAND = """\
# acme's known problems
s/wrong-fap,Fail   # accepts any Fail
s/no-multi,NotSupported   # multi-face output later
s/hang,Flake   # slow runners
s/segv,Crash,crash:SIGBUS   # was a bus error
s/passes,Fail,faps:2   # fixed since
other/not-run,Crash   # a case this run did not run

"""


def test_write_keeps_hand_written_lines_comments_and_flakes(tmp_path):
    f = tmp_path / "b.txt"
    f.write_text(HAND)
    rep = bl.write(run_results(), f)
    assert (
        f.read_text()
        == """\
# acme's known problems
s/wrong-fap,Fail   # accepts any Fail
s/no-multi,NotSupported   # multi-face output later
s/hang,Flake   # slow runners
s/segv,Crash,crash:SIGSEGV  # was a bus error
other/not-run,Crash   # a case this run did not run

"""
    )
    assert rep.updated == ["s/segv"] and rep.removed == ["s/passes"] and rep.added == [] and rep.kept == 4
    assert "1 rewritten" in rep.line() and "1 removed (passing now): s/passes" in rep.line()


def test_a_case_that_passed_on_a_rerun_is_written_as_a_flake(tmp_path):
    r = res("s/sometimes", Outcome.FAIL, fap=4, baseline="flake", message=f"{bl.RETRY_PASSED} 1; first run: x")
    f = tmp_path / "b.txt"
    bl.write([r], f)
    assert f.read_text().splitlines()[-1] == "s/sometimes,Flake"


@pytest.mark.parametrize(
    "text,words",
    [
        ("s/a,Failed,faps:3\n", "line 1: expected 'suite/case,Outcome[,signature]'"),
        ("s/a,Failed\n", "(did you mean Fail?)"),
        ("just-a-case\n", "line 1"),
        ("# c\ns/a,Fail\n\ns/a,Flake\n", "line 4: s/a is listed again (first on line 2)"),
    ],
)
def test_a_malformed_baseline_names_its_line(tmp_path, text, words):
    f = tmp_path / "b.txt"
    f.write_text(text)
    with pytest.raises(bl.BaselineError) as e:
        bl.load(f)
    assert words in str(e.value) and str(f) in str(e.value)


def test_write_target_is_checked_before_the_run(tmp_path):
    with pytest.raises(bl.BaselineError, match="does not exist"):
        bl.check_writable(tmp_path / "no-such-folder" / "b.txt")
    bad = tmp_path / "b.txt"
    bad.write_text("s/a,Sometimes\n")
    with pytest.raises(bl.BaselineError, match="line 1"):
        bl.check_writable(bad)
    bl.check_writable(tmp_path / "new.txt")  # a new file in an existing folder: fine


def test_classification_tags_what_fails_the_run():
    rs = run_results()
    known = {
        "s/wrong-fap": bl.Entry("Fail", "faps:30"),
        "s/optional-fail": bl.Entry("Fail", "faps:9"),
        "s/passes": bl.Entry("Crash"),
    }
    s = bl.classify(rs, known)
    by = {r.case_id: r.baseline for r in rs}
    # a second bug in a listed case is new; a case outside the claim is never new
    assert (
        by["s/wrong-fap"] == "new"
        and "fails differently from the baseline (Fail,faps:30 -> Fail,faps:31)" in rs[1].message
    )
    assert by["s/optional-fail"] is None and by["s/optional"] is None
    assert by["s/passes"] == "fixed" and by["s/no-multi"] == "new"
    assert s.line() == "4 new, 0 known, 1 fixed, 0 flaky"
    # without a baseline nothing is tagged (every failure fails the run anyway)
    rs = run_results()
    assert bl.classify(rs).line() == "4 new, 0 known, 0 fixed, 0 flaky"
    assert all(r.baseline is None for r in rs)


def test_signatures_hold_no_addresses_nor_comment_signs():
    a = res("s/a", Outcome.CRASH, crash_kind="UndefinedBehaviorSanitizer: load of address 0x7ffd1234 # x")
    assert bl.signature(a) == "crash:UndefinedBehaviorSanitizer: load of address 0x? x"
    assert bl.entry_for(res("s/b", Outcome.TIMEOUT)).text() == "Timeout"
