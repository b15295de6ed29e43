"""Mutant decoders: every mutation applies to the current reference source; the reference passes
every required case and a handful of mutants are each killed by a case (the full score is
`fbaconf suites mutants`, or benchmarks/bench_mutants.py)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time

import pytest

from fbaconf.conformance.suite import golden_root, load_suites
from fbaconf.harness.adapters import Job, ManifestError, resolve
from fbaconf.harness.runner import RunContext, run_case
from fbaconf.isolation.endings import EndingKind
from fbaconf.mutation import own, run
from fbaconf.mutation.core import Mutant, snippet_count


def test_at_least_30_mutants_each_naming_its_place():
    assert len(own.MUTANTS) >= 30
    for m in own.MUTANTS.values():
        assert m.description and ":" in m.where
        assert (m.patch is None) == bool(m.old), m.name


@pytest.mark.parametrize("name", [m.name for m in own.MUTANTS_LIST if m.patch is None])
def test_source_snippet_occurs_once(name):
    """A refactoring of the reference must not silently turn a mutant into the reference."""
    assert snippet_count(own.MUTANTS[name]) == 1


def test_snippet_count_sees_a_missing_and_a_repeated_snippet():
    where = "fbaconf.bitstreams.decoder:_Decoder.plane"
    assert snippet_count(Mutant("x", where, "", old="no such text in the source", new="")) == 0
    assert snippet_count(Mutant("x", where, "", old="self", new="")) > 1


def test_independent_set_is_large_named_and_tagged():
    """100+ mutants written from the spec notes alone, each naming the rule it breaks."""
    ind = [m for m in own.MUTANTS_LIST if m.family == "independent"]
    assert len(ind) >= 100
    assert len(set(m.name for m in own.MUTANTS_LIST)) == len(own.MUTANTS_LIST)
    for m in ind:
        assert m.name.startswith("ind-") and m.rule and m.description, m.name
    assert {m.family for m in own.MUTANTS_LIST} == set(own.FAMILIES)


def test_score_leaves_equivalent_mutants_out():
    ind = [m for m in own.MUTANTS_LIST if m.family == "independent"]
    eq = [m.name for m in ind if m.equivalent]
    rows = [{"mutant": m.name, "killed": not m.equivalent} for m in ind]
    assert run.score(rows, "independent") == (len(ind) - len(eq), len(ind) - len(eq), len(eq))
    rows[0]["killed"] = False
    assert run.score(rows, "independent")[0] == len(ind) - len(eq) - (0 if ind[0].equivalent else 1)


def test_a_source_mutant_reaches_the_modules_that_imported_its_function():
    """engine.py does ``from .faceparams import fapu_from_feature_points`` at import time: the
    mutant of faceparams' function must replace that name too, or the mutant never runs (it
    survived every case until core._rebind)."""
    code = (
        "from fbaconf.mutation import own\n"
        "from fbaconf.mutation.core import apply_mutant\n"
        "from fbaconf.animation import calibrate, engine, faceparams\n"
        "old = faceparams.fapu_from_feature_points\n"
        "apply_mutant(own.MUTANTS['wrong-fapu'])\n"
        "new = faceparams.fapu_from_feature_points\n"
        "import sys\n"
        "left = [n for n, m in sys.modules.items() if n.startswith('fbaconf') and m is not None\n"
        "        and any(v is old for v in vars(m).values())]\n"
        "print(new is not old, engine.fapu_from_feature_points is new, calibrate.fapu_from_feature_points is new,"
        " left)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.stdout.split() == ["True", "True", "True", "[]"], r.stdout + r.stderr


def test_reference_passes_and_mutants_are_killed():
    """Three mutants are killed; the unmutated reference, run the way the mutants run (both
    output formats), passes one case of every suite (its cheapest, in the mutants' own order) —
    every case of every suite is run through the harness by tests/integration/test_harness.py."""
    res = run.run_all(["prediction-sign", "ignore-retained", "wrong-fapu"], jobs=2)
    assert all(r["killed"] for r in res), res
    picked = [min(s.cases, key=run._case_cost) for s in load_suites()]
    out = run.run_mutant(None, stop_at_first=False, cases=picked)  # None: the reference, unmutated
    assert not out["killed"] and out["ran"] == out["total"] >= len(picked), out


def test_mutant_adapter_manifest(tmp_path):
    a = resolve("mutant")
    assert a.mutant in own.MUTANTS and a.claims == ["predictable@2"]
    bad = tmp_path / "m.toml"
    bad.write_text(open(a.manifest_path).read().replace('mutant = "prediction-sign"', 'mutant = "no-such"'))
    with pytest.raises(ManifestError):
        resolve(bad)


def test_a_mutant_rejects_through_its_adapter_as_it_does_in_process(tmp_path):
    """The mutant decoder program's own rejection (exit 2, a typed error naming its rule) is a
    rejection through the bundled adapter too, as in the in-process run: the same outcome and
    ending for the same case, not a crash of the adapter (explain reruns a run's failing cases
    through its decoder and takes a changed ending for undefined behaviour)."""
    name, case_id = "viseme-prediction-sign", "simple-l1-core/blend-64"
    (case,) = [c for s in load_suites() for c in s.cases if c.full_id == case_id]
    inproc = _run(name, [case_id])  # in a process of its own: a mutant patches the process it runs in
    assert {f["outcome"] for f in inproc["failing"]} == {"Fail"}, inproc
    m = tmp_path / "m.toml"
    text = open(resolve("mutant").manifest_path).read()
    m.write_text(text.replace('"prediction-sign"', f'"{name}"').replace('name = "mutant"', 'name = "mutant-x"'))
    adapter = resolve(m)
    adapter.outputs = ["faps"]
    ctx = RunContext(adapter, "predictable@2", tmp_path / "out", golden_root(), False, tmp_path)
    r = run_case(ctx, case)
    assert (r.outcome.value, r.ending) == ("Fail", "reject"), (r.outcome, r.ending, r.message)
    assert "[rule viseme-select-range]" in r.message and "RuntimeError" not in r.message


def test_the_mutant_adapter_writes_what_the_case_compares_and_times_out_as_a_timeout(tmp_path, monkeypatch):
    """The bundled adapter asks the mutant program for the outputs the case compares only (as the
    reference adapter writes them): a FAPs case of 16,500 frames rendered as images ran past the
    limit. A program killed at the limit is a timeout of the decoder, not a crash of the adapter."""
    adapter = resolve("mutant")  # outputs faps, vertices and images, as shipped
    values = {k: str(tmp_path / k) for k in ("input", "faps_out", "vertices_out", "images_dir")}
    job = Job(workdir=tmp_path, values=values, unwanted=frozenset(("vertices_out", "images_dir")))
    seen: list[list[str]] = []

    def finished(argv, **kw):
        seen.append(argv)
        return subprocess.CompletedProcess(argv, 0, "", "")

    monkeypatch.setattr(run.subprocess, "run", finished)
    assert adapter.execute(job).ending.kind == EndingKind.DECODED
    assert "--faps-out" in seen[0] and "--vertices-out" not in seen[0] and "--images-dir" not in seen[0]
    adapter.execute(Job(workdir=tmp_path, values=values))
    assert {"--faps-out", "--vertices-out", "--images-dir"} <= set(seen[1])

    def too_long(argv, timeout, **kw):
        time.sleep(timeout)  # what subprocess.run does before it kills the program
        raise subprocess.TimeoutExpired(argv, timeout)

    monkeypatch.setattr(run.subprocess, "run", too_long)
    adapter.limits = dataclasses.replace(adapter.limits, timeout_s=0.05)
    assert adapter.execute(job).ending.kind == EndingKind.TIMEOUT


# The rules of the cases independent faulty decoders got past: each with a mutant that breaks it and the
# case that must kill it.
_RUN = (
    "import json, sys\n"
    "from fbaconf.conformance.suite import load_suites\n"
    "from fbaconf.mutation import run\n"
    "ids = sys.argv[2:]\n"
    "cases = [c for s in load_suites() for c in s.cases if c.full_id in ids]\n"
    "assert sorted(c.full_id for c in cases) == sorted(ids), ids\n"
    "name = None if sys.argv[1] == 'reference' else sys.argv[1]\n"
    "print(json.dumps(run.run_mutant(name, cases=cases, stop_at_first=False)))\n"
)
MARKERS = [f"simple-l1-error/list-marker-{x}" for x in ("i-max", "i-min", "p-max", "p-min")]
GUARDS = {
    "hl-alphabet-first-quant": ["simple-l1-core/high-level-quant-change"],
    "hl-alphabet-floor": ["simple-l1-core/high-level-quant-change"],
    "hl-alphabet-ceil": ["simple-l1-core/high-level-quant-d5"],
    "viseme-select-unchecked": ["simple-l1-error/viseme-select-range"],
    "pred-clamped-to-intra-range": ["simple-l1-core/pred-beyond-intra-range"],
    "pred-outside-intra-rejected": ["simple-l1-core/pred-beyond-intra-range"],
    **{f"list-marker-unchecked-{c.rsplit('list-marker-', 1)[1]}": [c] for c in MARKERS},
}


def _run(name: str, ids: list[str]) -> dict:
    r = subprocess.run([sys.executable, "-c", _RUN, name, *ids], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return __import__("json").loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("name", sorted(GUARDS))
def test_each_new_rule_has_a_mutant_its_case_kills(name):
    """The mutant fails exactly its case(s); a list-marker mutant is run on all four marker cases
    and fails only its own list's (so each of the four cases is needed)."""
    ids = MARKERS if name.startswith("list-marker-") else GUARDS[name]
    out = _run(name, ids)
    failed = {f["case"].removesuffix(" (fap)") for f in out["failing"]}  # in either output format
    assert out["killed"] and sorted(failed) == GUARDS[name], out


def test_the_reference_passes_the_new_cases():
    out = _run("reference", sorted({c for ids in GUARDS.values() for c in ids} | set(MARKERS)))
    assert not out["killed"] and out["ran"] == out["total"], out
