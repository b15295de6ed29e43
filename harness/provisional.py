"""What a case's expected output rests on, and how a claim's verdict treats a difference there.

The ISO/IEC 14496 text was not available to fbaconf: some expected outputs follow readings
fbaconf had to decide (``harness/data/provisional.toml``, D1-D8). A case *rests on* a
decision when a plausible other reading changes its expected output:

* **D8** — the case codes a plane with the DCT segment mode (tool ``dct``): its transform,
  scaling, prediction and run/level VLC tables are fbaconf's own;
* **D3-D7** — the checker (:func:`fbaconf.profiles.checker.check_stream`) warns with a
  ``FAP-DECISION-*`` code on one of the case's streams; the code's clause names the decision;
* for an invalid stream (an ``error`` case, whose expected output is a rejection): the
  decisions named by the clauses of the errors that make it invalid (``viseme-select-range``
  rests on D5, ``dct-bad-vlc`` on D8, ``first-predicted`` on D2; ``trailing-zero-byte`` on none).

This module is the one place that says so (:func:`rests_on`); it is derived from the case's
tools and streams, so the suites carry no copy of it.

The verdict rule (docs/harness.md, "Provisional requirements"), modelled on the Khronos CTS's
*CompatibilityWarning* (a result that does not fail a conformance submission): a required case
that **fails**, rests on provisional decisions, and differs only in ways one of them can
explain (:data:`CAN_CHANGE`: a DCT or an alphabet reading desynchronises the decoding —
any value, a rejection; D6 changes timing, or whether a stream without a usable rate is
accepted; D3 only what a FAP holds; D2 only whether a first predicted plane is an error) is a *provisional
difference*. It stays a Fail in every report, but the claim's verdict is ``PASS (provisional
differences: N)`` when nothing else fails, and ``FAIL`` under ``--strict``. A crash, a hang,
a blown limit, a set-up error — or, say, frame numbers without their skips on a case that
rests only on D5 — fails the claim as anywhere.
"""
from __future__ import annotations

import functools
import re
from collections import defaultdict
from pathlib import Path

from fbaconf.conformance.suite import Case, CaseKind
from fbaconf.profiles.checker import check_stream
from fbaconf.rules import CODES

from .results import CaseResult, Outcome

DCT_DECISION = "D8"
DECISION_PREFIX = "FAP-DECISION-"
_DECISION_IN_CLAUSE = re.compile(r"\bdecision (D\d+)\b")


def decision_of_code(code: str) -> str | None:
    """The decision (``"D5"``) a ``FAP-DECISION-*`` checker code warns about, from its clause."""
    info = CODES.get(code)
    m = _DECISION_IN_CLAUSE.search(info.clause) if info is not None else None
    return m.group(1) if m else None


