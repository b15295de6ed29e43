"""A run's failures as root causes: the cases' features and first divergences (a failing case's
features less those its stream first has after its first divergence, :mod:`localise`), the spectrum
ranking, and (where the decoder can be run in the sandbox) confirming edits and reruns.

Read in this order: :func:`views` (what each case has and where it failed), :func:`explain`
(undefined behaviour first, then causes taken greedily by the spectrum, each confirmed by the
first tied candidate whose variant the decoder passes), :class:`Explanation` (what the reports
print)."""

from __future__ import annotations

import shlex
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from fbaconf.conformance.coverage import load_model, stream_points
from fbaconf.conformance.coverage_table import points_of
from fbaconf.conformance.suite import Case, CaseKind
from fbaconf.harness.adapters import Adapter
from fbaconf.harness.results import CaseResult, Outcome, RunRecord

from . import localise, spectrum, streams, triggers
from .confirm import Budget, Runner

# features every case of a claim or a suite form has: they name no behaviour
_UNINFORMATIVE = ("claim.", "limit.")
_ALWAYS = {"text.fap", "status.free-never-set", "text.version-2.1"}
FAILING = (Outcome.FAIL, Outcome.CRASH, Outcome.TIMEOUT)
UNDEFINED = "undefined-behaviour"
ERROR_KIND = "kind.error"


# coverage-point families that describe only how a stream is coded: a player reads the text
# form of the decoding and never sees them
_CODING_ONLY = (
    "arith.", "coding.", "dct.", "defaults.", "diag.", "fap_quant.", "lists.", "mask.", "model.", "plane.",
    "retained.", "skip.", "stream.", "symbol.", "timecode.", "error.FAP-",
)  # fmt: skip


def taken_input(case: Case, inputs: Sequence[str]) -> str | None:
    """Which of the case's inputs a decoder that accepts ``inputs`` is given (as the harness stages
    them): the binary stream, else the ``.fap`` text (a player)."""
    if "fba" in inputs and case.input_path("fba") is not None:
        return "fba"
    if "fap" in inputs and case.input_path("fap") is not None:
        return "fap"
    return None


def case_features(case: Case | None, result: CaseResult, inputs: Sequence[str] = ("fba",)) -> frozenset[str]:
    """A case's features: its coverage points (for a player, those of the content, not of the
    coding), the triggers in the ``.fap`` text a player reads, the provisional decisions its
    expected output rests on, and ``kind.error`` for an invalid input."""
    fs: set[str] = set()
    if case is not None:
        fs |= {p for p in points_of(case) if not p.startswith(_UNINFORMATIVE)} - _ALWAYS
        fap = case.input_path("fap")
        if taken_input(case, inputs) == "fap" and fap is not None and fap.is_file():
            fs = {p for p in fs if not p.startswith(_CODING_ONLY)} | triggers.text_features(fap.read_bytes())
        if case.kind == CaseKind.ERROR:
            fs.add(ERROR_KIND)
    fs |= {f"decision.{d}" for d in result.rests_on}
    return frozenset(fs)


def _short(v: object, n: int = 48) -> str:
    s = str(v)
    return s if len(s) <= n else s[: n - 1] + "…"


def divergence(r: CaseResult) -> str:
    """Where the decoder's output first left the expected one, from the comparison's structured
    first difference (or, for a case it did not decode, how its process ended)."""
    fd = r.first_difference
    if fd:
        what = fd.get("what", "value")
        at = f"frame {fd['frame']}" if "frame" in fd else "header"
        fap = f" FAP {fd['fap']} {fd.get('name', '')}".rstrip() if "fap" in fd else ""
        if "pixel" in fd:
            fap = f" pixel {fd['pixel']}"
        elif "vertex" in fd:
            fap = f" vertex {fd['vertex']}"
        return f"{at}{fap}: {what} expected {_short(fd.get('expected'))}, got {_short(fd.get('got'))}"
    if r.outcome == Outcome.CRASH:
        return f"crashed ({r.signal or r.crash_kind or f'exit {r.exit_code}'})"
    if r.outcome == Outcome.TIMEOUT:
        return "ran past its time limit"
    if r.kind == CaseKind.ERROR.value:
        return "decoded an invalid stream without complaint" if r.ending == "decoded" else r.message[:120]
    if r.ending == "reject":
        return f"rejected a valid input (exit {r.exit_code})"
    return r.message[:120]


