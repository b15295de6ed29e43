"""The claim verdict a careful certifier would sign (harness/verdict.py, docs/harness.md
"Provisional requirements"): honesty never loses to a lie, a provisional decision excuses only
what a declared other reading gives, and every real bug fails the claim.

Decoders here are the in-process reference with one behaviour changed, each written from a one-line
description (a tool declined, a tool faked, another reading followed, a plausible bug), run through
the session ``run`` and ``certify`` share (``execute``: the claim's cases, the verdict). The
verdict is the one ``certify`` writes and ``certify verify`` re-derives (tests/attacks/test_package.py).
Readings are switched process-wide, so every run here is sequential (``jobs=1``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from fbaconf.bitstreams import readings
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.harness.adapters import Job
from fbaconf.harness.refadapter import ReferenceAdapter
from fbaconf.harness.results import Outcome
from fbaconf.harness.selection import select_cases
from fbaconf.harness.session import RunOptions, execute
from fbaconf.harness.verdict import claim_verdict
from fbaconf.reference.pipeline import reference_outputs

SIMPLE_2 = ["simple-l1-core", "simple-l1-error", "simple-l1-stress", "simple-l1-regression", "simple-l2-stress"]
ALL_TOOLS_BUT_DCT = ["arithmetic", "high_level_faps"]


def adapter(cls=ReferenceAdapter, name: str = "dec", *, tools=None, declared=()):
    a = cls()
    a.name, a.claims, a.tools, a.readings = name, ["simple@2"], tools, tuple(declared)
    a.inputs, a.outputs, a.faps_format = ["fba"], ["faps"], "npz"
    return a


def certify_like(a, tmp_path: Path, *, strict: bool = False, suites=SIMPLE_2, globs=()):
    """The claim simple@2 through the session certify runs (its required cases, no speed)."""
    ss = load_suites(names=list(suites))
    cases = select_cases(ss, "simple@2", [], list(globs), only_required=True, adapter=a)
    return execute(
        a,
        "simple@2",
        cases,
        ss,
        tmp_path / f"run-{a.name}-{strict}",
        RunOptions(jobs=1, speed=False, strict=strict, progress=False),
    )


def by_id(record):
    return {r.case_id: r for r in record.results}


def _uses_dct(path: Path) -> bool:
    try:
        return any(p.coding_type == 1 for p in decode(Path(path).read_bytes()).planes)
    except FbaconfInputError:
        return False


class RejectsDct(ReferenceAdapter):
    """Declares the DCT tool but implements none of it: every stream with a DCT plane is "invalid"."""

    def run(self, job: Job) -> None:
        if any(_uses_dct(Path(p)) for p in [job.path("input"), *job.faces] if p is not None):
            raise FbaconfInputError("DCT segment mode: invalid stream", rule="invalid-vlc")
        super().run(job)


class FollowsRewind14(ReferenceAdapter):
    """Decodes by S1's 14-bit rewind at every arithmetic block end (the other reading of D7)."""

    def run(self, job: Job) -> None:
        with readings.using(readings.REWIND_14):
            super().run(job)


class RejectsD7(ReferenceAdapter):
    """The reference, except that it rejects every stream whose result rests on D7 (a decoder that
    finds those streams "invalid")."""

    rejected: set = set()

    def run(self, job: Job) -> None:
        if Path(job.path("input")).name in self.rejected:
            raise FbaconfInputError("stuffing error", rule="stuffing")
        super().run(job)


# ------------------------------------------------------------------ a tool declined, a tool faked


