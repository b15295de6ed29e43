"""Mutation score of the committed suites: every mutant decoder of mutation/own.py against
the required cases of predictable@2 (each mutant in its own process). Prints the table, the
wall time, and last `mutation score: K/N` (same as `fbaconf suites mutants`).

    python benchmarks/bench_mutants.py [-j N]
"""

from __future__ import annotations

import argparse
import time

from fbaconf.mutation import run


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("-j", "--jobs", type=int, default=None)
    a = ap.parse_args()
    t0 = time.perf_counter()
    res = run.run_all(jobs=a.jobs)
    text = run.format_results(res).splitlines()
    print("\n".join(text[:-1]))
    print(f"wall time: {time.perf_counter() - t0:.1f} s for {len(res)} mutants")
    print(text[-1])


if __name__ == "__main__":
    main()
