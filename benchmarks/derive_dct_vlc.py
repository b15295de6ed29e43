"""Derive the provisional DCT-mode entropy-code parameters from the real .fap corpus.

How the numbers in bitstreams/data/dct_provisional.toml ([dc] orders, [ac] table) were
made (rerun after changing the transform, the quantiser or the scale factors):

    python benchmarks/derive_dct_vlc.py [DATA_DIR]    # default ../shared/data/fap

For every real file and every scaling index 0..31 the reference encoder's segmentation and
quantiser give the DC levels / differences and the AC (run, |level|) events; each
(file, index) pair gets the same total weight so that no single long file decides the
table. The AC table is a canonical Huffman code over EOB, ESCAPE and the (run, |level|)
pairs (lengths limited to MAX_LEN = 14 bits, env DCT_VLC_MAX_LEN; the lightest pairs are
moved into the escape, whose weight is the sum of the pairs it carries plus one, until the
limit holds; 12 gives 64 codewords and ~4 % more bits at the finest index, 14 gives 111).
Canonical code assignment: by length, then EOB, ESCAPE, then (run, |level|) order. The sign is a separate
bit, so the table is over magnitudes. The DC Exp-Golomb orders minimise the total DC bits.
"""

from __future__ import annotations

import heapq
import os
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from fbaconf.bitstreams import dct
from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import SET
from fbaconf.bitstreams.prepare import _derive_group_types

MAX_LEN = int(os.environ.get("DCT_VLC_MAX_LEN", "14"))


def events(frames, index: int, t):
    coded = frames.status == SET
    types = _derive_group_types(frames, None)
    quants = np.full(len(frames), index)
    ac, dci, dcp = Counter(), Counter(), Counter()
    prev: dict[int, int] = {}
    for a, b, intra in dct.plan_groups(frames.frame_number, coded, types, quants, 0, t):
        if intra:
            prev = {}
        for f in range(3, 69):
            if not coded[a, f - 1]:
                continue
            x = list(frames.values[a:b, f - 1]) + [int(frames.values[b - 1, f - 1])] * (t.length - (b - a))
            lv = dct.forward_levels(x, t.ac_step(f, index), t)
            if f in prev:
                dcp[lv[0] - prev[f]] += 1
            else:
                dci[lv[0]] += 1
            prev[f] = lv[0]
            run = 0
            for v in lv[1:]:
                if v == 0:
                    run += 1
                else:
                    ac[(run, abs(v))] += 1
                    run = 0
            ac["eob"] += 1
    return ac, dci, dcp


def eg_bits(v: int, k: int) -> int:
    return 2 * dct.se_prefix(v, k) + k + 1


def huffman_lengths(weights: dict) -> dict:
    heap = [(w, i, [s]) for i, (s, w) in enumerate(sorted(weights.items(), key=lambda kv: str(kv[0])))]
    heapq.heapify(heap)
    depth = {s: 0 for s in weights}
    n = len(heap)
    while len(heap) > 1:
        w1, _, s1 = heapq.heappop(heap)
        w2, _, s2 = heapq.heappop(heap)
        for s in s1 + s2:
            depth[s] += 1
        n += 1
        heapq.heappush(heap, (w1 + w2, n, s1 + s2))
    return depth


def main(argv: list[str]) -> int:
    root = Path(argv[0]) if argv else Path(__file__).resolve().parents[2] / "shared" / "data" / "fap"
    t = dct.dct_tables()
    ac_w: Counter = Counter()
    dci_all, dcp_all = Counter(), Counter()
    for p in sorted(root.glob("*/*.fap")):
        frames = read_fap_file(p)[0]
        for index in range(32):
            ac, dci, dcp = events(frames, index, t)
            tot = sum(ac.values())
            for s, c in ac.items():
                ac_w[s] += c / tot
            dci_all.update(dci)
            dcp_all.update(dcp)
    k_intra = min(range(12), key=lambda k: sum(eg_bits(v, k) * c for v, c in dci_all.items()))
    k_pred = min(range(12), key=lambda k: sum(eg_bits(v, k) * c for v, c in dcp_all.items()))
    # scale to integer weights (1/1000 of a (file, index) pair), Huffman with a length limit
    weights = {s: max(1, round(w * 1000)) for s, w in ac_w.items()}
    esc = 1
    while True:
        table = dict(weights)
        table["esc"] = esc
        lengths = huffman_lengths(table)
        if max(lengths.values()) <= MAX_LEN:
            break
        # move the lightest pair into the escape
        pairs = [s for s in weights if s != "eob"]
        worst = min(pairs, key=lambda s: (weights[s], str(s)))
        esc += weights.pop(worst)

    # canonical code: by length, then EOB, ESC, then (run, level)
    def order(s):
        return (lengths[s], 0 if s == "eob" else 1 if s == "esc" else 2, s if isinstance(s, tuple) else ())

    code = 0
    prev_len = 0
    codes = {}
    for s in sorted(lengths, key=order):
        L = lengths[s]
        code <<= L - prev_len
        codes[s] = format(code, f"0{L}b")
        code += 1
        prev_len = L
    print(f"intra_exp_golomb_order = {k_intra}")
    print(f"pred_exp_golomb_order = {k_pred}")
    print(f'eob = "{codes["eob"]}"')
    print(f'escape = "{codes["esc"]}"')
    print("table = [")
    for s in sorted((s for s in codes if isinstance(s, tuple)), key=lambda s: (len(codes[s]), s)):
        print(f'  [{s[0]}, {s[1]}, "{codes[s]}"],')
    print("]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
