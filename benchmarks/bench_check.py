"""Benchmark: `fbaconf check` on a 10-minute, 30 Hz stream coding all 66 low-level FAPs.

    python benchmarks/bench_check.py [--frames N] [--coding arithmetic|dct]

Target: under 5 s for 18,000 frames. Prints the checker time and, for comparison, the
time of the reference decoder alone (the checker's parse), so it is clear which part
dominates. The arithmetic coder's inner loop runs in the optional C extension when it is
built; ``--pure`` (or FBACONF_PURE_PYTHON=1) measures the pure-Python reference coder.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from fbaconf.bitstreams import arith, tables
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.profiles.checker import analyse


def random_walk_frames(n: int, rate: float = 30.0, seed: int = 1) -> FapFrames:
    """All 66 low-level FAPs, smooth random walks in units of each FAP's quantiser step."""
    rng = np.random.default_rng(seed)
    f = FapFrames.empty(n, rate)
    qp = tables.quant_steps()[2:]
    vel = np.zeros(66)
    pos = np.zeros(66)
    out = np.zeros((n, 66))
    for k in range(n):
        vel = 0.9 * vel + rng.normal(0, 0.6, 66)
        pos = np.clip(pos + vel, -120, 120)
        out[k] = pos
    uni = np.array([t.direction == "U" for t in tables.fap_table()[2:]])
    out[:, uni] = np.abs(out[:, uni])  # unidirectional FAPs stay >= 0 (no FAP-DECISION-002)
    f.values[:, 2:] = np.round(out * qp).astype(np.int32)
    f.status[:, 2:] = SET
    return f


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--frames", type=int, default=18_000)
    ap.add_argument("--coding", default="arithmetic", choices=("arithmetic", "dct"))
    ap.add_argument("--repeat", type=int, default=2, help="best of N timings (the machine is shared)")
    ap.add_argument("--pure", action="store_true", help="force the pure-Python coder (FBACONF_PURE_PYTHON=1)")
    a = ap.parse_args()
    if a.pure:
        os.environ[arith.PURE_PYTHON_ENV] = "1"
    print(f"coder: {'native C extension' if arith.native_decoder() is not None else 'pure Python'}")
    t0 = time.perf_counter()
    data = encode(random_walk_frames(a.frames), EncoderOptions(coding=a.coding, intra_period=300)).data
    t1 = time.perf_counter()
    print(
        f"stream: {a.frames} frames, 66 FAPs, 30 Hz, {a.coding}: {len(data)} bytes "
        f"({len(data) * 8 / (a.frames / 30.0) / 1000:.2f} kbit/s); encoded in {t1 - t0:.2f} s"
    )
    t_dec, t_chk = [], []
    for _ in range(max(1, a.repeat)):
        t2 = time.perf_counter()
        decode(data)
        t3 = time.perf_counter()
        rep = analyse(data, claim="simple@1", smallest_claim=True)
        t4 = time.perf_counter()
        t_dec.append(t3 - t2)
        t_chk.append(t4 - t3)
    dec, chk = min(t_dec), min(t_chk)
    codes = sorted({d.code for d in rep.diagnostics})
    print(f"reference decode alone: {dec:.2f} s (best of {len(t_dec)})")
    print(
        f"fbaconf check: {chk:.2f} s (best of {len(t_chk)}; target < 5 s) -> {'OK' if chk < 5 else 'OVER TARGET'}; "
        f"checker work beyond the decode: {chk - dec:.2f} s"
    )
    print(f"diagnostics: {len(rep.diagnostics)} {codes}; smallest claim {rep.summary.get('smallest_claim')}")


if __name__ == "__main__":
    main()
