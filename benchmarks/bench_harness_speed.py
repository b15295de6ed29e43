"""Speed measurement of the bundled reference decoder (what ``fbaconf bench`` reports).

Measures the reference decoder as a subprocess (``--decoder reference``: process start-up
included in each run, separated by the fit) and in-process (``reference-inprocess``), decode
and render, against the minimums of each adapter's highest claim and of simple@1, and prints
per-frame cost, start-up, rate, required rate, the fit's r², the verdict with the machine's
load behind it (the decoder's CPU time and wait, the CPU others used) and the time the
measurement took. Also checks the harness's own accuracy on a synthetic decoder with a known start-up
(0.3 s) and per-frame cost (2 ms), as the acceptance test does.

    python benchmarks/bench_harness_speed.py [--repeats N] [--only reference|reference-inprocess|accuracy]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import textwrap
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from fbaconf.harness.adapters import load_manifest, resolve
from fbaconf.harness.bench import render_table
from fbaconf.harness.speed import measure as speed


def reference(name: str, repeats: int) -> None:
    a = resolve(name)
    claim = speed.highest_claim(a)
    t0 = time.perf_counter()
    res = speed.measure_claim(a, claim, repeats=repeats)
    dt = time.perf_counter() - t0
    print(f"\n== {name} ({a.kind}), claim {claim}: measured in {dt:.1f} s")
    print(render_table(res))
    for r in res:
        lengths = sorted({s["frames"] for s in r.samples})
        print(
            f"  {r.operation}: lengths {lengths} x {repeats}, fit r2 {r.fit_r2:.4f}; "
            f"simple@1 minimum {speed.required_rate('simple@1', r.operation)[0]:g} fps -> "
            f"{'PASS' if r.rate_fps >= speed.required_rate('simple@1', r.operation)[0] else 'FAIL'}"
        )
        print(f"    {r.verdict}: {r.reason}")


def accuracy(repeats: int) -> None:
    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        script = d / "timed.py"
        # sleeps 0.3 s and 2 ms a frame, then writes the reference decoding the speed check asks
        # for (its cost, ~0.03 ms a frame, adds to the 2 ms)
        script.write_text(
            textwrap.dedent("""\
            import sys, time
            time.sleep(0.3)
            time.sleep(0.002 * int(sys.argv[1]))
            from fbaconf.reference.pipeline import reference_outputs
            reference_outputs(sys.argv[3], faps_out=sys.argv[2])
        """)
        )
        m = d / "timed.toml"
        m.write_text(
            f'name = "timed"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
            f'[commands]\ndecode = ["{{python}}", "{script}", "{{frames}}", "{{faps_out}}", "{{input}}"]\n'
        )
        a = load_manifest(m)
        for label, kw in (("fixed lengths 20,160,320", {"lengths": [20, 160, 320]}), ("adaptive lengths", {})):
            t0 = time.perf_counter()
            r = speed.measure(a, "simple@1", "decode", repeats=repeats, **kw)
            print(
                f"  {label}: per-frame {r.per_frame_s * 1000:.4f} ms (true 2 ms, error "
                f"{r.per_frame_s / 0.002 - 1:+.2%}), start-up {r.startup_s:.3f} s (0.3 s + interpreter), "
                f"r2 {r.fit_r2:.4f}, {time.perf_counter() - t0:.1f} s"
            )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--only", choices=("reference", "reference-inprocess", "accuracy"))
    a = ap.parse_args()
    print(
        f"python {sys.version.split()[0]}, {os.cpu_count()} CPUs, load average "
        f"{', '.join(f'{x:.2f}' for x in os.getloadavg())}"
    )
    if a.only in (None, "accuracy"):
        print("\n== accuracy: synthetic decoder, start-up 0.3 s, 2 ms/frame")
        accuracy(a.repeats)
    for name in ("reference-inprocess", "reference"):
        if a.only in (None, name):
            reference(name, a.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
