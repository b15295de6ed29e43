"""Cases and fuzz shards on a local Dask cluster against the embedded pool, side by side.
On one machine a cluster only adds scheduling cost: the ratio says how much, so a
user knows what a cluster must win back by adding machines.

* ``run``: the reference decoder over the simple-l1 suites, ``-j 2`` vs ``--cluster local:2``;
* ``fuzz``: the planted skipchain decoder, one process at a time (``-j 1``) vs two shards on
  ``--cluster local:2`` (execs/s of the whole campaign).

    python benchmarks/bench_cluster.py [--seconds S]
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _skipchain import build


def fbaconf(*args: str) -> tuple[float, str]:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "fbaconf", *args], capture_output=True, text=True)
    return time.perf_counter() - t0, r.stdout + r.stderr


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="fuzzing time per side")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-cluster-"))
    try:
        rows = []
        for label, extra in (("run -j 2", ["-j", "2"]), ("run --cluster local:2", ["--cluster", "local:2"])):
            dt, _out = fbaconf(
                "run",
                "--decoder",
                "reference",
                "--suite",
                "simple-l1-core",
                "--suite",
                "simple-l1-error",
                "-o",
                str(tmp / label.replace(" ", "_")),
                "--no-progress",
                *extra,
            )
            rows.append((label, dt, "s wall"))
        print("conformance run, reference decoder, simple-l1-core + simple-l1-error")
        for label, dt, unit in rows:
            print(f"  {label:<28} {dt:8.1f} {unit}")
        print(f"  cluster / pool wall time     {rows[1][1] / rows[0][1]:8.2f}")
        cc = shutil.which("cc") or shutil.which("gcc")
        if cc is None:
            print("no C compiler: fuzz comparison skipped")
            return 0
        m = build(cc, tmp)
        rates = []
        for label, extra in (("fuzz -j 1", []), ("fuzz --cluster local:2", ["--cluster", "local:2"])):
            out = tmp / label.replace(" ", "_")
            fbaconf(
                "fuzz",
                "--decoder",
                str(m),
                "--seconds",
                str(args.seconds),
                "-o",
                str(out),
                "--no-progress",
                "--minimise-seconds",
                "2",
                *extra,
            )
            doc = json.loads((out / "fuzz.json").read_text())
            rates.append((label, doc["execs"] / max(1e-9, doc["seconds"]), doc["findings"]))
        print(f"fuzzing the planted skipchain decoder, {args.seconds:g} s")
        for label, rate, nf in rates:
            print(f"  {label:<28} {rate:8,.0f} execs/s (wall, minimisation included), {nf} finding(s)")
        print(f"  cluster / one process        {rates[1][1] / rates[0][1]:8.2f}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
