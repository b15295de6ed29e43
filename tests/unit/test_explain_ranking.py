"""The parts of ``fbaconf explain`` that run no decoder: the spectrum score (Ochiai's, computed by
hand below), the grouping of failing cases into causes on the committed suites (the failing set is
made here from a coverage point, so the expected cause is known), the ``.fap`` triggers and their
edits (hand-written texts), and the certificate statement's causes."""

from __future__ import annotations

import math
import types

import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.certification.certify import _cause_lines
from fbaconf.conformance.coverage import stream_points
from fbaconf.conformance.coverage_table import points_of
from fbaconf.conformance.suite import load_suites
from fbaconf.explain import causes, spectrum, triggers
from fbaconf.explain.causes import Cause, Explanation, Trial, _variant, explain
from fbaconf.explain.render import markdown, terminal
from fbaconf.harness.results import CaseResult, Outcome, RunRecord


def _view(cid: str, failing: bool, *features: str) -> spectrum.CaseView:
    return spectrum.CaseView(cid, "Fail" if failing else "Pass", failing, not failing, frozenset(features))


def test_ochiai_by_hand():
    vs = [_view("a", True, "x", "y"), _view("b", True, "x"), _view("c", False, "y"), _view("d", False)]
    got = {s.feature: s.ochiai for s in spectrum.scores(vs)}
    # x: in both failing cases, no passing one: 2 / sqrt(2 * 2); y: 1 failing, 1 passing: 1 / sqrt(2 * 2)
    assert got == {"x": pytest.approx(1.0), "y": pytest.approx(0.5)}
    assert spectrum.aliases(vs, "x") == [] and spectrum.aliases([*vs, _view("e", False, "z")], "z") == []


def test_features_always_together_are_aliases():
    vs = [_view("a", True, "p", "q"), _view("b", False, "p", "q", "r"), _view("c", False, "r")]
    assert spectrum.aliases(vs, "p") == ["q"] and spectrum.aliases(vs, "r") == []


def _record(failing: set[str], cases: dict) -> RunRecord:
    results = [
        CaseResult(
            case_id=cid,
            suite=c.suite,
            claim=c.claim,
            outcome=Outcome.FAIL if cid in failing else Outcome.PASS,
            kind=c.kind.value,
        )
        for cid, c in cases.items()
    ]
    return RunRecord(decoder={"name": "d", "inputs": ["fba"]}, claim="simple@2", suites=[], system={}, results=results)


@pytest.fixture(scope="module")
def core_cases():
    return {c.full_id: c for s in load_suites(names=["simple-l1-core"]) for c in s.cases}


@pytest.mark.parametrize("point", ["skip.chain", "rate.offset", "timecode.nonzero"])
def test_the_cases_of_one_point_failing_are_one_cause_naming_it(point, core_cases):
    failing = {cid for cid, c in core_cases.items() if point in points_of(c)}
    assert failing, point
    ex = explain(_record(failing, core_cases), core_cases)
    top = ex.causes[0]
    assert point in (top.feature, *top.aliases) and set(top.cases) == failing
    assert ex.explained == ex.failing == len(failing) and ex.runs == 0


def test_a_run_without_failures_says_so_in_one_line(core_cases):
    ex = explain(_record(set(), core_cases), core_cases)
    assert ex.causes == [] and terminal(ex).count("\n") == 0 and "no failures" in terminal(ex)


def test_a_failing_certificate_names_its_top_causes(core_cases):
    failing = {cid for cid, c in core_cases.items() if "skip.chain" in points_of(c)}
    text = _cause_lines(_record(failing, core_cases), list(core_cases.values()), "FAIL")
    assert "## Why it fails" in text and "skip.chain" in text
    assert _cause_lines(_record(failing, core_cases), list(core_cases.values()), "PASS") == ""


CRLF = "# made by hand\r\n2.1 two words 12.5 2\r\n" + " ".join(["0", "0", "1"] + ["0"] * 65) + "\r\n0 5\r\n"


def test_text_triggers_and_their_edits():
    data = CRLF.encode()
    assert triggers.text_features(data) >= {"text.crlf", "text.comment", "text.name-spaces", "content.rate-fractional"}
    no_crlf = triggers.text_variant(data, "text.crlf")
    assert no_crlf == CRLF.replace("\r\n", "\n")
    no_comment = triggers.text_variant(data, "text.comment")
    assert no_comment is not None and "#" not in no_comment and no_comment.startswith("2.1 two words")
    header = triggers.text_variant(data, "text.name-spaces")
    assert header is not None and header.splitlines()[1] == "2.1 two_words 12.5 2"
    rate = triggers.text_variant(data, "content.rate-fractional")
    assert rate is not None and read_fap_text(rate)[1].frame_rate == 25.0
    assert "content.rate-fractional" not in triggers.text_features(rate.encode())


@settings(max_examples=40, deadline=None)
@given(
    numbers=st.lists(st.integers(0, 50), min_size=1, max_size=6),
    rate=st.sampled_from([25.0, 12.5, 30.0]),
)
def test_each_content_edit_takes_its_trigger_out(numbers, rate):
    rows = [f"{' '.join(['0', '0', '1'] + ['0'] * 65)}\n{n} {i}" for i, n in enumerate(numbers)]
    rate_s = str(int(rate)) if rate.is_integer() else str(rate)
    text = f"2.1 p {rate_s} {len(numbers)}\n" + "\n".join(rows) + "\n"
    data = text.encode()
    present = triggers.text_features(data)
    for t in triggers.TEXT_TRIGGERS:
        if t.id in present and not t.form:
            edited = triggers.text_variant(data, t.id)
            assert edited is not None and t.id not in triggers.text_features(edited.encode()), t.id
    fr = read_fap_text(text)[0]
    assert ("content.frame-order" in present) == bool(any(b <= a for a, b in zip(numbers, numbers[1:])))
    assert ("content.rate-fractional" in present) == (not math.isclose(fr.frame_rate, round(fr.frame_rate)))


