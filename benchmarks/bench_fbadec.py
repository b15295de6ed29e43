"""The independent C decoder (examples/fbadec) against the reference, side by side.

Builds fbadec from source into a temporary folder and measures, in one run:

* decode speed through the harness's speed measurement (start-up fitted away), frames/s:
  fbadec, the reference as a subprocess, the reference in-process; fbadec through its
  persistent ``serve`` against one process per sample (per-frame ratio, short-run times);
* per-input cost when fuzzing (fork server, one input at a time, 20 s each, the same seed):
  fbadec and the reference as decoders under test.

    python benchmarks/bench_fbadec.py [--seconds S]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from fbaconf.fuzz.corpus import default_seeds
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness.adapters import resolve
from fbaconf.harness.speed import measure as speed

SRC = Path(__file__).resolve().parent.parent / "examples" / "fbadec"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="fuzzing time per decoder")
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        print("bench_fbadec: no C compiler; nothing measured")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="bench-fbadec-"))
    try:
        subprocess.run(
            [
                cc,
                "-O2",
                "-std=c11",
                "-I",
                str(SRC),
                "-o",
                str(tmp / "fbadec"),
                str(SRC / "fbadec.c"),
                str(SRC / "main.c"),
            ],
            check=True,
        )
        shutil.copy(SRC / "fbadec.toml", tmp / "fbadec.toml")
        decoders = [
            ("fbadec (C, subprocess)", str(tmp / "fbadec.toml")),
            ("reference (Python, subprocess)", "reference"),
            ("reference (Python, in-process)", "reference-inprocess"),
        ]
        print("decode speed, simple@2 streams (harness speed measurement, start-up fitted away)")
        rates = {}
        for label, d in decoders:
            r = speed.measure(resolve(d), "simple@2", "decode", repeats=3)
            rates[label] = r.rate_fps
            print(
                f"  {label:<34} {r.rate_fps:12,.0f} frames/s  ({r.per_frame_s * 1e3:.4f} ms/frame, "
                f"start-up {r.startup_s:+.3f} s)"
            )
        print(f"  fbadec / reference in-process  {rates[decoders[0][0]] / rates[decoders[2][0]]:10.1f}x")
        fb = resolve(decoders[0][1])
        lengths = [2000, 10000, 20000]
        pers = speed.measure(fb, "simple@2", "decode", lengths=lengths, repeats=3)
        spawn = speed.measure(fb, "simple@2", "decode", lengths=lengths, repeats=3, persistent=False)
        short = [
            speed.measure(fb, "simple@2", "decode", lengths=[100, 200], repeats=3, persistent=p) for p in (True, False)
        ]
        t_pers, t_spawn = (statistics.median(s["seconds"] for s in r.samples) for r in short)
        print(
            f"fbadec through [commands] serve against one process per sample: per-frame cost "
            f"{pers.per_frame_s / spawn.per_frame_s:.2f}x (expected near 1); a 100-200 frame run "
            f"{t_pers * 1e3:.1f} ms against {t_spawn * 1e3:.1f} ms ({t_pers / t_spawn:.2f}x: a pipe round trip "
            f"against a sandboxed process start)"
        )
        print(f"fuzzing, one input at a time (fork server), {args.seconds:g} s each, seed 3")
        fz_rates = {}
        for label, d in decoders[:2]:
            t = DecoderTarget(resolve(d), tmp / f"work-{len(fz_rates)}", timeout_s=10.0)
            fz = Fuzzer(
                t,
                default_seeds(),
                FuzzConfig(
                    seed=3,
                    seconds=args.seconds,
                    progress=False,
                    coverage_every=8,
                    minimise_seconds=2,
                    minimise_tests=20,
                ),
            )
            fz.run()
            fz_rates[label] = fz.stats.rate
            print(
                f"  {label:<34} {fz.stats.rate:10,.0f} execs/s ({1000 / max(fz.stats.rate, 1e-9):.2f} ms per input), "
                f"{len(fz.findings)} finding(s)"
            )
        print(f"  fbadec / reference per-input rate {fz_rates[decoders[0][0]] / fz_rates[decoders[1][0]]:8.1f}x")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
