"""Wall time of the full certification of the reference decoder for the highest claim:
`fbaconf certify --decoder reference-inprocess --claim predictable@2 -o DIR [--no-speed]`
(target: < 60 s on 2 cores), and of the same required cases with only the compared outputs
produced (what the in-process reference would cost if the harness told it the case's stages).

    python benchmarks/bench_certify.py [--speed]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

from fbaconf.mutation.run import run_mutant


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--speed", action="store_true", help="include the speed measurement")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        argv = [
            sys.executable,
            "-m",
            "fbaconf.cli",
            "certify",
            "--decoder",
            "reference-inprocess",
            "--claim",
            "predictable@2",
            "-o",
            os.path.join(tmp, "cert"),
        ] + ([] if a.speed else ["--no-speed"])
        t0 = time.perf_counter()
        p = subprocess.run(argv, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        print(p.stdout.strip().splitlines()[-1] if p.stdout.strip() else p.stderr[-500:])
        print(f"certify predictable@2 ({'with' if a.speed else 'without'} speed): {dt:.1f} s wall, exit {p.returncode}")
    t0 = time.perf_counter()
    r = run_mutant(None, "predictable@2", stop_at_first=False)
    print(
        f"same {r['total']} cases, only the compared outputs produced: {time.perf_counter() - t0:.1f} s wall "
        f"({'all pass' if not r['killed'] else 'FAILURES: ' + str(r['failing'][:2])})"
    )
    print(f"load average: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
