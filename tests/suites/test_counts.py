"""The case counts the docs print are the built suites' (conformance/counts.py), and each claim's
count is what the harness selects for a decoder of the binary stream (harness/selection.py)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest

from fbaconf.conformance import counts
from fbaconf.conformance.suite import load_suites
from fbaconf.harness.selection import required_for

DOC = Path(__file__).resolve().parents[2] / "docs" / "suites.md"


def test_the_docs_table_is_the_suites_own():
    text = DOC.read_text("utf-8")
    stale = "docs/suites.md is stale: run `fbaconf suites counts --write docs/suites.md`"
    assert counts.table(load_suites()) in text, stale


@pytest.mark.parametrize("claim", counts.CLAIMS)
def test_each_claims_count_is_what_the_harness_requires(claim):
    suites = load_suites()
    decoder = SimpleNamespace(is_player=False)
    assert counts.required(suites, claim) == sum(required_for(claim, c, decoder) for s in suites for c in s.cases)