def views(record: RunRecord, cases: dict[str, Case]) -> list[spectrum.CaseView]:
    inputs = list(record.decoder.get("inputs") or ["fba"])
    out = []
    for r in record.results:
        case = cases.get(r.case_id)
        features = case_features(case, r, inputs)
        if r.outcome in FAILING:
            features -= localise.after_divergence(case, r)
        out.append(
            spectrum.CaseView(
                case_id=r.case_id,
                outcome=r.outcome.value,
                failing=r.outcome in FAILING,
                passing=r.outcome.ok,
                features=features,
                divergence=divergence(r) if r.outcome in FAILING else "",
            )
        )
    return out


# ------------------------------------------------------------------ what a feature means


@dataclass(frozen=True)
class Meaning:
    what: str
    concerns: str


def meanings() -> Callable[[str], Meaning]:
    points = {p.id: p for p in load_model()}

    def of(feature: str) -> Meaning:
        if feature in triggers.TRIGGERS:
            t = triggers.TRIGGERS[feature]
            return Meaning(t.what, t.concerns)
        if feature in points:
            p = points[feature]
            return Meaning(p.description, p.clause)
        if feature == ERROR_KIND:
            return Meaning(
                "an invalid input accepted: the decoder does not check what it reads",
                "the rules each invalid case breaks (the checker's diagnostics); no variant confirms it: "
                "the fault is what makes the input invalid",
            )
        if feature.startswith("decision."):
            d = feature.split(".", 1)[1]
            return Meaning(f"the expected output rests on the provisional decision {d}", f"decision {d}")
        return Meaning(feature, "")

    return of


# ------------------------------------------------------------------ confirming edits


@dataclass
class Trial:
    """One confirming run: the variant of ``case_id`` without ``feature``."""

    feature: str
    case_id: str
    edit: str
    outcome: str  # the variant's outcome
    confirmed: bool
    control: str | None = None  # the writer's rewrite without the edit, where one was run
    input: str | None = None  # the variant's input, kept for the reproduce line
    # the case's other features the variant lacks too: a passing variant confirms the feature
    # only together with these (dropping FAP 1 drops its viseme and its held values with it)
    also: list[str] = field(default_factory=list)


def _text_edit(feature: str) -> str | None:
    """The text trigger whose edit takes ``feature`` out of a ``.fap``."""
    alias = {
        "text.count-0": "text.count",
        "text.gap": "content.frame-gap",
        "text.frame-past-count": "content.frame-past-count",
        "status.retained": "content.held",
        "highlevel.viseme_def": "content.viseme_def",
    }
    if feature in triggers.TRIGGERS:
        return feature
    if feature.startswith("text.version-"):
        return "text.version"
    if feature.startswith(("highlevel.", "viseme.", "expression.")):
        return "content.high-level"
    return alias.get(feature)


def _refines_another(feature: str, tied: Sequence[spectrum.Score]) -> bool:
    t = triggers.TRIGGERS.get(feature)
    return t is not None and t.refines in {c.feature for c in tied}


@dataclass(frozen=True)
class Variant:
    """A case's input without one feature, in the form the decoder takes."""

    key: str  # the input it replaces: "fba" or "fap"
    data: bytes
    edit: str  # what the edit did
    rewritten: bool  # the writer's rewrite also normalised the text's form
    gone: frozenset[str]  # every feature of the case's input the variant no longer has


