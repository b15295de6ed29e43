"""Known failures, flakes and retries (deqp-runner style), so CI fails on exactly what changed.

Baseline format — one case per line, ``#`` comments::

    simple-l1-core/dct-q4,Fail,faps:31,33             # known failure, with its failure signature
    simple-l2-stress/four-faces,Crash,signal:SIGSEGV
    predictable-l1-core/logo,Flake                    # any outcome accepted

The third field, the *failure signature* (:func:`signature`), says how the case fails: the
stages that failed and, per stage, what differs (the FAP numbers, the mesh parts, the
frames), or the crash kind. ``fbaconf run --write-baseline`` writes it; a line without one
accepts any failure of that outcome (the older two-field form).

After a run every result is classified:

* ``known-failure`` — failing exactly as listed (same outcome and signature): does not fail the run;
* ``flake``  — listed as ``Flake``, matching a ``--flakes`` pattern, or failing and then
  passing on a ``--retries`` re-run: does not fail the run;
* ``fixed``  — listed as failing but it passes now: fails the run (the baseline is stale;
  remove the line), unless ``--allow-fixed``;
* ``new``    — failing and not listed, or failing *differently* from its line (another
  outcome or signature: a second bug in a known-failing case): fails the run.

The summary line reads ``N new, N known, N fixed, N flaky``.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.errors import FbaconfInputError

from .results import CaseResult, Outcome

FLAKE = "Flake"
_MAX_ITEMS = 12


class BaselineError(FbaconfInputError):
    rule = "baseline"


@dataclass(frozen=True)
class Entry:
    outcome: str
    signature: str = ""


def _read_text(path: Path) -> str:
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise BaselineError(f"cannot read baseline: {e.strerror}", rule="baseline", file=str(path)) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise BaselineError(f"byte {e.start}: not UTF-8 text", rule="baseline", file=str(path)) from None


def load(path: Path) -> dict[str, Entry]:
    text = _read_text(path)
    out: dict[str, Entry] = {}
    valid = {o.value for o in Outcome} | {FLAKE}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p.strip() for p in line.split(",", 2)]
        if len(parts) < 2 or not parts[0] or parts[1] not in valid:
            raise BaselineError(f"line {n}: expected 'suite/case,Outcome[,signature]' with Outcome one of "
                                f"{', '.join(sorted(valid))}; got {raw.strip()[:200]!r}", rule="baseline",
                                file=str(path))
        out[parts[0]] = Entry(parts[1], parts[2] if len(parts) > 2 else "")
    return out


def load_flakes(path: Path) -> list[re.Pattern]:
    """A flakes file: one regular expression per line matched against case ids (``#`` comments)."""
    out = []
    for n, raw in enumerate(_read_text(path).splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        try:
            out.append(re.compile(line))
        except re.error as e:
            raise BaselineError(f"line {n}: not a regular expression: {e}", rule="baseline", file=str(path)) from None
    return out


def _items(xs) -> str:
    xs = list(xs)
    return ",".join(str(x) for x in xs[:_MAX_ITEMS]) + ("+" if len(xs) > _MAX_ITEMS else "")


def signature(r: CaseResult) -> str:
    """How a failing case fails, stable across runs: the failing stages with what differs
    (FAP numbers, mesh parts, frames with image errors), or the crash kind / signal / exit code."""
    if r.outcome.ok:
        return ""
    if r.outcome == Outcome.CRASH:
        return f"crash:{r.crash_kind or r.signal or r.exit_code}"
    if r.outcome in (Outcome.TIMEOUT, Outcome.NOT_SUPPORTED, Outcome.ERROR, Outcome.SKIPPED):
        return r.outcome.value.lower()
    parts = []
    for s in r.stages:
        if s.outcome.ok:
            continue
        fd = s.first_difference or {}
        if s.stage == "faps":
            faps = [x["fap"] for x in fd.get("faps", []) if isinstance(x, dict)] or \
                ([fd["fap"]] if "fap" in fd else [])
            parts.append(f"faps:{_items(faps)}" if faps else f"faps:{fd.get('what', 'differs')}")
        elif s.stage in ("vertices", "effective_faps"):
            parts.append(f"{s.stage}:{fd.get('part', fd.get('fap', 'differs'))}")
        else:
            parts.append(f"{s.stage}:{fd.get('frame', 'differs')}")
    if not parts:
        parts.append(f"exit:{r.exit_code}" if r.exit_code not in (None, 0) else "fail")
    return ";".join(parts)


@dataclass
class Summary:
    new: list[CaseResult] = field(default_factory=list)
    known: list[CaseResult] = field(default_factory=list)
    fixed: list[CaseResult] = field(default_factory=list)
    flaky: list[CaseResult] = field(default_factory=list)

    def line(self) -> str:
        return (f"{len(self.new)} new, {len(self.known)} known, {len(self.fixed)} fixed, "
                f"{len(self.flaky)} flaky")

    def failing(self, allow_fixed: bool = False) -> list[CaseResult]:
        """What fails the run: new failures, and fixed cases unless allowed."""
        return self.new + ([] if allow_fixed else self.fixed)


def classify(results: list[CaseResult], baseline: dict[str, Entry] | None = None,
             flakes: list[re.Pattern] | None = None) -> Summary:
    """Annotate ``results`` (``r.baseline``) and sort the required ones into a :class:`Summary`.
    A result already marked ``flake`` (by a passing retry) stays one."""
    baseline = baseline or {}
    flakes = flakes or []
    s = Summary()
    for r in results:
        if r.baseline != "flake":
            r.baseline = None
        entry = baseline.get(r.case_id)
        if r.baseline == "flake" or (not r.outcome.ok and (
                (entry is not None and entry.outcome == FLAKE) or any(p.search(r.case_id) for p in flakes))):
            r.baseline = "flake"
            if r.required:
                s.flaky.append(r)
            continue
        if entry is None or entry.outcome == FLAKE:
            if r.required and not r.outcome.ok:
                s.new.append(r)
            continue
        if r.outcome.ok and entry.outcome not in (Outcome.PASS.value, Outcome.QUALITY_WARNING.value):
            r.baseline = "fixed"
            if r.required:
                s.fixed.append(r)
        elif not r.outcome.ok and r.outcome.value == entry.outcome and \
                (not entry.signature or entry.signature == signature(r)):
            r.baseline = "known-failure"
            if r.required:
                s.known.append(r)
        elif not r.outcome.ok:
            r.baseline = "new"
            r.message = (f"fails differently from the baseline ({entry.outcome}"
                         f"{',' + entry.signature if entry.signature else ''} -> {r.outcome.value},"
                         f"{signature(r)}): {r.message}")
            if r.required:
                s.new.append(r)
    return s


def apply(results: list[CaseResult], baseline: dict[str, Entry], flakes=None, allow_fixed: bool = False):
    """Annotate ``results``; returns what fails the run (new failures, and fixed cases unless
    ``allow_fixed``)."""
    return classify(results, baseline, flakes).failing(allow_fixed)


def write(results: list[CaseResult], path: Path) -> int:
    lines = ["# fbaconf baseline: known failures 'case,Outcome,signature' (see docs/harness.md);",
             "# add 'case,Flake' lines by hand for flaky cases"]
    n = 0
    for r in sorted(results, key=lambda r: r.case_id):
        if not r.outcome.ok and r.outcome != Outcome.NOT_SUPPORTED:
            lines.append(f"{r.case_id},{r.outcome.value},{signature(r)}")
            n += 1
    atomic_write_text(path, "\n".join(lines) + "\n")
    return n
