"""A claim's verdict from its required cases' results: the one rule ``run``, ``certify`` and
``certify verify`` apply (docs/harness.md, "Provisional requirements").

Modelled on the Khronos CTS, whose conformance submissions list what is not verified beside a
pass instead of failing it — and made as narrow as each decision:

* **A declared other reading is judged by what it gives.** A decoder that follows another
  reading of a decision (``readings = ["D7:rewind-14"]`` in its manifest; the readings public
  sources show, ``bitstreams/data/readings.toml``) is judged, on every case that reading changes,
  against the reading's own goldens — value for value, and a rejection only where that reading
  rejects the stream. Such a pass is a *provisional difference*. A difference no declared
  reading gives — a rejected valid stream, a decoded invalid one, any other value — fails as
  anywhere, whatever the case rests on.
* **An open decision leaves its tool verified or unverified, as a whole.** D8 (the DCT segment
  mode, whose tables are fbaconf's own) has no known other reading. A decoder that decodes every
  valid stream of the tool as fbaconf does is verified for it (and then must reject its invalid
  streams like any other). One that does not — it does not declare the tool, declares it and
  rejects every stream of it, decodes the streams to other values, or a mix, as other tables
  would — is **unverified** for that tool, whatever the mix, provided nothing crashed, hung or
  failed to start: the claim passes *with the tool named*, all its cases set aside together. No
  other table can be told from a bug, so none is excused case by case, and declining honestly
  and faking the tool get the same verdict.
* ``--strict`` fails both: any provisional difference, any unverified tool.

Verdict words: ``PASS``; ``PASS (unverified: dct; provisional differences: 29)``; ``FAIL``;
``SPEED FAIL`` (exit 3) and ``SPEED INCONCLUSIVE`` (exit 4) once every required case passed.
The statement says, per tool and per decision, ``verified`` / ``differs`` (by a declared
reading) / ``declined`` / ``unverified`` / ``fails``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from fbaconf.bitstreams import readings
from fbaconf.conformance.provisional import open_decisions

OK = ("Pass", "QualityWarning")
HARD = ("Crash", "Timeout", "Error")  # never set aside: the decoder misbehaved or could not run


@dataclass
class ToolState:
    tool: str
    state: str  # verified, differs, declined, unverified, fails
    cases: int
    passed: int
    provisional: bool  # every required case of the tool rests on an open decision
    note: str = ""

    @property
    def set_aside(self) -> bool:
        """Whether the tool's cases are set aside (named in the verdict as unverified)."""
        return self.provisional and self.state in ("declined", "unverified")


@dataclass
class DecisionState:
    decision: str
    state: str  # verified, differs, declined, unverified, fails, not exercised
    cases: int
    passed: int
    readings: list[str] = field(default_factory=list)  # the declared other readings of it


@dataclass
class ClaimVerdict:
    verdict: str
    exit_code: int
    differences: list[dict[str, Any]]  # [{"case_id", "rests_on", "reading"}], by case id
    unverified: list[str]  # tools set aside
    set_aside: set[str]  # the case ids of those tools
    tools: dict[str, ToolState]
    decisions: dict[str, DecisionState]

    def to_json(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict,
            "exit_code": self.exit_code,
            "provisional_differences": self.differences,
            "unverified": self.unverified,
            "tools": {k: asdict(v) for k, v in self.tools.items()},
            "decisions": {k: asdict(v) for k, v in self.decisions.items()},
        }


def _ok(r: dict[str, Any]) -> bool:
    return r.get("outcome") in OK


def _declined(r: dict[str, Any]) -> bool:
    """Not taken (NotSupported), or a valid stream rejected with a reject exit code."""
    return r.get("outcome") == "NotSupported" or (r.get("outcome") == "Fail" and r.get("ending") == "reject")