def _variant(case: Case, feature: str, inputs: Sequence[str]) -> Variant | None:
    """``case`` without ``feature``; None where no edit takes it out — also where the edit leaves
    it in (a re-encoded stream still has intra planes, a 25 Hz rate is still an integer one): a
    decoder passing such a variant passed for another reason, and the feature would be confirmed
    by what the edit took out beside it."""
    fba, fap = case.input_path("fba"), case.input_path("fap")
    if feature == ERROR_KIND or case.kind == CaseKind.ERROR:
        return None
    if taken_input(case, inputs) == "fba" and fba is not None and fba.is_file():
        e = streams.edit_for(feature)
        if e is None:
            return None
        original = fba.read_bytes()
        data = streams.stream_variant(original, e[1], e[2])
        if data is None:
            return None
        gone = stream_points(original) - stream_points(data)
        return Variant("fba", data, e[0], False, frozenset(gone)) if feature in gone else None
    if taken_input(case, inputs) == "fap" and fap is not None and fap.is_file():
        tid = _text_edit(feature)
        if tid is None:
            return None
        original = fap.read_bytes()
        text = triggers.text_variant(original, tid)
        if text is None:
            return None
        gone = triggers.text_features(original) - triggers.text_features(text.encode())
        if tid not in gone:
            return None
        t = triggers.TRIGGERS[tid]
        return Variant("fap", text.encode(), f"without {t.what}", t.rewrites, frozenset(gone | {feature}))
    return None


def _try(runner: Runner, case: Case, feature: str, features: frozenset[str], keep: Path | None) -> Trial | None:
    v = _variant(case, feature, runner.adapter.inputs)
    if v is None:
        return None
    key, data, rewritten = v.key, v.data, v.rewritten
    label = feature.replace("/", "_")
    res, path = runner.variant(case, key, data, label)
    also = sorted((v.gone & features) - {feature})
    trial = Trial(feature, case.full_id, v.edit, res.outcome.value, res.outcome.ok, also=also)
    forms = {f for f in features if f in triggers.TRIGGERS and triggers.TRIGGERS[f].form} - {feature}
    fap = case.input_path("fap")
    if trial.confirmed and rewritten and forms and runner.left > 0 and fap is not None:
        ctl = triggers.control_variant(fap.read_bytes())
        if ctl is not None:
            cres, _ = runner.variant(case, key, ctl.encode(), "control")
            trial.control = cres.outcome.value
            trial.confirmed = not cres.outcome.ok  # the rewrite alone passes: the form, not this, failed it
            # the rewrite alone (the same forms gone) still failed: the forms are not what it lacks too
            trial.also = [a for a in trial.also if a not in forms]
    if trial.confirmed and keep is not None:
        trial.input = str(runner.keep(path, keep / f"{case.suite}~{case.id}~{label}{path.suffix}"))
    return trial


# ------------------------------------------------------------------ causes


@dataclass
class Cause:
    feature: str
    what: str
    concerns: str
    kind: str  # "trigger", "undefined-behaviour" or "unexplained"
    cases: list[str]
    ochiai: float = 0.0
    passed_with: int = 0  # passing cases that have the feature too
    divergences: list[str] = field(default_factory=list)
    confirmed: Trial | None = None
    tried: list[Trial] = field(default_factory=list)
    aliases: list[str] = field(default_factory=list)  # features the run's cases cannot tell from this one
    # features ranked equal that explain the same failing cases (the passing ones differ): the
    # ranking's choice among them is by name, so the cause names them all
    tied: list[str] = field(default_factory=list)


@dataclass
class Explanation:
    decoder: str
    claim: str | None
    cases: int
    failing: int
    causes: list[Cause]
    runs: int = 0
    bound: int = 0
    confirming: str = ""  # how the confirming runs were made, or why none were
    manifest: str | None = None
    not_decoder: int = 0  # cases the harness could not run (Error): the lab's, never a cause

    @property
    def explained(self) -> int:
        return sum(len(c.cases) for c in self.causes if c.kind != "unexplained")

    def headline(self) -> str:
        if not self.failing:
            return f"no failures: {self.decoder} passed or was excused every case it ran ({self.cases} cases)"
        n = sum(1 for c in self.causes if c.kind != "unexplained")
        return f"{n} cause{'s' * (n != 1)} explain {self.explained} of {self.failing} failures"

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["format"] = "fbaconf.explain/1"
        d["headline"] = self.headline()
        d["explained"] = self.explained
        return d