@pytest.fixture(scope="module")
def dct_verdicts(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dct")
    decline = adapter(name="declines-dct", tools=ALL_TOOLS_BUT_DCT)
    reject = adapter(RejectsDct, name="rejects-dct")
    out = {}
    for a in (decline, reject):
        out[a.name] = certify_like(a, tmp)
    out["declines-dct-strict"] = certify_like(decline, tmp, strict=True)  # the session's --strict
    out["rejects-dct-strict"] = claim_verdict(
        [r.to_json() for r in out["rejects-dct"].results], strict=True, speed=None
    )  # the same rule on the same results
    out["reference"] = certify_like(adapter(name="reference"), tmp)
    return out


def test_declining_dct_and_faking_it_get_the_same_verdict_and_neither_a_plain_pass(dct_verdicts):
    d, r = dct_verdicts["declines-dct"], dct_verdicts["rejects-dct"]
    assert d.verdict["verdict"] == r.verdict["verdict"] == "PASS (unverified: dct)"
    assert d.exit_code == r.exit_code == 0
    assert d.verdict["tools"]["dct"]["state"] == r.verdict["tools"]["dct"]["state"] == "declined"
    assert d.verdict["decisions"]["D8"]["state"] == "declined"
    # the faker's clean "reject" of the invalid DCT stream earns it nothing the honest one lacks
    assert d.verdict["unverified"] == r.verdict["unverified"] == ["dct"]
    assert d.provisional_differences == r.provisional_differences == []


def test_strict_fails_both_and_the_reference_passes(dct_verdicts):
    assert dct_verdicts["declines-dct-strict"].verdict["verdict"] == "FAIL"
    assert dct_verdicts["rejects-dct-strict"].verdict == "FAIL"
    assert dct_verdicts["declines-dct-strict"].exit_code == dct_verdicts["rejects-dct-strict"].exit_code == 1
    ref = dct_verdicts["reference"]
    assert ref.verdict["verdict"] == "PASS" and ref.exit_code == 0
    assert {t["state"] for t in ref.verdict["tools"].values()} == {"verified"}


class OffOnOneDctStream(ReferenceAdapter):
    """Decodes DCT streams, ``dct-skips`` wrongly: ``how`` is "value" (one value off) or "reject"."""

    how = "value"

    def run(self, job: Job) -> None:
        if Path(job.path("input")).name == "dct-skips.fba" and self.how == "reject":
            raise FbaconfInputError("invalid DCT segment", rule="invalid-vlc")
        super().run(job)
        if Path(job.path("input")).name == "dct-skips.fba":
            f = FapFrames.load_npz(job.path("faps_out"))
            f.values[-1, 2] += 1
            f.save_npz(job.path("faps_out"))


def test_an_open_decision_sets_its_tool_aside_as_a_whole_whatever_the_mix(tmp_path):
    """D8 has no known other reading: a DCT decoder that decodes all but one stream as fbaconf does —
    the last one to other values, or rejected — may hold other tables or a bug; nothing tells them
    apart, so the tool is unverified (as for the decliner), never excused case by case."""
    for how in ("value", "reject"):
        cls = type(f"Off_{how}", (OffOnOneDctStream,), {"how": how})
        rec = certify_like(adapter(cls, name=f"dct-off-{how}"), tmp_path, suites=["simple-l1-core"])
        assert rec.verdict["verdict"] == "PASS (unverified: dct)", (how, rec.verdict["tools"]["dct"])
        assert rec.verdict["tools"]["dct"]["state"] == "unverified" and rec.provisional_differences == []
        assert by_id(rec)["simple-l1-core/dct-skips"].outcome == Outcome.FAIL  # reported as what it is


def test_a_crash_on_a_stream_of_an_open_tool_fails_the_claim(tmp_path):
    class CrashesOnDct(ReferenceAdapter):
        def run(self, job: Job) -> None:
            if _uses_dct(job.path("input")):
                raise IndexError("segment table")  # an uncaught exception: a crash
            super().run(job)

    rec = certify_like(adapter(CrashesOnDct, name="dct-crash"), tmp_path, suites=["simple-l1-core"])
    assert rec.verdict["verdict"] == "FAIL" and rec.verdict["tools"]["dct"]["state"] == "fails"
    assert rec.verdict["unverified"] == []


def test_declining_a_tool_whose_cases_are_not_provisional_fails(tmp_path):
    rec = certify_like(adapter(name="no-high-level", tools=["arithmetic", "dct"]), tmp_path, suites=["simple-l1-core"])
    assert rec.verdict["verdict"] == "FAIL" and rec.exit_code == 1
    assert rec.verdict["tools"]["high_level_faps"]["state"] == "declined"


# ------------------------------------------------------------------ another reading, declared or not


@pytest.fixture(scope="module")
def d7_runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("d7")
    globs = ["*lookahead*", "arith-q1-all-faps", "dct-q4"]
    return {
        "declared": certify_like(
            adapter(FollowsRewind14, name="d7", declared=[readings.REWIND_14]),
            tmp,
            suites=["simple-l1-core"],
            globs=globs,
        ),
        "undeclared": certify_like(
            adapter(FollowsRewind14, name="d7-undeclared"), tmp, suites=["simple-l1-core"], globs=globs
        ),
        "declared-not-followed": certify_like(
            adapter(name="says-d7", declared=[readings.REWIND_14]), tmp, suites=["simple-l1-core"], globs=globs
        ),
    }


def test_a_declared_reading_is_judged_by_what_it_gives(d7_runs):
    rec = d7_runs["declared"]
    d7 = [r for r in rec.results if "D7" in r.rests_on]
    assert len(d7) == 29  # every case S1's rewind changes (golden/<suite>/<case>/readings/D7-rewind-14/)
    assert all(r.outcome == Outcome.PASS and r.reading == readings.REWIND_14 for r in d7), [
        (r.case_id, r.message) for r in d7 if r.outcome != Outcome.PASS
    ][:3]
    assert rec.verdict["verdict"] == "PASS (provisional differences: 29)"
    assert rec.verdict["decisions"]["D7"]["state"] == "differs"
    assert by_id(rec)["simple-l1-core/arith-q1-all-faps"].reading is None  # a case no reading changes


def test_the_same_decoder_undeclared_fails_and_is_told_which_reading_it_follows(d7_runs):
    rec = d7_runs["undeclared"]
    assert rec.verdict["verdict"] == "FAIL" and rec.provisional_differences == []
    d7 = [r for r in rec.results if "D7" in r.rests_on]
    assert all(r.outcome == Outcome.FAIL and r.other_reading == readings.REWIND_14 for r in d7)
    assert 'readings = ["D7:rewind-14"]' in d7[0].message


def test_declaring_a_reading_and_decoding_by_fbaconfs_fails(d7_runs):
    rec = d7_runs["declared-not-followed"]
    assert rec.verdict["verdict"] == "FAIL"
    d7 = [r for r in rec.results if "D7" in r.rests_on]
    assert all(r.outcome == Outcome.FAIL and "not the declared" in r.message for r in d7)


def test_rejecting_the_streams_that_rest_on_d7_is_no_provisional_difference(tmp_path):
    ss = load_suites(names=["simple-l1-core"])
    from fbaconf.conformance.provisional import rests_on  # noqa: PLC0415

    RejectsD7.rejected = {Path(c.inputs["fba"]).name for c in ss[0].cases if "D7" in rests_on(c)}
    assert len(RejectsD7.rejected) == 29
    rec = certify_like(adapter(RejectsD7, name="rejects-d7"), tmp_path, suites=["simple-l1-core"])
    assert rec.verdict["verdict"] == "FAIL" and rec.provisional_differences == []
    assert rec.verdict["decisions"]["D7"]["state"] == "fails"


# ------------------------------------------------------------------ real bugs (item 2 of the policy review)


class MultiFaceBug(ReferenceAdapter):
    """Decodes several faces, wrongly: ``bug`` says how."""

    bug = ""

    def run(self, job: Job) -> None:
        if not job.faces:
            return super().run(job)
        out = Path(job.path("faps_out_dir"))
        if self.bug == "no-output":
            return None
        frames = []
        for f in job.faces:
            tmp = out / f"tmp-{Path(f).stem}.npz"
            reference_outputs(Path(f), faps_out=tmp)
            frames.append((Path(f).stem, FapFrames.load_npz(tmp)))
            tmp.unlink()
        clock = 0.0
        first_rate = frames[0][1].frame_rate
        for i, (stem, fr) in enumerate(frames):
            if self.bug == "by-position":
                stem = f"face{i}"
            elif self.bug == "one-clock":
                fr.time_ms = fr.time_ms + clock
                clock = float(fr.time_ms[-1]) + 1000.0 / fr.frame_rate
            elif self.bug == "first-rate":
                fr.time_ms = fr.time_ms * (fr.frame_rate / first_rate)
                fr.frame_rate = first_rate
            fr.save_npz(out / f"{stem}.npz")
        return None


class AcceptsOnError(ReferenceAdapter):
    """Decodes what it can and exits 0 where the reference rejects for one of ``rules``."""

    rules: frozenset = frozenset()

    def run(self, job: Job) -> None:
        try:
            super().run(job)
        except FbaconfInputError as e:
            if e.rule not in self.rules:
                raise
            partial = getattr(e, "partial", None)
            (partial if partial is not None else FapFrames.empty(0)).save_npz(job.path("faps_out"))


@pytest.mark.parametrize("bug", ["no-output", "by-position", "one-clock", "first-rate"])
def test_multi_face_bugs_fail_the_claim(tmp_path, bug):
    cls = type(f"Multi_{bug}", (MultiFaceBug,), {"bug": bug})
    a = adapter(cls, name=f"multi-{bug}")
    a.supports_multi = True
    rec = certify_like(a, tmp_path, suites=["simple-l2-stress"], globs=["four-faces", "faces-*"])
    assert rec.verdict["verdict"] == "FAIL", rec.verdict
    failing = [r for r in rec.results if r.outcome == Outcome.FAIL]
    assert failing and rec.provisional_differences == [] and rec.verdict["unverified"] == []


@pytest.mark.parametrize(
    "rules, cases",
    [
        (["viseme-select-range", "expression-select-range"], ["viseme-select-range", "expression-select-range"]),
        (["first-plane-intra"], ["first-predicted", "first-predicted-decodable"]),
        (["frame-rate-zero"], ["frame-rate-zero"]),
    ],
)
def test_accepting_what_no_reading_makes_valid_fails_the_claim(tmp_path, rules, cases):
    cls = type("Accepts", (AcceptsOnError,), {"rules": frozenset(rules)})
    rec = certify_like(adapter(cls, name="accepts-" + rules[0]), tmp_path, suites=["simple-l1-error"])
    assert rec.verdict["verdict"] == "FAIL"
    got = by_id(rec)
    for c in cases:
        r = got[f"simple-l1-error/{c}"]
        assert r.outcome == Outcome.FAIL and r.reading is None and "without complaint" in r.message, (c, r.message)
    assert rec.provisional_differences == []


def test_the_bug_decoders_fail_the_whole_claim_not_only_their_cases(tmp_path):
    """One full simple@2 run of a bug decoder: the verdict of the claim, as certify gives it."""
    cls = type("Accepts", (AcceptsOnError,), {"rules": frozenset({"frame-rate-zero"})})
    rec = certify_like(adapter(cls, name="rate-zero-is-no-rate"), tmp_path)
    assert rec.verdict["verdict"] == "FAIL" and rec.exit_code == 1
    failing = {r.case_id for r in rec.results if not r.outcome.ok}
    assert "simple-l1-error/frame-rate-zero" in failing
    streams = {c.full_id: c.input_path("fba") for s in load_suites(names=SIMPLE_2) for c in s.cases}
    for cid in failing:  # only the streams the reference rejects for a frame rate 0 (a fuzz finding is one too)
        with pytest.raises(FbaconfInputError) as e:
            decode(streams[cid].read_bytes())
        assert e.value.rule == "frame-rate-zero", cid
    assert all(r.reading is None for r in rec.results)
