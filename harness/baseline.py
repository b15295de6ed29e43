"""Known failures, flakes and retries (deqp-runner style), so CI fails on exactly what changed.

Baseline format — one case per line, ``#`` comments::

    simple-l1-core/dct-q4,Fail,faps:31,33             # known failure, with its failure signature
    simple-l2-stress/four-faces,Crash,signal:SIGSEGV
    simple-l2-stress/two-faces,NotSupported           # a required case the decoder cannot take
    predictable-l1-core/logo,Flake                    # any outcome accepted

The third field, the *failure signature* (:func:`signature`), says how the case fails: the
stages that failed and, per stage, what differs (the FAP numbers, the mesh parts, the
frames), or the crash kind. ``fbaconf run --write-baseline`` writes it; a line without one
accepts any failure of that outcome (the two-field form, e.g. ``,NotSupported``).

``--write-baseline FILE`` records every required case that did not pass (NotSupported
included; a case that failed and then passed on a ``--retries`` re-run as ``Flake``). An
existing FILE is updated, not replaced (:func:`write`): comments, blank lines, ``Flake``
lines and the lines of cases this run did not run stay as written, a line that still
describes its case stays word for word (its trailing comment too), a line whose case now fails
differently is rewritten (its comment kept), a line whose case now passes is removed, and
new failures are appended. The file is checked before the run starts (:func:`load`).

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

import difflib
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.errors import FbaconfInputError

from .results import CaseResult, Outcome

FLAKE = "Flake"
RETRY_PASSED = "flaky: passed on re-run"  # the message prefix of a case that passed on a --retries re-run
_MAX_ITEMS = 12
_HEADER = """\
# fbaconf baseline (docs/harness.md, "Gating a project's CI"): one case per line.
#   suite/case,Outcome[,signature]  a known failure (NotSupported: a required case the decoder cannot take)
#   suite/case,Flake                a flaky case: any outcome accepted
# `fbaconf run --write-baseline` updates this file: comments, Flake lines and lines of cases it
# did not run are kept; lines of cases that pass now are removed."""


class BaselineError(FbaconfInputError):
    rule = "baseline"


@dataclass(frozen=True)
class Entry:
    outcome: str
    signature: str = ""

    def matches(self, r: CaseResult) -> bool:
        """Whether ``r`` fails exactly as this line says (a Flake line matches any outcome)."""
        if self.outcome == FLAKE:
            return True
        return (
            not r.outcome.ok
            and r.outcome.value == self.outcome
            and (not self.signature or self.signature == signature(r))
        )

    def text(self) -> str:
        return f"{self.outcome},{self.signature}" if self.signature else self.outcome


@dataclass
class Line:
    """One line of a baseline file as written: a comment or blank line (``case`` None), or an entry
    with its trailing comment (kept when the line is rewritten)."""

    raw: str
    case: str | None = None
    entry: Entry | None = None
    comment: str = ""


def _read_text(path: Path) -> str:
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise BaselineError(f"cannot read baseline: {e.strerror}", rule="baseline", file=str(path)) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise BaselineError(f"byte {e.start}: not UTF-8 text", rule="baseline", file=str(path)) from None


def read_lines(path: Path) -> list[Line]:
    """Every line of a baseline file, parsed and checked (:class:`BaselineError` naming the line:
    no outcome, an unknown outcome, a case listed twice)."""
    text = _read_text(path)
    valid = {o.value for o in Outcome} | {FLAKE}
    out: list[Line] = []
    seen: dict[str, int] = {}
    for n, raw in enumerate(text.splitlines(), 1):
        body, hash_, comment = raw.partition("#")
        line = body.strip()
        if not line:
            out.append(Line(raw))
            continue
        parts = [p.strip() for p in line.split(",", 2)]
        if len(parts) < 2 or not parts[0] or parts[1] not in valid:
            shown = raw.strip()[:200]
            close = difflib.get_close_matches(parts[1], sorted(valid), n=1) if len(parts) > 1 else []
            raise BaselineError(
                f"line {n}: expected 'suite/case,Outcome[,signature]' with Outcome one of "
                f'{", ".join(sorted(valid))}; got "{shown}"' + (f" (did you mean {close[0]}?)" if close else ""),
                rule="baseline",
                file=str(path),
            )
        if parts[0] in seen:
            raise BaselineError(
                f"line {n}: {parts[0]} is listed again (first on line {seen[parts[0]]}): keep one line per case",
                rule="baseline",
                file=str(path),
            )
        seen[parts[0]] = n
        out.append(Line(raw, parts[0], Entry(parts[1], parts[2] if len(parts) > 2 else ""), (hash_ + comment).strip()))
    return out


