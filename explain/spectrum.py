"""Fault localisation over a run's cases: which features the failing cases share that the
passing ones do not, and a greedy grouping of the failing cases into causes.

The score of a feature f is Ochiai's, ``ef / sqrt(F * (ef + ep))`` (ef, ep: failing and passing
cases with f; F: failing cases still unexplained): 1 when f is in every unexplained failing case
and in no passing one. (Weighting it by the share of passing cases without f lifted the mutant
decoders' ranking, ``benchmarks/bench_explain_mutants.py``, from 41 to 43 of 50 first, and lost
five of Xface's confirmed quirks to content features: real players come first.)
Causes are taken greedily: the best feature explains the failing cases that have it, those leave
the pool, the scores are taken again over the rest, until every failing case
is explained or no feature is left in any of them. Ties go to the feature that explains more
cases, then to the rarer one (fewer cases of the run have it), then by name, so the grouping is the
same on every machine; :func:`candidates` gives the tied best, which the confirming edits separate.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class CaseView:
    """What explain knows of one case of a run."""

    case_id: str
    outcome: str
    failing: bool  # the decoder misbehaved on it (Fail, Crash, Timeout)
    passing: bool  # Pass or QualityWarning
    features: frozenset[str]
    divergence: str = ""  # where its output first left the expected one, in words


@dataclass(frozen=True)
class Score:
    feature: str
    ochiai: float
    failed: int  # unexplained failing cases with the feature
    passed: int  # passing cases with it
    seen: int  # cases of the run with it


def scores(views: Sequence[CaseView], pool: Iterable[str] | None = None) -> list[Score]:
    """Every feature of the failing cases in ``pool`` (default: all failing), best first."""
    failing_ids = set(pool) if pool is not None else {v.case_id for v in views if v.failing}
    failing = [v for v in views if v.case_id in failing_ids]
    passing = [v for v in views if v.passing]
    n_fail = len(failing)
    if not n_fail:
        return []
    ef: dict[str, int] = {}
    for v in failing:
        for f in v.features:
            ef[f] = ef.get(f, 0) + 1
    ep = {f: sum(1 for v in passing if f in v.features) for f in ef}
    seen = {f: sum(1 for v in views if f in v.features) for f in ef}
    out = [Score(f, ef[f] / math.sqrt(n_fail * (ef[f] + ep[f])), ef[f], ep[f], seen[f]) for f in ef]
    return sorted(out, key=_order)


def _order(s: Score) -> tuple[float, int, int, str]:
    return (-round(s.ochiai, 9), -s.failed, s.seen, s.feature)


def aliases(views: Sequence[CaseView], feature: str) -> list[str]:
    """The other features that every case of the run has exactly when it has ``feature``: no spectrum
    can tell them apart (only a case with one and not the other could), so a cause names them all."""
    column = frozenset(v.case_id for v in views if feature in v.features)
    others = {f for v in views if v.case_id in column for f in v.features} - {feature}
    return sorted(f for f in others if frozenset(v.case_id for v in views if f in v.features) == column)


def candidates(ranked: Sequence[Score], k: int) -> list[Score]:
    """The best ``k`` features that explain something (the first is the ranking's choice)."""
    return [s for s in ranked if s.failed][:k]


def explained_by(views: Sequence[CaseView], feature: str, pool: Iterable[str]) -> list[str]:
    """The unexplained failing cases (of ``pool``) that have ``feature``."""
    left = set(pool)
    return [v.case_id for v in views if v.case_id in left and feature in v.features]