def tool_state(tool: str, cases: list[dict[str, Any]]) -> ToolState:
    """How the decoder fared on the required cases whose streams use ``tool`` (module doc)."""
    opened = set(open_decisions())
    provisional = bool(cases) and all(opened & set(r.get("rests_on") or ()) for r in cases)
    valid = [r for r in cases if r.get("kind") != "error"]
    passed = sum(_ok(r) for r in cases)
    hard = any(r.get("outcome") in HARD for r in cases)
    st = ToolState(tool, "fails", len(cases), passed, provisional)
    declined = bool(valid) and all(_declined(r) for r in valid)
    if passed == len(cases):
        st.state = "differs" if any(r.get("reading") for r in cases) else "verified"
    elif not hard and declined:
        taken = [r for r in valid if r.get("outcome") != "NotSupported"]
        st.state = "declined"
        st.note = (
            f"every valid stream of it was rejected ({len(taken)} of {len(valid)})"
            if taken
            else f"not taken ({len(valid)} valid stream(s) NotSupported)"
        )
    elif provisional and not hard and not all(_ok(r) for r in valid):
        # another table decodes some streams as fbaconf's does, others to other values, rejects others:
        # none of it can be told from a bug, so the tool as a whole is not verified
        ok = sum(_ok(r) for r in valid)
        rejected = sum(_declined(r) for r in valid)
        st.state = "unverified"
        st.note = (
            f"{ok} of its {len(valid)} valid stream(s) decoded as fbaconf decodes them, {rejected} rejected "
            f"or not taken, {len(valid) - ok - rejected} decoded otherwise"
        )
    else:
        st.note = f"{len(cases) - passed} of {len(cases)} case(s) not passed"
    return st


def decision_state(
    decision: str, cases: list[dict[str, Any]], set_aside: set[str], tools: dict[str, ToolState], declared: list[str]
) -> DecisionState:
    mine = [r for r in declared if readings.get(r).decision == decision]
    passed = sum(_ok(r) for r in cases)
    if not cases:
        return DecisionState(decision, "not exercised", 0, 0, mine)
    if any(not _ok(r) and r["case_id"] not in set_aside for r in cases):
        state = "fails"
    elif all(r["case_id"] in set_aside for r in cases):
        tool = open_decisions().get(decision)
        state = tools[tool].state if tool in tools else "unverified"
    elif any(r.get("reading") for r in cases):
        state = "differs"
    else:
        state = "verified"
    return DecisionState(decision, state, len(cases), passed, mine)


def verdict_of(s: dict[str, Any]) -> str:
    """ "pass" | "fail" | "inconclusive" of one speed result's JSON. Only a result that says it
    passed passes; one without a verdict (written before verdicts) is "pass" or "fail" by
    ``passed``; anything else that did not pass is a fail."""
    v = s.get("verdict")
    if s.get("passed") is True and v in (None, "pass"):
        return "pass"
    if s.get("passed") is False and v == "inconclusive":
        return "inconclusive"
    return "fail"


def speed_verdict(speed: list[dict[str, Any]] | None) -> tuple[str, int] | None:
    """The claim's speed verdict from its speed results (``SpeedResult.to_json()``; None: not
    measured): None when nothing blocks the pass; ``("SPEED FAIL", 3)`` when any operation
    failed; ``("SPEED INCONCLUSIVE", 4)`` when none failed and one was inconclusive."""
    if not speed:
        return None
    verdicts = [verdict_of(s) if isinstance(s, dict) else "fail" for s in speed]
    if "fail" in verdicts:
        return "SPEED FAIL", 3
    if "inconclusive" in verdicts:
        return "SPEED INCONCLUSIVE", 4
    return None