def _divergences(vs: Sequence[spectrum.CaseView], ids: list[str], n: int = 3) -> list[str]:
    by = {v.case_id: v.divergence for v in vs}
    return [d for d, _ in Counter(by[i] for i in ids if by.get(i)).most_common(n)]


def _undefined(
    runner: Runner, record: RunRecord, cases: dict[str, Case], pool: set[str]
) -> tuple[list[str], dict[str, list[str]]]:
    """Failing cases whose outcome is not reproducible (run again ``budget.reruns`` times): the
    decoder's behaviour on them is undefined (e.g. an uninitialised read), its own cause."""
    unstable: dict[str, list[str]] = {}
    # what differs between runs of a decoder with undefined behaviour is how it ends: rerun those first
    order = sorted(
        (r for r in record.results if r.case_id in pool and r.case_id in cases),
        key=lambda r: r.case_id,
    )
    # undefined behaviour shows in how a run ends (a crash one time, a rejection the next): the
    # cases that did not end with outputs to compare are the ones run again
    order = [r for r in order if r.outcome != Outcome.FAIL or r.ending != "decoded"]
    for r in order[: runner.budget.rerun_cases]:
        seen = [f"{r.outcome.value}/{r.ending}"]
        for _ in range(runner.budget.reruns):
            again = runner.rerun(cases[r.case_id])
            seen.append(f"{again.outcome.value}/{again.ending}")
        if len(set(seen)) > 1:
            unstable[r.case_id] = seen
    return sorted(unstable), unstable


def _in_rank_order(cands: Sequence[spectrum.Score]) -> list[spectrum.Score]:
    """The candidates as they are tried: the ones ranked equal to the best (refinements before what
    they refine), then the next ones."""
    best = cands[0]
    tied = [c for c in cands if (round(c.ochiai, 9), c.failed) == (round(best.ochiai, 9), best.failed)]
    features = tuple(tied)
    first = sorted(tied, key=lambda c: not _refines_another(c.feature, features))
    return first + [c for c in cands if c not in tied]


def _choose(
    order: list[spectrum.Score],
    vs: Sequence[spectrum.CaseView],
    pool: set[str],
    cases: dict[str, Case],
    runner: Runner | None,
    keep: Path | None,
) -> tuple[spectrum.Score, Trial | None, list[Trial]]:
    """The cause to take next: in ``order``, the first whose variant the decoder passes (a feature
    that only happens to be shared by failures of several causes is confirmed by none of its
    variants, and gives way); the first in ``order`` when none is confirmed within the budget.

    A passing variant that also lacks a candidate ranked before its own confirms that one as much
    (the edit does not tell them apart: dropping FAPs 1 and 2 changes the arithmetic coding, and a
    look-ahead stuffing no edit can take out alone goes with it), and the ranking decides: the
    earlier candidate is taken (unless a variant without it failed), confirmed by that variant,
    the later one among what it also lacks."""
    tried: list[Trial] = []
    if runner is None:
        return order[0], None, tried
    spent = runner.runs
    features = {v.case_id: v.features for v in vs}
    for k, cand in enumerate(order):
        for cid in sorted(spectrum.explained_by(vs, cand.feature, pool), key=lambda i: (len(features[i]), i))[:2]:
            if runner.runs - spent >= runner.budget.per_cause or runner.left <= 0 or cid not in cases:
                break
            t = _try(runner, cases[cid], cand.feature, features[cid], keep)
            if t is not None:
                tried.append(t)
                if t.confirmed:
                    refuted = {x.feature for x in tried if not x.confirmed}  # failed without it: not it
                    earlier = next((c for c in order[:k] if c.feature in t.also and c.feature not in refuted), None)
                    if earlier is None:
                        return cand, t, tried
                    also = sorted((set(t.also) - {earlier.feature}) | {cand.feature})
                    return earlier, replace(t, feature=earlier.feature, also=also), tried
    return order[0], None, tried


