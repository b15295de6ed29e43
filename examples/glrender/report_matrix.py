#!/usr/bin/env python3
"""Collect the image-stage verdicts and metrics of ``fbaconf run`` folders (one per variant)
into Markdown tables (for README.md) and one JSON file.

    for v in ...; do fbaconf run --decoder examples/glrender/manifests/$v.toml \\
        --suite calibration-l1-core ... -o RUNS/$v; done
    python examples/glrender/report_matrix.py RUNS [--json matrix.json]

Cell: outcome letter (P Pass, Q QualityWarning, F Fail, N NotSupported), then
violations_max (most pixels over the per-pixel limit in one frame; the limit is 32) /
interior_deltae_mean_max (largest interior CIEDE2000 mean of a frame; fail above 0.75).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from glrender import FAITHFUL, WRONG

KEYS = (
    "violations_max",
    "violation_limit",
    "interior_deltae_mean_max",
    "interior_deltae_p99_max",
    "deltae_mean_max",
    "psnr_min",
    "max_error",
    "frames_failing",
    "frames_warning",
    "frames_compared",
)


def collect(runs: Path) -> dict:
    out = {}
    for v in FAITHFUL + WRONG:
        rep = runs / v / "report.json"
        if not rep.is_file():
            continue
        r = json.loads(rep.read_text())
        rows = {}
        for res in r["results"]:
            st = [s for s in res["stages"] if s["stage"] == "images"]
            if st:
                s = st[0]
                rows[res["case_id"]] = {"outcome": s["outcome"], **{k: s["metrics"].get(k) for k in KEYS}}
            elif res["outcome"] in ("NotSupported", "Error", "Crash", "Timeout"):
                rows[res["case_id"]] = {"outcome": res["outcome"], "message": res["message"][:200]}
        out[v] = rows
    return out


def cell(x: dict) -> str:
    o = x["outcome"][0]
    if x.get("violations_max") is None:
        return o
    return f"{o} {int(x['violations_max'])}/{x['interior_deltae_mean_max']:.2f}"


def markdown(m: dict) -> str:
    lines = []
    cases = sorted({c for rows in m.values() for c in rows}, key=lambda c: (c.split("/")[0], c))
    lines.append(
        "| variant | Fail | QualityWarning | Pass | NotSupported | most violating px in a frame | "
        "largest interior ΔE mean | largest interior ΔE p99 | lowest PSNR dB |"
    )
    lines.append("|---|---|---|---|---|---|---|---|---|")
    for v, rows in m.items():
        outs = [x["outcome"] for x in rows.values()]
        vals = [x for x in rows.values() if x.get("violations_max") is not None]
        f = lambda k, fn: f"{fn(x[k] for x in vals):.4g}" if vals else "–"
        lines.append(
            f"| {v} | {outs.count('Fail')} | {outs.count('QualityWarning')} | {outs.count('Pass')} | "
            f"{outs.count('NotSupported')} | {f('violations_max', max)} | "
            f"{f('interior_deltae_mean_max', max)} | {f('interior_deltae_p99_max', max)} | "
            f"{f('psnr_min', min)} |"
        )
    for title, group in (("Faithful variants", FAITHFUL), ("Wrong variants", WRONG)):
        vs = [v for v in group if v in m and any(x.get("violations_max") is not None for x in m[v].values())]
        lines += [
            "",
            f"**{title}** (cell: verdict, violations_max / interior ΔE mean max)",
            "",
            "| case | " + " | ".join(vs) + " |",
            "|---|" + "---|" * len(vs),
        ]
        for c in cases:
            lines.append(f"| {c} | " + " | ".join(cell(m[v][c]) if c in m[v] else "" for v in vs) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("runs", type=Path)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)
    m = collect(a.runs)
    if a.json:
        a.json.write_text(json.dumps(m, indent=1, sort_keys=True) + "\n")
    sys.stdout.write(markdown(m))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