@functools.lru_cache(maxsize=1024)
def _stream_decisions(path: str, digest: str, invalid: bool) -> tuple[str, ...]:
    """The decisions a stream's expected result depends on (cached by the file's sha256): for a
    valid stream those the checker's FAP-DECISION warnings name; for an invalid one those the
    clauses of its errors name."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return ()
    ds = check_stream(data)
    if invalid:
        found = {decision_of_code(d.code) for d in ds if d.severity == "error"}
    else:
        found = {decision_of_code(d.code) for d in ds if d.code.startswith(DECISION_PREFIX)}
    return tuple(sorted(x for x in found if x in CAN_CHANGE))


def rests_on(case: Case) -> list[str]:
    """The provisional decisions ``case``'s expected output rests on (sorted ids, e.g.
    ``["D5", "D8"]``); empty when it rests only on public facts and the decisions every
    case shares (D1, D2)."""
    out: set[str] = set()
    invalid = case.kind == CaseKind.ERROR
    if "dct" in case.tools and not invalid:
        out.add(DCT_DECISION)
    streams = [case.inputs.get("fba")] + list(case.inputs.get("faces", []))
    for rel in streams:
        if isinstance(rel, str) and case.suite_dir is not None:
            out.update(_stream_decisions(str(case.suite_dir / rel), case.sha256.get(rel, ""), invalid))
    return sorted(out)


# What each decision can change in a decoder's result: "values" (FAP values or statuses), "verdict"
# (a valid stream rejected, an invalid one accepted), "count" (how many frames), "timing" (frame
# numbers, plane times, the header rate). Anything else (vertices or images failing while the FAPs
# match) no decision explains.
CAN_CHANGE: dict[str, frozenset[str]] = {
    "D2": frozenset({"verdict"}),
    "D3": frozenset({"values"}),
    "D4": frozenset({"values", "verdict"}),
    "D5": frozenset({"values", "verdict"}),
    "D6": frozenset({"timing", "verdict"}),  # the rate: plane times, and whether "no rate" is an error
    "D7": frozenset({"values", "verdict", "count"}),
    "D8": frozenset({"values", "verdict", "count", "timing"}),
}


def difference_kinds(r: dict) -> set[str]:
    """What differs in a failing result (its JSON form): see :data:`CAN_CHANGE`; ``"other"``
    for what no decision explains."""
    stages = [s for s in r.get("stages") or [] if isinstance(s, dict)]
    if not stages:
        return {"verdict"}
    faps = next((s for s in stages if s.get("stage") == "faps"), None)
    kinds: set[str] = set()
    for s in stages:
        if s.get("outcome") in ("Pass", "QualityWarning"):
            continue
        if s is not faps:
            kinds.add("other" if faps is not None and faps.get("outcome") == "Pass" else "values")
            continue
        m = s.get("metrics") or {}
        if not {"values_differing", "frame_numbers_differing"} <= set(m):
            kinds.add("other")  # an unreadable output or a missing file: nothing to attribute
            continue
        if m.get("values_differing") or m.get("status_differing"):
            kinds.add("values")
        if m.get("frame_numbers_differing") or m.get("times_differing") or m.get("rate_differs"):
            kinds.add("timing")
        if m.get("expected_frames") != m.get("got_frames"):
            kinds.add("count")
    return kinds or {"other"}


def is_provisional_difference(r: CaseResult | dict) -> bool:
    """A required case that failed only in what its provisional decisions can change (module doc)."""
    d = r.to_json() if isinstance(r, CaseResult) else r
    if not (d.get("required") and d.get("outcome") == Outcome.FAIL.value and d.get("rests_on")):
        return False
    explained = set().union(*(CAN_CHANGE.get(x, frozenset()) for x in d["rests_on"]))
    return difference_kinds(d) <= explained


def provisional_differences(results: list) -> list[dict]:
    """``[{"case_id", "rests_on"}]`` of the provisional differences among ``results``
    (:class:`CaseResult` objects or their JSON form), by case id: the same list whatever order the
    cases finished in (certify writes it from the run, verify re-derives it from results.jsonl)."""
    out = []
    for r in results:
        if is_provisional_difference(r):
            d = r.to_json() if isinstance(r, CaseResult) else r
            out.append({"case_id": d["case_id"], "rests_on": list(d["rests_on"])})
    return sorted(out, key=lambda d: d["case_id"])


def agreement(results: list[CaseResult]) -> dict[str, dict[str, int]]:
    """Per decision: how many required cases resting on it the decoder passed and how many it
    failed (``{"D8": {"cases": 6, "passed": 6, "failed": 0}}``): which provisional readings
    the decoder agrees with."""
    out: dict[str, dict[str, int]] = defaultdict(lambda: {"cases": 0, "passed": 0, "failed": 0})
    for r in results:
        if not r.required:
            continue
        for d in r.rests_on:
            out[d]["cases"] += 1
            if r.outcome.ok:
                out[d]["passed"] += 1
            elif r.outcome.failing or r.outcome == Outcome.NOT_SUPPORTED:
                out[d]["failed"] += 1
    return dict(sorted(out.items()))
