"""How often ``fbaconf explain`` names the mutated rule: each mutant decoder of a hand-annotated
sample runs every case of predictable@2 (``python -m fbaconf.mutation.run run NAME --all-cases``,
its own process), explain ranks the causes of its failures (the spectrum over the cases'
features, each failing case's taken up to its first difference, which the mutant's run records;
with ``--confirm``, as explain runs on a run of a decoder it can run: each cause confirmed by
running the mutant, through the bundled mutant manifest, on variants without its trigger, and the
failing cases that did not decode run again), and a mutant scores when a cause whose
feature matches one of the coverage points written beside it below (by hand, from the mutant's
description and the coverage model, not from explain's output) comes first, or in the first three.

    python benchmarks/bench_explain_mutants.py [-j N] [--keep DIR] [--confirm] [NAME ...]

Prints one line per mutant (rank of the first matching cause, the top cause), then the shares
``first: K/N`` and ``top 3: K/N`` and the wall and CPU time.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from fbaconf.conformance.suite import load_suites
from fbaconf.explain.causes import explain
from fbaconf.harness.adapters import Adapter, resolve
from fbaconf.harness.results import CaseResult, Outcome, RunRecord, StageResult
from fbaconf.harness.selection import claim_covers

CLAIM = "predictable@2"
# mutant -> the coverage points (fnmatch patterns) that name the rule it breaks; a point the model
# gains later that names the same rule joins its mutants' rows (mask.keep-or-free: where D3's types
# 01 and 10 decode differently; lists.min-below-zero: where a min bound's sign matters;
# facedef.transform.<field>.driven: where that field moves the model)
EXPECTED: dict[str, tuple[str, ...]] = {
    "time-code-ignored": ("timecode.*",),
    "time-code-minutes-as-seconds": ("timecode.*",),
    "skip-not-counted": ("skip.*",),
    "skip-chain-not-continued": ("skip.chain",),
    "skip-not-in-time": ("skip.*",),
    "frequency-offset-ignored": ("rate.offset",),
    "ignore-retained": ("mask.type-1", "status.retained"),
    "minmax-lists-ignored": ("lists.*",),
    "minmax-sign-swapped": ("lists.*",),
    "stuffing-not-removed": ("arith.stuffing",),
    "model-no-halving": ("arith.model-rescale",),
    "viseme-prediction-sign": ("highlevel.predicted", "fap.1"),  # FAP 1 is the viseme
    "dct-dc-prediction-ignored": ("dct.predicted",),
    "dct-scale-index-off-by-one": ("dct.*",),
    "lookahead-rewind-at-3": ("arith.lookahead-rewind-3", "arith.lookahead-3"),
    "lookahead-rewind-at-9": ("arith.lookahead-rewind-9", "arith.lookahead-9"),
    "lookahead-error-at-5": ("arith.lookahead-error-5",),
    "lookahead-error-at-12": ("arith.lookahead-error-12",),
    "retained-rescaled": ("retained.quant-change",),
    "faces-share-lists": ("faces.*",),
    "lists-reset-at-intra": ("lists.persist-intra",),
    "fit-denominator-ignored": ("fit.denominator",),
    "fit-impulse-ignored": ("fit.impulse",),
    "fit-topological-order": ("fit.chain", "fit.derived"),
    "transform-axis-sign": ("facedef.transform.rotation", "facedef.transform.rotation.driven"),
    "transform-scale-absolute": ("facedef.transform.scale", "facedef.transform.scale.driven"),
    "calibration-ignores-subset": ("calibration.subset",),
    "left-right-fill-missing": ("lrfill.*",),
    "ind-syn-step-q0-uses-qp": ("fap_quant.0",),
    # decisions are rules too: the checker's diagnostic point for the decision the mutant breaks
    "default-rate-30": ("rate.none", "diag.FAP-DECISION-004"),  # D6: 25 Hz when no rate is signalled
    "mask-type-2-as-1": ("mask.type-2", "diag.FAP-DECISION-006", "mask.keep-or-free"),  # D3: mask type 10 frees
    "ind-syn-mask-type-10-is-all": ("mask.type-2", "diag.FAP-DECISION-006"),
    # written before their first measurement (the ones above were measured once before the two
    # decision diagnostics were added to their rows)
    "ind-syn-frame-rate-offset-before-seconds": ("rate.offset",),
    "ind-syn-skip-chain-last-chunk-only": ("skip.chain",),
    "ind-syn-skip-chain-stops-at-14": ("skip.chain",),
    "ind-syn-mask-01-10-swapped": ("mask.type-1", "mask.type-2", "diag.FAP-DECISION-006", "mask.keep-or-free"),
    "ind-syn-mask-00-free": ("mask.type-0", "status.retained"),
    "ind-syn-mask-11-last-fap-missing": ("mask.type-3",),
    "ind-syn-list-order-min-first": ("lists.*",),
    "ind-syn-list-min-positive": ("lists.i_min", "lists.p_min", "lists.min-below-zero"),
    "ind-syn-intra-uses-p-list": ("lists.*",),
    "ind-syn-p-uses-i-list": ("lists.*",),
    "ind-syn-step-ignores-qp": ("fap_quant.*",),
    "ind-syn-viseme-blend-p-step-missing": ("highlevel.predicted", "highlevel.quantised"),
    "ind-syn-expression-intra-order": ("highlevel.*", "expression.*", "fap.2"),  # FAP 2 is the expression
    "lookahead-rewind-at-11": ("arith.lookahead-rewind-11", "arith.lookahead-11"),
    "lookahead-error-at-2": ("arith.lookahead-error-2",),
    "facedefmesh-zero-top": ("facedef.interval.zero-top",),
    "facedefmesh-no-fapu": ("facedef.mesh",),
    "fit-parent-order": ("fit.fan-in",),
}


def _adapter(name: str, folder: Path) -> Adapter:
    """The mutant ``name`` as a decoder: the bundled mutant manifest with its name."""
    text = Path(str(resolve("mutant").manifest_path)).read_text()
    m = folder / f"{name}.toml"
    m.write_text(
        text.replace('mutant = "prediction-sign"', f'mutant = "{name}"').replace(
            'name = "mutant"', f'name = "mutant-{name}"'
        )
    )
    return resolve(str(m))


def _mutant_run(name: str, keep: Path | None = None) -> dict:
    if keep is not None and (keep / f"{name}.json").is_file():  # a run kept earlier: rank it again
        return json.loads((keep / f"{name}.json").read_text())
    argv = [sys.executable, "-m", "fbaconf.mutation.run", "run", name, "--claim", CLAIM, "--all-cases"]
    p = subprocess.run(argv, capture_output=True, text=True, timeout=1800)
    for line in reversed(p.stdout.splitlines()):
        if line.startswith("{"):
            if keep is not None:
                keep.mkdir(parents=True, exist_ok=True)
                (keep / f"{name}.json").write_text(line + "\n")
            return json.loads(line)
    return {"mutant": name, "killed": False, "error": p.stderr[-300:]}


def rank(res: dict, cases: dict, adapter: Adapter | None = None) -> tuple[int | None, str]:
    """(1-based rank of the first cause matching the mutant's points, the top cause's feature);
    with ``adapter`` (the mutant as a decoder) explain confirms its causes as it does for a run."""
    failing: dict[str, CaseResult] = {}
    for f in res.get("failing", []):  # a case's first format's entry, and the second's differences
        cid = f["case"].split(" (")[0]
        if cid not in failing and cid in cases:
            c = cases[cid]
            failing[cid] = CaseResult(
                cid, c.suite, c.claim, Outcome(f["outcome"]), kind=c.kind.value, ending=f.get("ending")
            )
        if cid in failing:
            failing[cid].stages.extend(
                StageResult(d["stage"], Outcome.FAIL, first_difference=d["first_difference"])
                for d in f.get("differences", [])
            )
    results = [
        failing.get(cid) or CaseResult(cid, c.suite, c.claim, Outcome.PASS, kind=c.kind.value, ending="decoded")
        for cid, c in cases.items()
    ]
    decoder = {"name": res["mutant"], "inputs": ["fba"]}
    record = RunRecord(decoder=decoder, claim=CLAIM, suites=[], system={}, results=results)
    ex = explain(record, cases, adapter=adapter)
    patterns = EXPECTED[res["mutant"]]
    for i, c in enumerate(ex.causes, 1):
        # a cause names its feature, the features no case of the run tells from it, and those ranked equal
        if any(fnmatch.fnmatchcase(f, p) for f in (c.feature, *c.aliases, *c.tied) for p in patterns):
            return i, ex.causes[0].feature
    return None, ex.causes[0].feature if ex.causes else "-"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-j", "--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--keep", type=Path, help="keep each mutant's run here, and rank a kept run again")
    ap.add_argument(
        "--confirm",
        action="store_true",
        help="explain as it runs on a run: confirming each cause by running the mutant on variants, "
        "and rerunning its failing cases (the bundled mutant manifest; about 100 runs a mutant)",
    )
    ap.add_argument("names", nargs="*")
    a = ap.parse_args()
    names = a.names or list(EXPECTED)
    cases = {c.full_id: c for s in load_suites() for c in s.cases if claim_covers(CLAIM, c.claim)}
    t0, c0 = time.perf_counter(), os.times()
    with ThreadPoolExecutor(max_workers=a.jobs) as ex:
        runs = list(ex.map(lambda n: _mutant_run(n, a.keep), names))
    killed = [res for res in runs if res.get("killed")]
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(max_workers=a.jobs) as ex:
        ranks = list(
            ex.map(lambda res: rank(res, cases, _adapter(res["mutant"], Path(tmp)) if a.confirm else None), killed)
        )
    first = top3 = scored = 0
    for res in runs:
        if not res.get("killed"):
            print(f"{res['mutant']:38s} not killed: not scored {res.get('error', '')}")
    for res, (r, top) in zip(killed, ranks):
        scored += 1
        first += r == 1
        top3 += r is not None and r <= 3
        print(f"{res['mutant']:38s} rank {r if r is not None else '-':>2}  top cause {top}")
    t = os.times()
    cpu = (t.children_user + t.children_system + t.user + t.system) - (
        c0.children_user + c0.children_system + c0.user + c0.system
    )
    print(f"first: {first}/{scored} ({100 * first / max(scored, 1):.0f} %)")
    print(f"top 3: {top3}/{scored} ({100 * top3 / max(scored, 1):.0f} %)")
    print(f"wall {time.perf_counter() - t0:.0f} s, CPU {cpu:.0f} s, {len(names)} mutants, {CLAIM}")


if __name__ == "__main__":
    main()
