"""Known failures and flakes (deqp-runner style), so CI fails only on new failures.

Format — one case per line, ``#`` comments::

    simple-l1-core/dct-q4,Fail          # known failure: expected to fail this way
    simple-l2-stress/four-faces,Crash
    predictable-l1-core/logo,Flake      # any outcome accepted

After a run each result is annotated: ``known-failure`` (failing exactly as listed),
``flake`` (listed as Flake), ``fixed`` (listed as failing but now passes — remove the line),
and a failing case that is not listed, or fails differently, is a new failure.
"""
from __future__ import annotations

from pathlib import Path

from fbaconf._atomic import atomic_write_text
from fbaconf.errors import FbaconfInputError

from .results import CaseResult, Outcome

FLAKE = "Flake"


class BaselineError(FbaconfInputError):
    pass


def load(path: Path) -> dict[str, str]:
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as e:
        raise BaselineError(f"cannot read baseline: {e.strerror}", rule="baseline", file=str(path)) from None
    out: dict[str, str] = {}
    valid = {o.value for o in Outcome} | {FLAKE}
    for n, raw in enumerate(text.splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        case, sep, outcome = line.rpartition(",")
        case, outcome = case.strip(), outcome.strip()
        if not sep or not case or outcome not in valid:
            raise BaselineError(f"line {n}: expected 'suite/case,Outcome' with Outcome one of "
                                f"{', '.join(sorted(valid))}; got {raw.strip()!r}", rule="baseline",
                                file=str(path))
        out[case] = outcome
    return out


def apply(results: list[CaseResult], baseline: dict[str, str]) -> list[CaseResult]:
    """Annotate ``results``; returns the new failures (required, failing, not excused)."""
    new = []
    for r in results:
        r.baseline = None
        listed = baseline.get(r.case_id)
        if listed == FLAKE:
            r.baseline = "flake"
        elif listed is not None and r.outcome.value == listed and not r.outcome.ok:
            r.baseline = "known-failure"
        elif listed is not None and r.outcome.ok and listed not in (Outcome.PASS.value, Outcome.QUALITY_WARNING.value):
            r.baseline = "fixed"
        if r.required and r.outcome.failing and r.baseline not in ("flake", "known-failure"):
            new.append(r)
    return new


def write(results: list[CaseResult], path: Path) -> int:
    lines = ["# fbaconf baseline: known failures (case,Outcome); add ',Flake' lines by hand for flaky cases"]
    n = 0
    for r in sorted(results, key=lambda r: r.case_id):
        if r.outcome.failing:
            lines.append(f"{r.case_id},{r.outcome.value}")
            n += 1
    atomic_write_text(path, "\n".join(lines) + "\n")
    return n