def test_a_stream_edit_that_leaves_its_point_in_makes_no_variant(core_cases):
    # every stream starts with an intra plane (D2) and the edit for a coding point re-encodes the
    # stream: a variant "without plane.intra" would still have one, and a decoder passing it
    # would confirm plane.intra for what the re-encoding took out beside it (a quantiser, a skip)
    case = next(c for c in core_cases.values() if "skip.chain" in points_of(c))
    assert _variant(case, "plane.intra", ["fba"]) is None
    assert _variant(case, "rate.integer", ["fba"]) is None or "rate.integer" not in points_of(case)
    v = _variant(case, "skip.chain", ["fba"])
    assert v is not None and v.key == "fba"
    assert "skip.chain" not in stream_points(v.data) and "plane.intra" in stream_points(v.data)
    assert "skip.chain" in v.gone and "plane.intra" not in v.gone


def test_a_list_edit_re_encodes_under_the_default_ranges(core_cases):
    # arith-q1-all-faps sends tight lists in its intra plane and its values fit the default ranges
    # (the FAP table's): re-encoded under them it needs no list (lists.none)
    case = core_cases["simple-l1-core/arith-q1-all-faps"]
    assert "lists.i_max" in points_of(case)
    v = _variant(case, "lists.i_max", ["fba"])
    assert v is not None
    points = stream_points(v.data)
    assert "lists.none" in points and not any(p.startswith("lists.i_") for p in points), v.edit
    assert {"lists.i_max", "lists.i_min"} <= v.gone


def test_a_confirming_variant_names_what_else_it_took_out(core_cases):
    # the edit for a high-level point drops FAPs 1 and 2: every point of theirs goes with it, so a
    # decoder that passes the variant has not shown that init_face, rather than FAP 1, failed it
    case = core_cases["simple-l1-core/high-level-held"]
    assert "highlevel.init_face" in points_of(case)
    v = _variant(case, "highlevel.init_face", ["fba"])
    assert v is not None and {"highlevel.init_face", "fap.1", "fap.2"} <= v.gone
    trial = Trial("highlevel.init_face", case.full_id, v.edit, "Pass", True, also=["fap.1", "fap.2"])
    cause = Cause("highlevel.init_face", "init_face set", "", "trigger", [case.full_id], confirmed=trial)
    ex = Explanation("d", "simple@1", 1, 1, [cause])
    assert "the variant also lacks: fap.1, fap.2" in terminal(ex)
    assert "(also without `fap.1`, `fap.2`)" in markdown(ex, {"Fail": 1})


def _scores(*names: str) -> list[spectrum.Score]:
    return [spectrum.Score(n, 1.0 - i / 10, 1, 0, 1) for i, n in enumerate(names)]


@pytest.mark.parametrize(
    ("first_variant", "chosen", "also"),
    [
        (None, "a", ["b"]),  # no edit takes a out alone; b's passing variant lacks a too: a, as ranked
        (False, "b", ["a"]),  # the decoder failed without a: the passing variant confirms b
    ],
)
def test_a_passing_variant_that_also_lacks_a_better_candidate_confirms_that_one(
    monkeypatch, first_variant, chosen, also
):
    vs = [_view("c1", True, "a", "b"), _view("c2", False)]
    runner = types.SimpleNamespace(runs=0, left=10, budget=types.SimpleNamespace(per_cause=6))

    def trial(runner_, case, feature, features, keep):
        if feature == "a":
            return None if first_variant is None else Trial("a", "c1", "edit a", "Fail", False)
        return Trial("b", "c1", "edit b", "Pass", True, also=["a"])

    monkeypatch.setattr(causes, "_try", trial)
    cand, confirmed, _tried = causes._choose(_scores("a", "b"), vs, {"c1"}, {"c1": None}, runner, None)
    assert cand.feature == chosen and confirmed is not None and confirmed.feature == chosen
    assert confirmed.also == also


def test_a_rewrite_whose_control_fails_does_not_name_the_forms_it_normalised():
    # comments-crlf holds values (content.held) in a text with comments, CRLF line ends and a name
    # with spaces; the edit for held values rewrites the text through fbaconf's writer, which
    # normalises all three. The variant passes and the control (the rewrite alone) fails: the
    # forms are cleared, so the confirmation names none of them beside held values
    (case,) = [c for s in load_suites(names=["simple-l1-text"]) for c in s.cases if c.id == "comments-crlf"]
    features = frozenset(triggers.text_features(case.input_path("fap").read_bytes()))
    assert {"content.held", "text.comment", "text.crlf", "text.name-spaces"} <= features

    class Runner:
        left = 10
        adapter = types.SimpleNamespace(inputs=["fap"])

        def variant(self, case_, key, data, label):
            ok = label != "control"
            return types.SimpleNamespace(outcome=Outcome.PASS if ok else Outcome.FAIL), None

    t = causes._try(Runner(), case, "content.held", features, None)
    assert t is not None and t.confirmed and t.control == "Fail"
    assert not {"text.comment", "text.crlf", "text.name-spaces"} & set(t.also)
