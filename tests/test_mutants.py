"""Mutant decoders: every mutation applies to the current reference source; the reference passes
every required case and a handful of mutants are each killed by a case (the full score is
`fbaconf suites mutants`, or benchmarks/bench_mutants.py)."""
from __future__ import annotations

import importlib
import inspect
import textwrap

import pytest

from fbaconf.harness import mutants


def test_at_least_30_mutants_each_naming_its_place():
    assert len(mutants.MUTANTS) >= 30
    for m in mutants.MUTANTS.values():
        assert m.description and ":" in m.where
        assert (m.patch is None) == bool(m.old), m.name


@pytest.mark.parametrize("name", [m.name for m in mutants.MUTANTS_LIST if m.patch is None])
def test_source_snippet_occurs_once(name):
    """A refactoring of the reference must not silently turn a mutant into the reference."""
    m = mutants.MUTANTS[name]
    mod, qual = m.where.split(":")
    owner = importlib.import_module(mod)
    for p in qual.split(".")[:-1]:
        owner = getattr(owner, p)
    raw = inspect.getattr_static(owner, qual.split(".")[-1])
    fn = raw.__func__ if isinstance(raw, (staticmethod, classmethod)) else raw
    assert textwrap.dedent(inspect.getsource(fn)).count(m.old) == 1


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