def explain(
    record: RunRecord,
    cases: dict[str, Case],
    *,
    adapter: Adapter | None = None,
    why_not: str = "",
    budget: Budget | None = None,
    keep: Path | None = None,
) -> Explanation:
    """Group ``record``'s failing cases into ranked causes. With ``adapter`` (the run's decoder,
    in the sandbox) each cause is confirmed by a variant without its trigger and the failing cases
    are rerun to find undefined behaviour, within ``budget``; ``why_not`` says why there is none."""
    budget = budget or Budget()
    vs = views(record, cases)
    meaning = meanings()
    pool = {v.case_id for v in vs if v.failing}
    ex = Explanation(
        decoder=str(record.decoder.get("name", "?")),
        claim=record.claim,
        cases=len(vs),
        failing=len(pool),
        causes=[],
        bound=budget.bound if adapter is not None else 0,
        confirming=why_not if adapter is None else "",
        manifest=record.decoder.get("manifest"),
        not_decoder=sum(1 for r in record.results if r.outcome == Outcome.ERROR),
    )
    if not pool:
        return ex
    runner = Runner(adapter, record.claim, budget) if adapter is not None else None
    try:
        if runner is not None:
            ids, seen = _undefined(runner, record, cases, pool)
            if ids:
                ex.causes.append(
                    Cause(
                        UNDEFINED,
                        "outcomes that change from run to run: undefined behaviour (an uninitialised "
                        "read, a race); " + "; ".join(f"{i}: {' / '.join(seen[i])}" for i in ids[:4]),
                        "any: the decoder's behaviour is not a function of its input",
                        UNDEFINED,
                        ids,
                        divergences=_divergences(vs, ids),
                    )
                )
                pool -= set(ids)
        while pool and len(ex.causes) < budget.max_causes:
            ranked = spectrum.scores(vs, pool)
            cands = spectrum.candidates(ranked, 6)
            if not cands:
                break
            chosen, confirmed, tried = _choose(_in_rank_order(cands), vs, pool, cases, runner, keep)
            ids = spectrum.explained_by(vs, chosen.feature, pool)
            aliases = spectrum.aliases(vs, chosen.feature)
            tied = [
                s.feature
                for s in ranked
                if s.feature != chosen.feature
                and s.feature not in aliases
                and (round(s.ochiai, 9), s.failed, s.passed) == (round(chosen.ochiai, 9), chosen.failed, chosen.passed)
                and spectrum.explained_by(vs, s.feature, pool) == ids
            ]
            m = meaning(chosen.feature)
            ex.causes.append(
                Cause(
                    chosen.feature,
                    m.what,
                    m.concerns,
                    "trigger",
                    ids,
                    round(chosen.ochiai, 3),
                    chosen.passed,
                    _divergences(vs, ids),
                    confirmed,
                    [t for t in tried if t.feature == chosen.feature],
                    aliases,
                    # a confirmed cause is separated from its ties, but for those its variant lacked too
                    tied if confirmed is None else [f for f in tied if f in confirmed.also],
                )
            )
            pool -= set(ids)
        if pool:
            left = sorted(pool)
            ex.causes.append(
                Cause(
                    "unexplained",
                    "no feature of these cases sets them apart from the passing ones",
                    "",
                    "unexplained",
                    left,
                    divergences=_divergences(vs, left),
                )
            )
    finally:
        if runner is not None:
            ex.runs = runner.runs
            runner.__exit__(None, None, None)
    return ex


def reproduce(ex: Explanation, trial: Trial) -> str:
    """A command line that runs the decoder on the confirming input (the case's own is `fbaconf run
    --case`)."""
    case = trial.case_id
    line = f"fbaconf run --decoder {shlex.quote(ex.manifest or 'MANIFEST')} --case {shlex.quote(case)}"
    if trial.input:
        line += f"   # passes without the trigger: {shlex.quote(trial.input)}"
    return line
