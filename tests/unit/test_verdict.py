"""The claim verdict rule (harness/verdict.py) on hand-made result lines: each expected verdict is
read off the rule as docs/harness.md states it, not computed."""

from __future__ import annotations

import pytest

from fbaconf.harness.verdict import claim_verdict


def res(
    cid,
    outcome="Pass",
    *,
    kind="decode",
    tools=("arithmetic",),
    rests_on=(),
    ending="decoded",
    reading=None,
    required=True,
    stages=(),
):
    return {
        "case_id": f"s/{cid}",
        "outcome": outcome,
        "kind": kind,
        "tools": list(tools),
        "rests_on": list(rests_on),
        "ending": ending,
        "reading": reading,
        "required": required,
        "stages": list(stages),
    }


def dct(cid, outcome="Pass", **kw):
    return res(cid, outcome, tools=kw.pop("tools", ("dct",)), rests_on=("D8",), **kw)


BASE = [res("a1"), res("a2", rests_on=("D7",)), res("bad", kind="error", ending="reject")]
DCT_OK = [dct("d1"), dct("d2"), dct("mix", tools=("arithmetic", "dct")), dct("dbad", kind="error", ending="reject")]


def verdict(results, **kw):
    kw.setdefault("strict", False)
    kw.setdefault("speed", None)
    return claim_verdict(results, **kw)


def test_everything_passing_is_a_plain_pass_with_every_tool_verified():
    v = verdict(BASE + DCT_OK)
    assert (v.verdict, v.exit_code, v.unverified, v.differences) == ("PASS", 0, [], [])
    assert {t.state for t in v.tools.values()} == {"verified"}
    assert v.decisions["D8"].state == v.decisions["D7"].state == "verified"


DECLINED = [
    dct("d1", "NotSupported", ending=None),
    dct("d2", "NotSupported", ending=None),
    dct("mix", "NotSupported", ending=None, tools=("arithmetic", "dct")),
    dct("dbad", "NotSupported", kind="error", ending=None),
]
REJECTED = [
    dct("d1", "Fail", ending="reject"),
    dct("d2", "Fail", ending="reject"),
    dct("mix", "Fail", ending="reject", tools=("arithmetic", "dct")),
    dct("dbad", kind="error", ending="reject"),
]
FAKED = [
    dct("d1", "Fail"),
    dct("d2", "Fail"),
    dct("mix", "Fail", tools=("arithmetic", "dct")),
    dct("dbad", kind="error", ending="reject"),
]
PARTLY = [
    dct("d1"),
    dct("d2", "Fail"),
    dct("mix", "Fail", ending="reject", tools=("arithmetic", "dct")),
    dct("dbad", "Fail", kind="error"),
]


@pytest.mark.parametrize(
    "dct_results, state",
    [(DECLINED, "declined"), (REJECTED, "declined"), (FAKED, "unverified"), (PARTLY, "unverified")],
)
def test_an_open_tool_not_decoded_as_fbaconf_does_is_unverified_whatever_the_mix(dct_results, state):
    v = verdict(BASE + dct_results)
    assert (v.verdict, v.exit_code, v.unverified) == ("PASS (unverified: dct)", 0, ["dct"])
    assert v.tools["dct"].state == state and v.decisions["D8"].state == state
    assert v.tools["arithmetic"].state == "verified"  # judged on what is left: "mix" is set aside
    s = verdict(BASE + dct_results, strict=True)
    assert (s.verdict, s.exit_code) == ("FAIL", 1)


def test_a_crash_hang_or_set_up_error_in_an_open_tool_fails():
    for bad in ("Crash", "Timeout", "Error"):
        v = verdict(BASE + [dct("d1", "NotSupported", ending=None), dct("d2", bad)])
        assert v.verdict == "FAIL" and v.unverified == [] and v.tools["dct"].state == "fails"


def test_an_open_tool_decoded_right_must_reject_its_invalid_streams():
    v = verdict(BASE + DCT_OK[:3] + [dct("dbad", "Fail", kind="error")])
    assert v.verdict == "FAIL" and v.tools["dct"].state == "fails"


def test_declining_a_tool_an_open_decision_does_not_cover_fails():
    hl = [
        res("h1", "NotSupported", ending=None, tools=("high_level_faps",)),
        res("h2", "NotSupported", ending=None, tools=("high_level_faps",), rests_on=("D5",)),
    ]
    v = verdict(BASE + hl)
    assert v.verdict == "FAIL" and v.tools["high_level_faps"].state == "declined" and v.unverified == []


def test_a_declared_reading_is_a_provisional_difference_and_nothing_else_is():
    judged = [res("a1"), res("a2", rests_on=("D7",), reading="D7:rewind-14"), res("bad", kind="error", ending="reject")]
    v = verdict(judged, declared=["D7:rewind-14"])
    assert (v.verdict, v.exit_code) == ("PASS (provisional differences: 1)", 0)
    assert v.differences == [{"case_id": "s/a2", "rests_on": ["D7"], "reading": "D7:rewind-14"}]
    assert v.decisions["D7"].state == "differs" and v.decisions["D7"].readings == ["D7:rewind-14"]
    assert verdict(judged, declared=["D7:rewind-14"], strict=True).verdict == "FAIL"
    # a failing case resting on D7, not judged by a declared reading (a rejection, other values): a failure
    for outcome, ending in (("Fail", "reject"), ("Fail", "decoded")):
        v = verdict([res("a1"), res("a2", outcome, rests_on=("D7",), ending=ending)])
        assert v.verdict == "FAIL" and v.differences == [] and v.decisions["D7"].state == "fails"


def test_both_qualifiers_together_and_cases_outside_the_claim_ignored():
    judged = [res("a2", rests_on=("D7",), reading="D7:rewind-14"), res("x", "Crash", required=False)] + DECLINED
    v = verdict(judged, declared=["D7:rewind-14"])
    assert v.verdict == "PASS (unverified: dct; provisional differences: 1)"


def test_speed_is_judged_only_once_every_case_passed():
    slow = [{"operation": "decode", "passed": False}]
    assert verdict(BASE, speed=slow).verdict == "SPEED FAIL" and verdict(BASE, speed=slow).exit_code == 3
    assert verdict(BASE + [res("z", "Fail")], speed=slow).verdict == "FAIL"
    assert verdict(BASE, speed=[{"operation": "decode", "passed": True}]).verdict == "PASS"
