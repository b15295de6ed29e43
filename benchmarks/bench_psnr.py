"""FAP PSNR against bitrate for the frame-based (arithmetic) and the DCT coding modes.

    python benchmarks/bench_psnr.py [DATA_DIR] [--files a.fap,b.fap] [--step N]

Reproduces the experiment of the IST paper (seed pereira-ist, section 5.1.1, Figure 8) on the
real .fap files in ../shared/data/fap: every file is coded at its own frame rate with the
frame-based mode at fap_quant 1..31 and with the DCT mode at scaling index 0..31; each
point is (bitrate in kbit/s, FAP PSNR in dB). Bitrate = stream bits / sequence duration,
duration = (last frame number - first frame number + 1) / frame rate.

FAP PSNR (the equation image is missing from the seed text; reconstructed from its
legend: "NFAP is the number of FAPs used for a sequence, Nframe the number of frames, Ri the
peak to peak range of the ith FAP, MSEi the mean square error along the sequence for each
decoded FAP, fap_orig[i][j] and fap_recon[i][j] the original and decoded value of FAP i
for frame j"):

    MSE_i  = (1/Nframe) * sum_j (fap_orig[i][j] - fap_recon[i][j])^2
    PSNR   = (1/NFAP) * sum_i 10 log10(R_i^2 / MSE_i),  R_i = max_j - min_j of fap_orig[i]

over the low-level FAPs coded in the sequence; FAPs with R_i = 0 are skipped (no range, the
ratio is undefined); MSE_i is floored at 1/12, the variance of the integer rounding FAP
values already carry, so that a FAP coded without error gives a finite term. The "all
files" rows pool every (file, FAP) term and divide the total bits by the total duration.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import SET, first_difference

MSE_FLOOR = 1.0 / 12.0


def psnr_terms(orig, recon) -> list[float]:
    coded = (orig.status == SET).any(axis=0)
    out = []
    for i in range(2, 68):
        if not coded[i]:
            continue
        rows = orig.status[:, i] == SET
        x = orig.values[rows, i].astype(np.float64)
        y = recon.values[rows, i].astype(np.float64)
        R = x.max() - x.min()
        if R == 0:
            continue
        mse = max(float(np.mean((x - y) ** 2)), MSE_FLOOR)
        out.append(10.0 * math.log10(R * R / mse))
    return out


def duration_s(frames) -> float:
    fn = frames.frame_number
    return float(fn[-1] - fn[0] + 1) / frames.frame_rate


def point(frames, coding: str, q: int) -> tuple[int, list[float]]:
    res = encode(frames, EncoderOptions(coding=coding, fap_quant=q))
    dec = decode(res.data).frames
    if first_difference(res.recon, dec) is not None:  # the benchmark doubles as a round-trip check
        raise SystemExit(f"decoder disagrees with the encoder reconstruction ({coding}, q={q})")
    return len(res.data) * 8, psnr_terms(frames, dec)


def curves(seqs, qs_arith, qs_dct):
    """{mode: [(q, kbit/s, PSNR dB)]} pooled over the sequences."""
    dur = sum(duration_s(f) for f in seqs)
    out = {}
    for coding, qs in (("arithmetic", qs_arith), ("dct", qs_dct)):
        pts = []
        for q in qs:
            bits, terms = 0, []
            for f in seqs:
                b, t = point(f, coding, q)
                bits += b
                terms += t
            pts.append((q, bits / dur / 1000.0, float(np.mean(terms)) if terms else float("nan")))
        out[coding] = pts
    return out


def interp_psnr(pts, rate: float) -> float | None:
    """PSNR of a rate/PSNR curve at ``rate`` (linear in log rate), None outside its range."""
    pts = sorted((r, p) for _, r, p in pts)
    for (r0, p0), (r1, p1) in zip(pts, pts[1:]):
        if r0 <= rate <= r1:
            if r1 == r0:
                return max(p0, p1)
            a = (math.log(rate) - math.log(r0)) / (math.log(r1) - math.log(r0))
            return p0 + a * (p1 - p0)
    return None


def summarise(name: str, c) -> dict:
    ar, dc = c["arithmetic"], c["dct"]
    lo = max(min(r for _, r, _ in ar), min(r for _, r, _ in dc))
    hi = min(max(r for _, r, _ in ar), max(r for _, r, _ in dc))
    gains = []
    for _, r, p in dc:
        pa = interp_psnr(ar, r)
        if pa is not None:
            gains.append((r, p - pa))
    low = [g for r, g in gains if r <= math.sqrt(lo * hi)] if hi > lo else []
    return {
        "name": name,
        "overlap": (lo, hi),
        "dct_gain_low": float(np.mean(low)) if low else float("nan"),
        "dct_gains": gains,
        "max_arith": max(p for *_, p in ar),
        "max_dct": max(p for *_, p in dc),
        "min_rate_arith": min(r for _, r, _ in ar),
        "min_rate_dct": min(r for _, r, _ in dc),
    }


def print_table(name: str, c) -> None:
    ar = {q: (r, p) for q, r, p in c["arithmetic"]}
    dc = {q: (r, p) for q, r, p in c["dct"]}
    print(f"\n## {name}")
    print("| q / index | frame-based kbit/s | frame-based PSNR dB | DCT kbit/s | DCT PSNR dB |")
    print("|---:|---:|---:|---:|---:|")
    for q in sorted(set(ar) | set(dc)):
        a = ar.get(q)
        d = dc.get(q)
        fa = f"{a[0]:.3f} | {a[1]:.2f}" if a else "– | –"
        fd = f"{d[0]:.3f} | {d[1]:.2f}" if d else "– | –"
        print(f"| {q} | {fa} | {fd} |")
    s = summarise(name, c)
    print(
        f"\noverlapping bitrates {s['overlap'][0]:.3f}..{s['overlap'][1]:.3f} kbit/s; mean DCT gain over the "
        f"lower half (log scale) {s['dct_gain_low']:+.2f} dB; max PSNR frame-based {s['max_arith']:.2f} dB, "
        f"DCT {s['max_dct']:.2f} dB; lowest bitrate frame-based {s['min_rate_arith']:.3f}, "
        f"DCT {s['min_rate_dct']:.3f} kbit/s"
    )
    low_ok = s["dct_gain_low"] > 0
    max_ok = s["max_arith"] > s["max_dct"]
    print(
        f"IST Figure 8 shape: DCT better at the lower bitrates: {'yes' if low_ok else 'NO'}; "
        f"frame-based reaches the higher max PSNR: {'yes' if max_ok else 'NO'}"
    )


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("data", nargs="?", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "fap"))
    ap.add_argument(
        "--files",
        default="xface/anger.fap,xface/joy.fap,xface/test.fap,vreng/jag.fap",
        help="comma-separated files (relative to DATA) shown one by one; 'all' for every file",
    )
    ap.add_argument("--step", type=int, default=1, help="use every N-th quantiser / index")
    ap.add_argument("--no-pooled", action="store_true", help="skip the all-files rows")
    ap.add_argument("--summary", action="store_true", help="one summary line per multi-frame file, no tables")
    args = ap.parse_args(argv)
    root = Path(args.data)
    paths = sorted(root.glob("*/*.fap"))
    if not paths:
        print(f"no .fap files under {root}", file=sys.stderr)
        return 1
    seqs = {str(p.relative_to(root)): read_fap_file(p)[0] for p in paths}
    qa = list(range(1, 32, args.step))
    qd = list(range(0, 32, args.step))
    if args.summary:
        print(
            "| file | Hz | frames | overlap kbit/s | DCT gain, lower half | max PSNR frame-based / DCT | "
            "lowest kbit/s frame-based / DCT |"
        )
        print("|---|---:|---:|---|---:|---|---|")
        for n, f in seqs.items():
            if len(f) < 2:
                continue
            s = summarise(n, curves([f], qa, qd))
            print(
                f"| {n} | {f.frame_rate:g} | {len(f)} | {s['overlap'][0]:.3f}..{s['overlap'][1]:.3f} | "
                f"{s['dct_gain_low']:+.2f} dB | {s['max_arith']:.2f} / {s['max_dct']:.2f} | "
                f"{s['min_rate_arith']:.3f} / {s['min_rate_dct']:.3f} |"
            )
        return 0
    names = list(seqs) if args.files == "all" else [n for n in args.files.split(",") if n in seqs]
    for n in names:
        print_table(n, curves([seqs[n]], qa, qd))
    if not args.no_pooled:
        multi = [f for f in seqs.values() if len(f) > 1]
        print_table(f"all {len(multi)} multi-frame files pooled", curves(multi, qa, qd))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
