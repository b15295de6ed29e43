"""Where a stream depends on an fbaconf decision (D3-D7 of the spec notes): the checker's
FAP-DECISION-* warnings, each emitted where a plausible other reading would decode the stream
differently (``conformance/provisional.py`` derives from them what a case rests on).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from fbaconf import rules as R
from fbaconf.bitstreams import tables
from fbaconf.bitstreams.arith import LOOKAHEAD, ZERO_RUN_LIMIT
from fbaconf.bitstreams.syntax import (
    CODING_DCT,
    LIST_ORDER,
    MASK_INTERPOLATE,
    _tdiv,
    alphabet,
    d5_alphabet_differs,
    intensity_bound,
    intensity_bound_ceil,
    low_level_step,
    quant_div,
)
from fbaconf.bitstreams.tables import NUM_FAPS, RANGE_DELTA

from .diagnostics import Diagnostic, diag

ARITH_BLOCKS = frozenset({"viseme", "expression", "low-level"})  # PlaneInfo.blocks of the arithmetic mode


def _bits(data: bytes, at: int, n: int) -> int | None:
    end = at + n
    if at < 0 or end > len(data) * 8:
        return None
    first, last = at >> 3, (end + 7) >> 3
    return (int.from_bytes(data[first:last], "big") >> ((last << 3) - end)) & ((1 << n) - 1)


def lookahead_stuffing(data: bytes, start: int, length: int) -> int | None:
    """Stream offset of a stuffing position inside the 14-bit look-ahead after an arithmetic
    block [start, start+length), or None. There the D7 reading (next field right after the
    block) and a plain 14-bit rewind (S1) disagree: the decoder removed (or, for a '0',
    rejected) a stuffing bit among the look-ahead bits that belong to the next field."""
    end = start + length
    n = min(length, ZERO_RUN_LIMIT)
    tail = _bits(data, end - n, n) if n else 0
    if tail is None:
        return None
    z = n if tail == 0 else (tail & -tail).bit_length() - 1  # zero run at the block end (< 22)
    k = ZERO_RUN_LIMIT - z  # look-ahead zeros needed to complete a run of 22
    if k > LOOKAHEAD or k <= 0:
        return None
    nxt = _bits(data, end, k)
    if nxt is None or nxt != 0:
        return None
    return end + k


def check_decisions(st, rows: list[tuple[int, Any]], out: list[Diagnostic]) -> None:
    """The FAP-DECISION warnings of a parsed stream ``st`` (the checker's record: planes, data,
    frames) whose decoded frame rows are ``rows`` ((frame row, plane) pairs)."""
    planes = st.planes
    data = st.data
    if planes and all(p.frame_rate is None for p in planes):
        out.append(
            diag(
                R.DECISION_NO_FRAME_RATE,
                "no plane signals a frame rate: timed at 25 Hz (D6)",
                bit_offset=planes[0].bit_offset,
                plane=0,
            )
        )
    bounds = tables.default_bounds().copy()
    replaced = np.zeros((NUM_FAPS, 4), dtype=bool)
    raw = np.zeros((NUM_FAPS, 4), dtype=np.int64)
    for f in tables.fap_table()[2:]:
        raw[f.number - 1] = (f.intra_range, -f.intra_range, f.pred_range, -f.pred_range)
    ever = np.zeros(NUM_FAPS, dtype=bool)
    set_div = np.zeros((NUM_FAPS, 4), dtype=np.int64)  # the divisor each bound was last scaled by (0: not yet)
    last_q = 0  # the last non-zero fap_quant of a frame-based intra plane (S1 keeps its high-level alphabet at 0)
    row_of = {p.index: k for k, p in rows}
    for i, p in enumerate(planes):
        for name, start, length in getattr(p, "blocks", ()):
            if name not in ARITH_BLOCKS:
                continue
            at = lookahead_stuffing(data, start, length)
            if at is not None:
                out.append(
                    diag(
                        R.DECISION_LOOKAHEAD_STUFFING,
                        f"{name} block ending at bit {start + length}: a stuffing position (bit {at}) lies "
                        "in the 14-bit look-ahead; D7 and a plain 14-bit rewind read the next field "
                        "differently",
                        bit_offset=at,
                        plane=p.index,
                        frame=p.frame_number,
                    )
                )
        if not p.is_intra or p.coded is None:
            continue
        coded = np.asarray(p.coded, dtype=bool)
        q = int(p.fap_quant)
        loc = dict(bit_offset=p.bit_offset, plane=p.index, frame=p.frame_number)
        low = [f for f in range(3, NUM_FAPS + 1) if coded[f - 1]]
        has_p = i + 1 < len(planes) and not planes[i + 1].is_intra
        if p.coding_type != CODING_DCT:
            d = quant_div(q)
            set_div[set_div == 0] = d  # the defaults take the first frame-based intra plane's scaling
            for li, name in enumerate(LIST_ORDER):
                for fap, v in p.new_lists.get(name, {}).items():
                    bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA
                    replaced[fap - 1, li] = True
                    set_div[fap - 1, li] = d
            kept = sorted(
                {
                    (f, LIST_ORDER[li])
                    for f in low
                    for li in (range(4) if has_p else (0, 1))
                    if _tdiv(int(bounds[f - 1, li]), int(set_div[f - 1, li])) != _tdiv(int(bounds[f - 1, li]), d)
                }
            )
            if kept:
                out.append(
                    diag(
                        R.DECISION_QUANT_NO_LISTS,
                        f"fap_quant {q}: the {kept[0][1]} bound of FAP {kept[0][0]}"
                        + (f" (and {len(kept) - 1} more)" if len(kept) > 1 else "")
                        + " was last scaled at another fap_quant and no new list replaced it: D4 recomputes "
                        "its alphabet, S1 keeps the old one",
                        fap=kept[0][0],
                        **loc,
                    )
                )
            for f in low:
                for kind, (ih, il) in (("intra", (0, 1)), ("predicted", (2, 3))):
                    if kind == "predicted" and not has_p:
                        continue
                    lo, hi = alphabet(int(bounds[f - 1, il]), int(bounds[f - 1, ih]), q)
                    if lo == hi:
                        out.append(
                            diag(
                                R.SEM_SINGLE_SYMBOL,
                                f"FAP {f}: {kind} alphabet is the single symbol {lo} "
                                f"(bounds {int(bounds[f - 1, il])}..{int(bounds[f - 1, ih])}, fap_quant {q})",
                                fap=f,
                                **loc,
                            )
                        )
                    for li in (ih, il):
                        moved = _tdiv(int(raw[f - 1, li]), d) != _tdiv(int(bounds[f - 1, li]), d)
                        if not replaced[f - 1, li] and moved:
                            out.append(
                                diag(
                                    R.DECISION_DEFAULT_ROUNDING,
                                    f"FAP {f} uses the default {LIST_ORDER[li]} bound {int(raw[f - 1, li])}, "
                                    f"rounded to {int(bounds[f - 1, li])} by D4 (alphabet differs)",
                                    fap=f,
                                    **loc,
                                )
                            )
            _outside_intra_range(st, planes, i, low, bounds, row_of, out)
        types = tuple(p.group_types)
        for gi, g in enumerate(tables.groups()):
            if gi < len(types) and types[gi] == MASK_INTERPOLATE:
                freed = [f for f in g.faps if not coded[f - 1] and ever[f - 1]]
                if freed:
                    out.append(
                        diag(
                            R.DECISION_MASK_INTERPOLATE,
                            f"group {g.group} mask type 10 leaves FAP(s) "
                            f"{', '.join(map(str, freed))} uncoded after they were set: FREE under D3, "
                            "retained under S1's reading",
                            fap=freed[0],
                            **loc,
                        )
                    )
        if (coded[0] or coded[1]) and p.coding_type != CODING_DCT:
            hl = {"fap": 1 if coded[0] else 2, **loc}
            if d5_alphabet_differs(q):
                out.append(
                    diag(
                        R.DECISION_HIGH_LEVEL_QUANT,
                        f"visemes/expressions coded with fap_quant {q}: blend/"
                        f"intensity alphabet 0..{intensity_bound(q)} per D5, 0..{intensity_bound_ceil(q)} "
                        "under the other reading",
                        **hl,
                    )
                )
            elif q == 0 and intensity_bound(last_q) != intensity_bound(0):
                out.append(
                    diag(
                        R.DECISION_HIGH_LEVEL_QUANT,
                        f"visemes/expressions coded with fap_quant 0 after "
                        f"fap_quant {last_q}: blend/intensity alphabet 0..{intensity_bound(0)} per D5, "
                        f"0..{intensity_bound(last_q)} in S1 (which keeps fap_quant {last_q}'s)",
                        **hl,
                    )
                )
        if p.coding_type != CODING_DCT and q > 0:
            last_q = q
        ever |= coded


def _outside_intra_range(st, planes, i: int, low: list[int], bounds, row_of: dict, out: list[Diagnostic]) -> None:
    """D4: the predicted planes after intra plane ``i`` that decode a coded FAP to a value outside
    the range its intra alphabet codes (FAP-DECISION-008), one warning per plane and FAP."""
    p = planes[i]
    if not low or st.frames is None:
        return
    seg = []
    j = i + 1
    while j < len(planes) and not planes[j].is_intra:
        if planes[j].index in row_of:
            seg.append(planes[j])
        j += 1
    if not seg:
        return
    q = int(p.fap_quant)
    faps = np.array(low)
    rng = np.array([alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q) for f in low], dtype=np.int64)
    steps = np.array([low_level_step(f, q) for f in low], dtype=np.int64)
    vmin, vmax = rng[:, 0] * steps, rng[:, 1] * steps
    vals = st.frames.values[np.array([row_of[pl.index] for pl in seg])][:, faps - 1].astype(np.int64)
    for j, c in zip(*np.nonzero((vals < vmin) | (vals > vmax))):
        pl, f = seg[j], int(faps[c])
        out.append(
            diag(
                R.DECISION_PRED_OUTSIDE_INTRA,
                f"FAP {f} decodes to {int(vals[j, c])} in a predicted plane, outside "
                f"{int(vmin[c])}..{int(vmax[c])} (the values its intra alphabet codes at fap_quant {q}): "
                "valid under D4",
                bit_offset=pl.bit_offset,
                plane=pl.index,
                frame=pl.frame_number,
                fap=f,
            )
        )


__all__ = ["ARITH_BLOCKS", "check_decisions", "lookahead_stuffing"]