def claim_verdict(
    results: list[dict[str, Any]],
    *,
    strict: bool,
    speed: list[dict[str, Any]] | None,
    declared: list[str] | tuple[str, ...] = (),
) -> ClaimVerdict:
    """The claim's verdict from its result lines (JSON form; only the required ones count) and the
    speed results (None: not measured); ``declared``: the decoder's declared other readings."""
    required = [r for r in results if r.get("required")]
    by_tool: dict[str, list[dict[str, Any]]] = {}
    for r in required:
        for t in r.get("tools") or ():
            by_tool.setdefault(t, []).append(r)
    # the tools of open decisions first (set aside as a whole, or verified); every other tool is judged on
    # the cases left
    tools = {t: tool_state(t, cs) for t, cs in by_tool.items()}
    set_aside = {r["case_id"] for t in tools.values() if t.set_aside for r in by_tool[t.tool]}
    unverified = sorted(t.tool for t in tools.values() if t.set_aside)
    for t, cs in by_tool.items():
        if tools[t].set_aside:
            continue
        rest = [r for r in cs if r["case_id"] not in set_aside]
        if rest:
            tools[t] = tool_state(t, rest)
        else:
            del tools[t]
    tools = dict(sorted(tools.items()))
    differences = sorted(
        (
            {"case_id": r["case_id"], "rests_on": list(r.get("rests_on") or ()), "reading": r["reading"]}
            for r in required
            if r.get("reading") and _ok(r)
        ),
        key=lambda d: d["case_id"],
    )
    named = {d for r in required for d in r.get("rests_on") or ()} | {readings.get(r).decision for r in declared}
    decisions = {
        d: decision_state(d, [r for r in required if d in (r.get("rests_on") or ())], set_aside, tools, list(declared))
        for d in sorted(named)
    }
    hard = [r for r in required if not _ok(r) and (strict or r["case_id"] not in set_aside)]
    cv = ClaimVerdict("PASS", 0, differences, unverified, set_aside, tools, decisions)
    if hard or (strict and differences):
        cv.verdict, cv.exit_code = "FAIL", 1
        return cv
    blocked = speed_verdict(speed)
    if blocked is not None:
        cv.verdict, cv.exit_code = blocked
        return cv
    qualifiers = ([f"unverified: {', '.join(unverified)}"] if unverified else []) + (
        [f"provisional differences: {len(differences)}"] if differences else []
    )
    if qualifiers:
        cv.verdict = f"PASS ({'; '.join(qualifiers)})"
    return cv


_TOOL_WORDS = {
    "verified": "verified: every required case passed by fbaconf's readings",
    "differs": "differs: every required case passed, some by a declared other reading (provisional differences)",
    "declined": "declined",
    "unverified": "unverified",
    "fails": "fails",
}


def describe(verdict: dict[str, Any]) -> list[str]:
    """What a claim's verdict (:meth:`ClaimVerdict.to_json`) says per tool and per decision, one
    line each: the statement, the terminal summary and the HTML report print these."""
    out = []
    for t in (verdict.get("tools") or {}).values():
        line = (
            f"tool {t['tool']}: {_TOOL_WORDS.get(t['state'], t['state'])} ({t['passed']} of {t['cases']} case(s) "
            f"passed{'; ' + t['note'] if t.get('note') else ''})"
        )
        if t["state"] in ("declined", "unverified") and t["provisional"]:
            line += (
                " — every required case of it rests on an open provisional decision, so the claim passes with "
                "the tool named unverified; --strict fails it"
            )
        elif t["state"] == "declined":
            line += " — a claim means all of it: its cases fail the claim"
        out.append(line)
    for d in (verdict.get("decisions") or {}).values():
        how = {
            "verified": "verified: every case resting on it passed by fbaconf's reading",
            "differs": f"differs: judged by the declared reading {', '.join(d['readings'])} where it changes the "
            f"result",
            "declined": "declined: its tool was declined (not taken, or every valid stream rejected)",
            "unverified": "unverified: its tool was decoded, never as fbaconf decodes it",
            "fails": "fails: a case resting on it failed in a way no declared reading gives",
            "not exercised": "not exercised by this claim's cases",
        }.get(d["state"], d["state"])
        out.append(f"decision {d['decision']}: {how} ({d['passed']} of {d['cases']} case(s) passed)")
    return out