def load(path: Path) -> dict[str, Entry]:
    """The entries of a baseline file by case id (checked: :func:`read_lines`)."""
    return {ln.case: ln.entry for ln in read_lines(path) if ln.case is not None and ln.entry is not None}


def load_flakes(path: Path) -> list[re.Pattern[str]]:
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


def _items(xs: Iterable[object]) -> str:
    xs = list(xs)
    return ",".join(str(x) for x in xs[:_MAX_ITEMS]) + ("+" if len(xs) > _MAX_ITEMS else "")


_HEX = re.compile(r"0x[0-9a-fA-F]+")


def _clean(sig: str) -> str:
    """A signature fit for one baseline field: one line, no comment sign, no addresses."""
    return " ".join(_HEX.sub("0x?", sig).replace("#", " ").split())


def signature(r: CaseResult) -> str:
    """How a failing case fails, stable across runs: the failing stages with what differs
    (FAP numbers, mesh parts, frames with image errors), or the crash kind / signal / exit code."""
    if r.outcome.ok:
        return ""
    if r.outcome == Outcome.CRASH:
        return _clean(f"crash:{r.crash_kind or r.signal or r.exit_code}")
    if r.outcome in (Outcome.TIMEOUT, Outcome.NOT_SUPPORTED, Outcome.ERROR, Outcome.SKIPPED):
        return r.outcome.value.lower()
    parts = []
    for s in r.stages:
        if s.outcome.ok:
            continue
        fd = s.first_difference or {}
        if s.stage == "faps":
            faps = [x["fap"] for x in fd.get("faps", []) if isinstance(x, dict)] or ([fd["fap"]] if "fap" in fd else [])
            parts.append(f"faps:{_items(faps)}" if faps else f"faps:{fd.get('what', 'differs')}")
        elif s.stage in ("vertices", "effective_faps"):
            parts.append(f"{s.stage}:{fd.get('part', fd.get('fap', 'differs'))}")
        else:
            parts.append(f"{s.stage}:{fd.get('frame', 'differs')}")
    if not parts:
        parts.append(f"exit:{r.exit_code}" if r.exit_code not in (None, 0) else "fail")
    return _clean(";".join(parts))


def entry_for(r: CaseResult) -> Entry:
    """The baseline entry that describes ``r`` (the signature left out where it only repeats the outcome;
    ``Flake`` for a case that passed on a ``--retries`` re-run)."""
    if r.baseline == "flake" and r.message.startswith(RETRY_PASSED):
        return Entry(FLAKE)
    sig = signature(r)
    return Entry(r.outcome.value, "" if sig == r.outcome.value.lower() else sig)


@dataclass
class Summary:
    new: list[CaseResult] = field(default_factory=list)
    known: list[CaseResult] = field(default_factory=list)
    fixed: list[CaseResult] = field(default_factory=list)
    flaky: list[CaseResult] = field(default_factory=list)

    def line(self) -> str:
        return f"{len(self.new)} new, {len(self.known)} known, {len(self.fixed)} fixed, {len(self.flaky)} flaky"

    def failing(self, allow_fixed: bool = False) -> list[CaseResult]:
        """What fails the run: new failures, and fixed cases unless allowed."""
        return self.new + ([] if allow_fixed else self.fixed)


