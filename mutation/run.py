"""Running mutant decoders against the suites (the mutation score, ``fbaconf suites mutants``).

A mutant is applied to the WHOLE process and never undone, so it always runs in a process of its
own:

- ``python -m fbaconf.mutation.run run NAME [--claim C] [--all-cases]`` applies the mutant and
  runs the required cases of the claim through the harness (in-process reference adapter, one case
  at a time, cheapest first), stopping at the first case that fails ("killed"); prints one JSON
  line.
- ``python -m fbaconf.mutation.run decode NAME ...`` is the reference decoder program
  (``reference.decoder``) with the mutant applied: what :class:`MutantAdapter` (a manifest
  ``python = "fbaconf.mutation.run:MutantAdapter"`` with ``[options] mutant = "NAME"``, bundled as
  ``harness/adapters/mutant.toml``) runs per case, so ``fbaconf run`` can run any mutant like any
  other decoder, in parallel, with no patch leaking into the harness.

``fbaconf suites mutants [-j N]`` runs every mutant (``-j`` processes at a time) and prints the
table and, last, ``mutation score: K/N``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from fbaconf.conformance.suite import CaseKind, golden_root, load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.harness.adapters import OUTPUT_PLACEHOLDER, ManifestError, PythonAdapter, resolve
from fbaconf.harness.runner import RunContext, run_case
from fbaconf.harness.selection import claim_covers
from fbaconf.reference import decoder as refdecoder

from .own import FAMILIES, MUTANTS, MUTANTS_LIST, apply

# ------------------------------------------------------------------ running one mutant


def _case_cost(c) -> tuple:
    order = {"decode": 0, "multi": 1, "error": 3}
    heavy = 2 if "images" in c.stages else 1 if "vertices" in c.stages else 0
    return (order.get(c.kind, 2), heavy, c.frames, c.full_id)


def run_mutant(
    name: str | None,
    claim: str = "predictable@2",
    *,
    stop_at_first: bool = True,
    out_dir: Path | None = None,
    cases=None,
    formats: tuple[str, ...] = ("npz", "fap"),
) -> dict:
    """Apply ``name`` (None: the plain reference) and run the cases of ``claim`` through the
    harness, cheapest first: the required ones and the .fap player cases (the reference reads
    both, and a decoder's .fap reader is code a mutant can break), once with each FAP output
    format in ``formats`` (the second format only for the cases that compare FAPs, only while
    the mutant lives). Returns {mutant, killed, killed_by, failing, ran, total, seconds}."""
    t0 = time.perf_counter()
    if name is not None:
        apply(name)
    adapter = resolve("reference-inprocess")
    all_outputs = list(adapter.outputs)
    if cases is None:
        cases = [c for s in load_suites() for c in s.cases if claim_covers(claim, c.claim)]
    cases = sorted(cases, key=_case_cost)
    if stop_at_first:
        cases = [c for c in cases if c.kind != CaseKind.ERROR] + [c for c in cases if c.kind == CaseKind.ERROR]
    plan = [(c, formats[0]) for c in cases]
    for fmt in formats[1:]:
        plan += [(c, fmt) for c in cases if "faps" in (c.stages or ["faps"]) and c.kind != CaseKind.ERROR]
    failing, ran = [], 0
    with tempfile.TemporaryDirectory(prefix="fbaconf-mutant-") as tmp:
        ctx = RunContext(adapter, claim, Path(out_dir or tmp), golden_root(), False, Path(tmp))
        for c, fmt in plan:
            # produce only what the case compares (the in-process reference renders otherwise)
            adapter.outputs = [s for s in all_outputs if s in (c.stages or ["faps"])] or ["faps"]
            adapter.faps_format = fmt
            r = run_case(ctx, c)
            ran += 1
            if r.outcome.failing:
                failing.append(
                    {
                        "case": c.full_id if fmt == formats[0] else f"{c.full_id} ({fmt})",
                        "outcome": r.outcome.value,
                        "message": r.message[:300],
                        "ending": r.ending,  # how the mutant's decode ended (explain reruns what did not decode)
                        # where it first differed, per stage: explain localises a cause by it
                        "differences": [
                            {"stage": st.stage, "first_difference": st.first_difference}
                            for st in r.stages
                            if st.first_difference
                        ],
                    }
                )
                if stop_at_first:
                    break
    return {
        "mutant": name or "reference",
        "killed": bool(failing),
        "killed_by": failing[0]["case"] if failing else None,
        "failing": failing,
        "ran": ran,
        "total": len(plan),
        "seconds": round(time.perf_counter() - t0, 2),
    }


def run_all(
    names: list[str] | None = None,
    *,
    claim: str = "predictable@2",
    jobs: int | None = None,
    stop_at_first: bool = True,
    timeout: float = 900.0,
) -> list[dict]:
    """Every mutant (or ``names``) in its own process, ``jobs`` at a time."""
    names = names or list(MUTANTS)
    jobs = jobs or os.cpu_count() or 1

    def one(n: str) -> dict:
        argv = [sys.executable, "-m", "fbaconf.mutation.run", "run", n, "--claim", claim]
        if not stop_at_first:
            argv.append("--all-cases")
        try:
            p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"mutant": n, "killed": False, "killed_by": None, "error": f"timed out after {timeout:g} s"}
        for line in reversed(p.stdout.splitlines()):
            if line.startswith("{"):
                return json.loads(line)
        return {
            "mutant": n,
            "killed": False,
            "killed_by": None,
            "error": f"exit {p.returncode}: {p.stderr.strip()[-400:]}",
        }

    with ThreadPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(one, names))


def score(results: list[dict], family: str | None = None) -> tuple[int, int, int]:
    """(killed, scored, equivalent) over ``results`` (of one mutant ``family``, or all)."""
    rows = [r for r in results if family is None or getattr(MUTANTS.get(r["mutant"]), "family", None) == family]
    equivalent = [r for r in rows if getattr(MUTANTS.get(r["mutant"]), "equivalent", "")]
    scored = [r for r in rows if r not in equivalent]
    return sum(1 for r in scored if r["killed"]), len(scored), len(equivalent)


def format_results(results: list[dict]) -> str:
    lines = [f"{'mutant':38s} {'verdict':10s} killed by"]
    for r in results:
        m = MUTANTS.get(r["mutant"])
        eq = getattr(m, "equivalent", "")
        verdict = "killed" if r["killed"] else "equivalent" if eq else "SURVIVED"
        by = r.get("killed_by") or r.get("error") or "-"
        lines.append(f"{r['mutant']:38s} {verdict:10s} {by}")
        if not r["killed"] and m is not None:
            lines.append(f"{'':38s}            ({eq or m.description}; {m.where})")
    for fam in FAMILIES:
        k, n, e = score(results, fam)
        if n or e:
            lines.append(f"{fam} mutants: {k}/{n} killed" + (f", {e} equivalent (not scored)" if e else ""))
    k, n, _ = score(results)
    lines.append(f"mutation score: {k}/{n}")
    return "\n".join(lines)


# ------------------------------------------------------------------ adapter


RULE = re.compile(r" \[rule ([^\]]+)\]$")


class MutantAdapter(PythonAdapter):
    """In-process adapter class for manifests: each case runs the mutant decoder program in a
    subprocess (``python -m fbaconf.mutation.run decode NAME ...``), so the mutant's
    patches never touch the harness process (thread-safe with ``-j``)."""

    supports_multi = True
    description = "fbaconf reference decoder with one injected bug (mutation/own.py)"

    def __init__(self, mutant: str = "") -> None:
        super().__init__()
        if mutant not in MUTANTS:
            raise ManifestError(
                f"[options] mutant = {mutant!r}: unknown (known: {', '.join(MUTANTS)})", rule="manifest-options"
            )
        self.mutant = mutant

    def run(self, job) -> None:
        base = [sys.executable, "-m", "fbaconf.mutation.run", "decode", self.mutant]
        if job.faces:
            argv = (
                base
                + ["decode-multi", "--out-dir", str(job.path("faps_out_dir")), "--format", self.faps_format]
                + list(job.faces)
            )
        else:
            argv = base + ["decode", str(job.path("input"))]
            for opt, key in (("--scene", "scene"), ("--scenario", "scenario")):
                if job.values.get(key):
                    argv += [opt, job.values[key]]
            # only what the case compares, as the reference adapter writes: a case of 16,500
            # frames that compares FAPs is not rendered
            for out, key in OUTPUT_PLACEHOLDER.items():  # the program's options: --faps-out ...
                if out in self.outputs and key not in job.unwanted:
                    argv += [f"--{key.replace('_', '-')}", job.values[key]]
        try:
            p = subprocess.run(argv, capture_output=True, text=True, timeout=self.limits.timeout_s)
        except subprocess.TimeoutExpired:
            return  # killed at the limit: execute() finds the time past it, a timeout (not a crash)
        said = p.stderr.strip().splitlines()[-1] if p.stderr.strip() else ""
        if p.returncode == 2 and said.startswith(refdecoder.ERROR_PREFIX):
            # the program's own rejection (a typed input error): judged as the in-process reference's
            # is, a rejection naming its rule, not a crash of the adapter
            what = said[len(refdecoder.ERROR_PREFIX) :]
            m = RULE.search(what)
            raise FbaconfInputError(what[: m.start()] if m else what, rule=m.group(1) if m else None)
        if p.returncode != 0:
            raise RuntimeError(f"mutant decoder exited {p.returncode}: {p.stderr.strip()[-300:]}")


# ------------------------------------------------------------------ program


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m fbaconf.mutation.run", description="Run one mutant decoder (see the module doc)."
    )
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the suites against one mutant; prints one JSON line")
    r.add_argument("name", help="mutant name, or 'reference' for the unmodified reference")
    r.add_argument("--claim", default="predictable@2")
    r.add_argument("--all-cases", action="store_true")
    d = sub.add_parser("decode", help="the reference decoder program with the mutant applied")
    d.add_argument("name")
    d.add_argument("rest", nargs=argparse.REMAINDER, help="arguments of python -m fbaconf.reference.decoder")
    sub.add_parser("list", help="list the mutants")
    a = ap.parse_args(argv)
    if a.cmd == "list":
        for m in MUTANTS_LIST:
            print(f"{m.name:38s} {m.description}")
        return 0
    if a.name != "reference" and a.name not in MUTANTS:
        print(f"unknown mutant {a.name!r}", file=sys.stderr)
        return 2
    if a.cmd == "decode":
        if a.name != "reference":
            apply(a.name)
        return refdecoder.main(a.rest)
    res = run_mutant(None if a.name == "reference" else a.name, a.claim, stop_at_first=not a.all_cases)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
