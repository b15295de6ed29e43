"""Mutant decoders: every mutation applies to the current reference source; the reference passes
every required case and a handful of mutants are each killed by a case (the full score is
`fbaconf suites mutants`, or benchmarks/bench_mutants.py)."""
from __future__ import annotations

import pytest

from fbaconf.harness import mutants
from fbaconf.harness.mutant_core import Mutant, snippet_count


def test_at_least_30_mutants_each_naming_its_place():
    assert len(mutants.MUTANTS) >= 30
    for m in mutants.MUTANTS.values():
        assert m.description and ":" in m.where
        assert (m.patch is None) == bool(m.old), m.name


@pytest.mark.parametrize("name", [m.name for m in mutants.MUTANTS_LIST if m.patch is None])
def test_source_snippet_occurs_once(name):
    """A refactoring of the reference must not silently turn a mutant into the reference."""
    assert snippet_count(mutants.MUTANTS[name]) == 1


def test_snippet_count_sees_a_missing_and_a_repeated_snippet():
    where = "fbaconf.bitstreams.decoder:_Decoder.plane"
    assert snippet_count(Mutant("x", where, "", old="no such text in the source", new="")) == 0
    assert snippet_count(Mutant("x", where, "", old="self", new="")) > 1


def test_independent_set_is_large_named_and_tagged():
    """Issue 15: 100+ mutants written from the spec notes alone, each naming the rule it breaks."""
    ind = [m for m in mutants.MUTANTS_LIST if m.family == "independent"]
    assert len(ind) >= 100
    assert len(set(m.name for m in mutants.MUTANTS_LIST)) == len(mutants.MUTANTS_LIST)
    for m in ind:
        assert m.name.startswith("ind-") and m.rule and m.description, m.name
    assert {m.family for m in mutants.MUTANTS_LIST} == set(mutants.FAMILIES)


def test_score_leaves_equivalent_mutants_out():
    ind = [m for m in mutants.MUTANTS_LIST if m.family == "independent"]
    eq = [m.name for m in ind if m.equivalent]
    rows = [{"mutant": m.name, "killed": not m.equivalent} for m in ind]
    assert mutants.score(rows, "independent") == (len(ind) - len(eq), len(ind) - len(eq), len(eq))
    rows[0]["killed"] = False
    assert mutants.score(rows, "independent")[0] == len(ind) - len(eq) - (0 if ind[0].equivalent else 1)


def test_reference_passes_and_mutants_are_killed():
    res = mutants.run_all(["prediction-sign", "ignore-retained", "fit-parent-order"], jobs=2)
    assert all(r["killed"] for r in res), res
    ref = mutants.run_all.__wrapped__ if hasattr(mutants.run_all, "__wrapped__") else None
    del ref
    import json
    import subprocess
    import sys
    p = subprocess.run([sys.executable, "-m", "fbaconf.harness.mutants", "run", "reference", "--all-cases"],
                       capture_output=True, text=True, timeout=600)
    out = json.loads(p.stdout.strip().splitlines()[-1])
    assert not out["killed"] and out["ran"] == out["total"] > 40, out


def test_mutant_adapter_manifest(tmp_path):
    from fbaconf.harness.adapters import resolve
    a = resolve("mutant")
    assert a.mutant in mutants.MUTANTS and a.claims == ["predictable@2"]
    bad = tmp_path / "m.toml"
    bad.write_text((mutants.__file__ and open(a.manifest_path).read()).replace('mutant = "prediction-sign"',
                                                                                'mutant = "no-such"'))
    with pytest.raises(Exception):
        resolve(bad)
