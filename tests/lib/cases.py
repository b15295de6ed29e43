"""Conformance cases by full id (``suite/case``), as the committed suites hold them (read afresh
each call: a test may change the objects it gets)."""

from __future__ import annotations

from collections.abc import Iterable

from fbaconf.conformance.suite import Case, load_suites


def cases(ids: Iterable[str]) -> list[Case]:
    ids = list(ids)
    by_id = {c.full_id: c for s in load_suites(names=sorted({i.split("/")[0] for i in ids})) for c in s.cases}
    missing = [i for i in ids if i not in by_id]
    if missing:
        raise KeyError(f"not in the committed suites: {', '.join(missing)}")
    return [by_id[i] for i in ids]


def case(full_id: str) -> Case:
    (c,) = cases([full_id])
    return c
