"""Bitrate table and encode/decode speed of the reference codec (frame-based arithmetic mode).

    python benchmarks/bench_codec.py [--data ../shared/data/fap] [--frames 3000]

Prints (1) kbit/s for every real .fap file x fap_quant x frame rate 25/15/10 Hz (rates
above the file's own rate are skipped: the encoder subsamples, it does not invent frames),
compared with the seed's 0.5-5 kbit/s (IST 5.1), and (2) encode and decode speed in
frames/s for a 68-FAP stream (66 low-level FAPs + viseme + expression in every frame),
single process, one core, median of repeats. The arithmetic coder's inner loop runs in the
optional C extension when it is built (``--pure`` or FBACONF_PURE_PYTHON=1: the pure-Python
reference coder; ``--compare``: both).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from fbaconf.bitstreams import arith
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.errors import FbaconfInputError

REPO = Path(__file__).resolve().parents[1]
QUANTS = (1, 2, 4, 8, 16, 31)
RATES = (25.0, 15.0, 10.0)


def bitrate_table(data_dir: Path) -> None:
    files = sorted(data_dir.rglob("*.fap"))
    if not files:
        print(f"(no real .fap files under {data_dir}: bitrate table skipped)")
        return
    print("Bitrate (kbit/s) of the real files, frame-based mode; seed IST 5.1 reports 0.5-5 kbit/s")
    head = f"{'file':28s} {'Hz':>4s} " + " ".join(f"{'q=' + str(q):>7s}" for q in QUANTS)
    print(head)
    print("-" * len(head))
    for path in files:
        frames, _, _ = read_fap_file(path)
        if len(frames) < 2:
            continue
        rates = [r for r in RATES if r <= frames.frame_rate + 1e-9] or [frames.frame_rate]
        for rate in rates:
            cells = []
            for q in QUANTS:
                try:
                    res = encode(frames, EncoderOptions(fap_quant=q, frame_rate=rate))
                except FbaconfInputError as e:
                    cells.append(f"{'err':>7s}")
                    print(f"  {path.name} q={q} {rate} Hz: {e}", file=sys.stderr)
                    continue
                dur = len(res.recon) / rate
                cells.append(f"{len(res.data) * 8 / dur / 1000:7.2f}")
            name = f"{path.parent.name}/{path.name}"
            print(f"{name:28s} {rate:4.0f} " + " ".join(cells))
    print()


def speed(n_frames: int, repeats: int = 3) -> None:
    frames = synthetic_sequence(n_frames, 30.0)
    opts = EncoderOptions(fap_quant=1)
    enc_t, dec_t = [], []
    data = b""
    for _ in range(repeats):
        t = time.perf_counter()
        data = encode(frames, opts).data
        enc_t.append(time.perf_counter() - t)
        t = time.perf_counter()
        out = decode(data)
        dec_t.append(time.perf_counter() - t)
    assert len(out.frames) == n_frames
    enc, dec = statistics.median(enc_t), statistics.median(dec_t)
    kbps = len(data) * 8 / (n_frames / 30.0) / 1000
    coder = "native C extension" if arith.native_decoder() is not None else "pure Python"
    print(f"68-FAP stream, {n_frames} frames at 30 Hz, fap_quant 1, {kbps:.1f} kbit/s; coder: {coder}")
    print(f"  encode: {n_frames / enc:8.0f} frames/s")
    print(
        f"  decode: {n_frames / dec:8.0f} frames/s  ({n_frames / dec / 30:.0f}x real time at 30 Hz; "
        f"target 6000 frames/s -> ratio {n_frames / dec / 6000:.2f})"
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=REPO.parent / "shared" / "data" / "fap")
    ap.add_argument("--frames", type=int, default=3000)
    ap.add_argument("--skip-table", action="store_true")
    ap.add_argument("--pure", action="store_true", help="force the pure-Python coder (FBACONF_PURE_PYTHON=1)")
    ap.add_argument("--compare", action="store_true", help="measure the native and the pure-Python coder")
    args = ap.parse_args(argv)
    np.seterr(all="raise")
    if args.pure:
        os.environ[arith.PURE_PYTHON_ENV] = "1"
    if not args.skip_table:
        bitrate_table(args.data)
    speed(args.frames)
    if args.compare and not args.pure:
        os.environ[arith.PURE_PYTHON_ENV] = "1"
        speed(args.frames)
    return 0


if __name__ == "__main__":
    sys.exit(main())
