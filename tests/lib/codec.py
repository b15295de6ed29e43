"""Random inputs for the codec's property tests: FAP sequences with the encoder options that
make them codable (segment by segment: quantiser, group mask types, rates, intra period)."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from fbaconf.bitstreams import tables
from fbaconf.bitstreams.encoder import EncoderOptions
from fbaconf.bitstreams.frames import FREE, SET, FapFrames

GROUPS = tables.groups()
QP = tables.quant_steps()


def group_masks(draw) -> tuple[list[int], np.ndarray]:
    """(mask type per group, coded per FAP): each group none, all (type 11) or partial (01/10)."""
    types: list[int] = []
    coded = np.zeros(68, dtype=bool)
    for g in GROUPS:
        kind = draw(st.sampled_from(["none", "all", "partial"]))
        if kind == "all":
            coded[g.first_fap - 1 : g.last_fap] = True
            types.append(3)
        elif kind == "none":
            types.append(draw(st.sampled_from([0, 1, 2])))
        else:
            coded[g.first_fap - 1 : g.last_fap] = draw(st.lists(st.booleans(), min_size=g.size, max_size=g.size))
            types.append(draw(st.sampled_from([1, 2])))
    return types, coded


# the high-level fields of FAP 1 (viseme: select1, select2, blend, viseme_def) and FAP 2 (expression:
# select1, intensity1, select2, intensity2, init_face, expression_def): their columns and ranges
HIGH_RANGES = (
    (0, 0, ((0, 14), (0, 14), (0, 63), (0, 1))),
    (1, 4, ((0, 6), (0, 63), (0, 6), (0, 63), (0, 1), (0, 1))),
)


def high_fields(draw, frames: FapFrames, k: int, coded: np.ndarray) -> None:
    """Frame ``k``'s viseme (FAP 1) and expression (FAP 2) fields where coded, in their ranges."""
    for fap, first, ranges in HIGH_RANGES:
        if coded[fap]:
            frames.high[k, first : first + len(ranges)] = [draw(st.integers(lo, hi)) for lo, hi in ranges]


@st.composite
def sequences(draw):
    """Random FAP sequences with explicit group mask types, segment by segment."""
    n_seg = draw(st.integers(1, 4))
    quant_mode = draw(st.sampled_from(["fixed", "per-segment"]))
    q_fixed = draw(st.integers(0, 31))
    rows = []
    for _ in range(n_seg):
        seg_len = draw(st.integers(1, 8))
        q = q_fixed if quant_mode == "fixed" else draw(st.integers(0, 31))
        types, coded = group_masks(draw)
        for _ in range(seg_len):
            rows.append((q, tuple(types), coded.copy()))
    n = len(rows)
    frames = FapFrames.empty(n)
    gaps = draw(st.lists(st.sampled_from([1, 1, 1, 2, 3, 16, 31, 200]), min_size=n, max_size=n))
    frames.frame_number[:] = np.cumsum(gaps) - gaps[0] + draw(st.sampled_from([0, 0, 1, 5]))
    quants = np.array([r[0] for r in rows])
    types = np.array([r[1] for r in rows])
    value_draw = st.integers(-1200, 1200)
    for k, (q, _, coded) in enumerate(rows):
        frames.status[k] = np.where(coded, SET, FREE)
        for f in np.nonzero(coded[2:])[0] + 3:
            # codable: |value| <= 1860 x QP (1860 when lossless); stay inside it
            unit = int(QP[f - 1]) if q else 1
            frames.values[k, f - 1] = draw(value_draw) * unit // draw(st.integers(1, 4))
        high_fields(draw, frames, k, coded)
    rate = draw(st.sampled_from([25.0, 30.0, 30000 / 1001, 10.0, 12.5, 0.5, 60.0]))
    frames.frame_rate = rate
    opts = EncoderOptions(
        fap_quant_per_frame=quants,
        group_types=types,
        intra_period=draw(st.sampled_from([0, 0, 1, 3])),
        time_codes=draw(st.booleans()),
        plane_start_codes=draw(st.sampled_from(["none", "intra", "all"])),
        ranges=draw(st.sampled_from(["auto", "persist"])),
        gender=draw(st.integers(0, 1)),
    )
    return frames, opts, types