def classify(
    results: list[CaseResult], baseline: dict[str, Entry] | None = None, flakes: list[re.Pattern[str]] | None = None
) -> Summary:
    """Annotate ``results`` (``r.baseline``) and sort the required ones into a :class:`Summary`.
    A result already marked ``flake`` (by a passing retry) stays one. With a baseline or a flakes
    file, a required case failing and not excused is tagged ``new``."""
    tag_new = baseline is not None or flakes is not None
    baseline = baseline or {}
    flakes = flakes or []
    s = Summary()
    for r in results:
        if r.baseline != "flake":
            r.baseline = None
        entry = baseline.get(r.case_id)
        if r.baseline == "flake" or (
            not r.outcome.ok
            and ((entry is not None and entry.outcome == FLAKE) or any(p.search(r.case_id) for p in flakes))
        ):
            r.baseline = "flake"
            if r.required:
                s.flaky.append(r)
            continue
        if entry is None or entry.outcome == FLAKE:
            if r.required and not r.outcome.ok:
                s.new.append(r)
                r.baseline = "new" if tag_new else None
            continue
        if r.outcome.ok and entry.outcome not in (Outcome.PASS.value, Outcome.QUALITY_WARNING.value):
            r.baseline = "fixed"
            if r.required:
                s.fixed.append(r)
        elif entry.matches(r):
            r.baseline = "known-failure"
            if r.required:
                s.known.append(r)
        elif not r.outcome.ok and r.required:  # a case outside the claim fails nothing, whatever its line says
            r.baseline = "new"
            r.message = f"fails differently from the baseline ({entry.text()} -> {entry_for(r).text()}): {r.message}"
            s.new.append(r)
    return s


def apply(
    results: list[CaseResult],
    baseline: dict[str, Entry],
    flakes: list[re.Pattern[str]] | None = None,
    allow_fixed: bool = False,
) -> list[CaseResult]:
    """Annotate ``results``; returns what fails the run (new failures, and fixed cases unless
    ``allow_fixed``)."""
    return classify(results, baseline, flakes).failing(allow_fixed)


@dataclass
class WriteReport:
    """What :func:`write` did to the file: lines added, rewritten, kept as written, removed."""

    path: Path
    added: list[str] = field(default_factory=list)
    updated: list[str] = field(default_factory=list)
    kept: int = 0
    removed: list[str] = field(default_factory=list)

    def line(self) -> str:
        def named(xs: list[str]) -> str:
            return (": " + ", ".join(xs[:10]) + (f", +{len(xs) - 10} more" if len(xs) > 10 else "")) if xs else ""

        return (
            f"baseline {self.path} written: {len(self.added)} case(s) added{named(self.added)}; "
            f"{len(self.updated)} rewritten (failing differently now){named(self.updated)}; "
            f"{len(self.removed)} removed (passing now){named(self.removed)}; {self.kept} line(s) kept as written"
        )


def check_writable(path: Path) -> None:
    """Before a run: ``--write-baseline``'s file must be a readable baseline if it exists, and its
    folder must exist (:class:`BaselineError`)."""
    path = Path(path)
    if path.exists():
        read_lines(path)
    elif not path.parent.is_dir():
        raise BaselineError(f"folder {path.parent} does not exist", rule="baseline", file=str(path))


def write(results: list[CaseResult], path: Path) -> WriteReport:
    """Record every required case of ``results`` that did not pass, updating ``path`` if it exists
    (the module's docstring says what is kept)."""
    path = Path(path)
    old = read_lines(path) if path.exists() else [Line(x) for x in _HEADER.splitlines()]
    ran = {r.case_id: r for r in results}
    want = {r.case_id: r for r in results if r.required and (not r.outcome.ok or r.baseline == "flake")}
    rep = WriteReport(path)
    out: list[str] = []
    for ln in old:
        if ln.case is None or ln.entry is None:  # comments and blank lines: as written
            out.append(ln.raw)
            continue
        r = ran.get(ln.case)
        if r is None or ln.entry.outcome == FLAKE:  # Flake lines, cases not run: as written
            out.append(ln.raw)
            rep.kept += 1
            want.pop(ln.case, None)
        elif ln.case in want:
            w = want.pop(ln.case)
            if ln.entry.matches(w) and entry_for(w).outcome != FLAKE:
                out.append(ln.raw)
                rep.kept += 1
            else:
                out.append(f"{ln.case},{entry_for(w).text()}" + (f"  {ln.comment}" if ln.comment else ""))
                rep.updated.append(ln.case)
        elif r.outcome.ok:
            rep.removed.append(ln.case)
        else:  # failing but no longer required (another claim): the line does no harm
            out.append(ln.raw)
            rep.kept += 1
    for cid in sorted(want):
        out.append(f"{cid},{entry_for(want[cid]).text()}")
        rep.added.append(cid)
    atomic_write_text(path, "\n".join(out) + "\n")
    return rep
