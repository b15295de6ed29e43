"""DCT segment coding mode (coding_type = 1): face object plane groups of up to 16 frames.

Every table the public sources do not give is read from ``data/dct_provisional.toml``
(tagged ``provisional = true``, decision D8); this module holds no table literal. See
``docs/dct-mode.md`` for the syntax and the rationale of each table.

Syntax (fbaconf's reading; one *plane group* is one plane of the face object):

    plane header as in the frame-based mode (start code, is_intra, fba_object_mask,
        frame rate / time code when intra, skip_frames: frames skipped before the group)
    if is_intra: fap_quant(5) = DCT scaling index, 10 x group masks, suggested_gender,
        coding_type(1) = 1                      (shared with the frame-based intra header)
    segment_length_minus1                       [segment] length_bits; L = 1..16 frames,
                                                consecutive frame numbers
    if FAP 1 coded: L x viseme fields           [high_level]: direct in the first frame of
    if FAP 2 coded: L x expression fields       an intra group, else repeat flag / diffs
    for every coded low-level FAP, increasing:
        DC: intra group: level, signed Exp-Golomb order [dc] intra_exp_golomb_order
            predicted:   level - previous group's level, order pred_exp_golomb_order
        AC (coefficients 1..15): [ac] run/level codewords + sign bit, escape, end of block

The decoder inverse-transforms 16 dequantised coefficients with the stored integer matrix
(exact integer arithmetic, round half away from zero) and outputs the first L samples, one
FapFrames row per frame. A new intra group resets the DC prediction.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources

import numpy as np

from fbaconf.errors import EncodeError

from . import tables
from .dct_stuffing import END_STUFF_FROM, STUFF_AFTER, StuffingReader, StuffingWriter  # noqa: F401 (re-exported)
from .frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET
from .syntax import (
    CODING_DCT,
    EXPRESSION_SELECT_MAX,
    INTENSITY_MAX,
    MASK_INTERPOLATE,
    VISEME_SELECT_MAX,
    default_frame_rate,
)
from .tables import NUM_FAPS

DATA_FILE = "dct_provisional.toml"
INT32_MAX = 2**31 - 1
EOB = ("eob",)
ESC = ("esc",)


def rdiv(a: int, b: int) -> int:
    """a / b rounded to the nearest integer, halves away from zero (b > 0)."""
    h = b // 2
    if a >= 0:
        return (a + h) // b
    return -((h - a) // b)


# ---------------------------------------------------------------------------- tables


@dataclass(frozen=True)
class DctTables:
    provisional: bool
    version: str
    length: int
    length_bits: int
    scale_bits: int
    matrix: tuple[tuple[int, ...], ...]  # matrix[k][n]
    dc_ratio: tuple[int, int]  # DC step = AC step * num / den
    scale_factors: tuple[int, ...]
    dc_intra_order: int
    dc_pred_order: int
    dc_max_prefix: int
    dc_max_level: int
    eob: str
    escape: str
    escape_run_bits: int
    escape_level_bits: int
    ac_max_level: int
    table: tuple[tuple[int, int, str], ...]  # (run, |level|, codeword)
    hl_bits: dict = field(default_factory=dict)
    # derived
    codes: dict = field(default_factory=dict)  # (run, |level|) -> codeword
    decode_map: dict = field(default_factory=dict)  # (length, value) -> (run, |level|) | EOB | ESC
    max_code_length: int = 0
    columns: tuple[tuple[int, ...], ...] = ()  # matrix transposed: columns[n][k]

    def ac_step(self, fap: int, index: int) -> int:
        return int(tables.quant_steps()[fap - 1]) * self.scale_factors[index]

    def dc_step(self, fap: int, index: int) -> float:
        return self.ac_step(fap, index) * self.dc_ratio[0] / self.dc_ratio[1]


def parse_tables(doc: dict) -> DctTables:
    """Build and validate the tables from a parsed TOML document (RuntimeError if invalid)."""

    def need(cond, msg):
        if not cond:
            raise RuntimeError(f"{DATA_FILE}: {msg}")

    try:
        seg, tr, qu, dc, ac, hl = (doc[k] for k in ("segment", "transform", "quantiser", "dc", "ac", "high_level"))
        length = int(seg["length"])
        matrix = tuple(tuple(int(v) for v in row) for row in tr["matrix"])
        need(
            int(tr["size"]) == length and len(matrix) == length and all(len(r) == length for r in matrix),
            "transform size, matrix shape and segment length must agree",
        )
        need(1 << int(seg["length_bits"]) >= length, "length_bits too small for the segment length")
        need(tr["rounding"] == "half-away-from-zero", "only half-away-from-zero rounding is implemented")
        ratio = tuple(int(v) for v in qu["dc_step_ratio"])
        need(len(ratio) == 2 and ratio[0] > 0 and ratio[1] > 0, "dc_step_ratio must be two positive integers")
        sf = tuple(int(v) for v in qu["scale_factors"])
        need(len(sf) == 32 and min(sf) >= 1, "scale_factors must hold 32 integers >= 1")
        entries = tuple((int(r), int(lv), str(c)) for r, lv, c in ac["table"])
        t = DctTables(
            provisional=bool(doc["provisional"]),
            version=str(doc["version"]),
            length=length,
            length_bits=int(seg["length_bits"]),
            scale_bits=int(tr["scale_bits"]),
            matrix=matrix,
            dc_ratio=ratio,
            scale_factors=sf,
            dc_intra_order=int(dc["intra_exp_golomb_order"]),
            dc_pred_order=int(dc["pred_exp_golomb_order"]),
            dc_max_prefix=int(dc["max_prefix_zeros"]),
            dc_max_level=int(dc["max_level"]),
            eob=str(ac["eob"]),
            escape=str(ac["escape"]),
            escape_run_bits=int(ac["escape_run_bits"]),
            escape_level_bits=int(ac["escape_level_bits"]),
            ac_max_level=int(ac["max_level"]),
            table=entries,
            hl_bits={k: int(v) for k, v in hl.items() if k.endswith("_bits")},
        )
    except (KeyError, TypeError, ValueError) as e:
        raise RuntimeError(f"{DATA_FILE}: missing or malformed entry: {e}") from None
    need(1 << t.escape_run_bits >= length - 1, "escape_run_bits cannot code every run")
    need(0 < t.ac_max_level < 1 << t.escape_level_bits, "ac max_level must fit escape_level_bits")
    codes: dict = {}
    symbols: list[tuple[str, tuple]] = [(t.eob, EOB), (t.escape, ESC)]
    for run, lv, c in entries:
        need(0 <= run <= length - 2 and 1 <= lv <= t.ac_max_level, f"bad run/level entry {run}/{lv}")
        need((run, lv) not in codes, f"duplicate run/level entry {run}/{lv}")
        codes[(run, lv)] = c
        symbols.append((c, (run, lv)))
    words = [c for c, _ in symbols]
    need(all(c and set(c) <= {"0", "1"} for c in words), "codewords must be non-empty strings of 0/1")
    srt = sorted(words)
    need(all(not b.startswith(a) for a, b in zip(srt, srt[1:])), "the AC VLC table is not prefix-free")
    decode_map = {(len(c), int(c, 2)): s for c, s in symbols}
    for k in ("viseme_select", "viseme_blend", "expression_select", "expression_intensity"):
        need(k + "_bits" in t.hl_bits and k + "_diff_bits" in t.hl_bits, f"high_level {k} widths missing")
    object.__setattr__(t, "codes", codes)
    object.__setattr__(t, "decode_map", decode_map)
    object.__setattr__(t, "max_code_length", max(len(c) for c in words))
    object.__setattr__(t, "columns", tuple(zip(*matrix)))
    return t


def read_table_document(path=None) -> dict:
    if path is None:
        text = resources.files("fbaconf.bitstreams").joinpath("data", DATA_FILE).read_text("utf-8")
    else:
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
    return tomllib.loads(text)


@lru_cache(maxsize=1)
def dct_tables() -> DctTables:
    """The tables of the installed data file (cached)."""
    return parse_tables(read_table_document())


# ---------------------------------------------------------------------------- transform


def forward_levels(x, ac_step: int, t: DctTables) -> list[int]:
    """Encoder (informative): quantised levels of 16 samples. AC: rdiv(M x, 2^s * step);
    DC: rdiv(M x * den, 2^s * step * num) (DC step = step * num / den)."""
    S = 1 << t.scale_bits
    num, den = t.dc_ratio
    xs = [int(v) for v in x]
    out = []
    for k, row in enumerate(t.matrix):
        p = sum(m * v for m, v in zip(row, xs))
        out.append(rdiv(p * den, S * ac_step * num) if k == 0 else rdiv(p, S * ac_step))
    return out


def dequantise(levels, ac_step: int, t: DctTables) -> list[int]:
    """Normative: coefficients in units of 1/den (den = dc_step_ratio[1])."""
    num, den = t.dc_ratio
    return [levels[0] * ac_step * num] + [lv * ac_step * den for lv in levels[1:]]


def inverse(levels, ac_step: int, t: DctTables) -> list[int]:
    """Normative inverse: x[n] = rdiv(sum_k M[k][n] Y[k], 2^s * den), exact integers."""
    y = dequantise(levels, ac_step, t)
    D = (1 << t.scale_bits) * t.dc_ratio[1]
    acc = [0] * t.length
    for k, v in enumerate(y):  # the same exact sums, over the non-zero coefficients only (most are zero)
        if v:
            acc = [a + m * v for a, m in zip(acc, t.matrix[k])]
    return [rdiv(a, D) for a in acc]


def error_bound(fap: int, index: int, max_abs: int, t: DctTables | None = None) -> float:
    """Largest |decoded - original| a sample can have (derivation in docs/dct-mode.md):
    1/2 (output rounding) + sum_k |M[k][n]| / 2^s * step_k / 2 (coefficient quantisation)
    + sum_m |(M^T M / 2^2s - I)[n][m]| * max|x| (fixed-point matrix), maximised over n."""
    t = t or dct_tables()
    S = float(1 << t.scale_bits)
    ac = t.ac_step(fap, index)
    steps = [t.dc_step(fap, index)] + [float(ac)] * (t.length - 1)
    M = np.array(t.matrix, dtype=np.float64)
    quant = (np.abs(M) / S * (np.array(steps)[:, None] / 2.0)).sum(axis=0)
    E = M.T @ M / (S * S) - np.eye(t.length)
    mat = np.abs(E).sum(axis=1) * max_abs
    return float((0.5 + quant + mat).max()) + 1e-9


# ---------------------------------------------------------------------------- variable-length codes


def _write_code(w, code: str) -> None:
    w.write(int(code, 2), len(code))


def write_se(w, v: int, order: int) -> int:
    """Signed Exp-Golomb of order ``order``; returns the number of leading zeros used."""
    u = (2 * v - 1 if v > 0 else -2 * v) + (1 << order)
    nb = u.bit_length()
    z = nb - order - 1
    w.write(0, z)
    w.write(u, nb)
    return z


def se_prefix(v: int, order: int) -> int:
    u = (2 * v - 1 if v > 0 else -2 * v) + (1 << order)
    return u.bit_length() - order - 1


def read_se(r, order: int, max_zeros: int, what: str, err) -> int:
    at = r.pos
    z = 0
    while r.bit(what) == 0:
        z += 1
        if z > max_zeros:
            raise err(f"{what}: more than {max_zeros} leading zeros in an Exp-Golomb code", "invalid-vlc", at)
    rest = r.read(z + order, what)
    u = ((1 << (z + order)) | rest) - (1 << order)
    return (u + 1) // 2 if u & 1 else -(u // 2)


def write_ac(w, levels, t: DctTables) -> None:
    run = 0
    for k in range(1, t.length):
        lv = levels[k]
        if lv == 0:
            run += 1
            continue
        a = -lv if lv < 0 else lv
        code = t.codes.get((run, a))
        if code is not None:
            _write_code(w, code)
        else:
            _write_code(w, t.escape)
            w.write(run, t.escape_run_bits)
            w.write(a, t.escape_level_bits)
        w.bit(1 if lv < 0 else 0)
        run = 0
    _write_code(w, t.eob)


def read_vlc(r, t: DctTables, err):
    at = r.pos
    v = 0
    n = 0
    dm = t.decode_map
    while True:
        v = (v << 1) | r.bit("AC run/level VLC")
        n += 1
        s = dm.get((n, v))
        if s is not None:
            return s
        if n >= t.max_code_length:
            raise err("invalid AC run/level codeword", "invalid-vlc", at)


def read_ac(r, t: DctTables, err) -> list[int]:
    N = t.length
    levels = [0] * N
    k = 1
    while True:
        at = r.pos
        s = read_vlc(r, t, err)
        if s is EOB:
            return levels
        if s is ESC:
            run = r.read(t.escape_run_bits, "escape run")
            mag = r.read(t.escape_level_bits, "escape level")
            if mag == 0:
                raise err("escape with level 0", "invalid-vlc", at)
            if mag > t.ac_max_level:
                raise err(f"AC level {mag} exceeds {t.ac_max_level}", "coefficient-overflow", at)
        else:
            run, mag = s
        neg = r.bit("AC level sign")
        k += run
        if k >= N:
            raise err(f"run of zeros goes past coefficient {N - 1}", "run-overflow", at)
        levels[k] = -mag if neg else mag
        k += 1


def _tc_write(w, v: int, bits: int) -> None:
    w.write(v & ((1 << bits) - 1), bits)


def _tc_read(r, bits: int, what: str) -> int:
    v = r.read(bits, what)
    return v - (1 << bits) if v >> (bits - 1) else v


# high-level field layout: (index in HIGH_LEVEL_FIELDS, width key or None for a flag bit)
_VISEME_LAYOUT = ((0, "viseme_select"), (1, "viseme_select"), (2, "viseme_blend"), (3, None))
_EXPRESSION_LAYOUT = (
    (4, "expression_select"),
    (5, "expression_intensity"),
    (6, "expression_select"),
    (7, "expression_intensity"),
    (8, None),
    (9, None),
)
_HL_MAX = {
    0: VISEME_SELECT_MAX,
    1: VISEME_SELECT_MAX,
    2: INTENSITY_MAX,
    4: EXPRESSION_SELECT_MAX,
    5: INTENSITY_MAX,
    6: EXPRESSION_SELECT_MAX,
    7: INTENSITY_MAX,
}


def _write_hl(w, layout, cur, prev, direct: bool, t: DctTables) -> None:
    if direct:
        for j, key in layout:
            w.write(int(cur[j]), t.hl_bits[key + "_bits"] if key else 1)
        return
    same = all(int(cur[j]) == int(prev[j]) for j, _ in layout)
    w.bit(1 if same else 0)
    if same:
        return
    for j, key in layout:
        if key:
            _tc_write(w, int(cur[j]) - int(prev[j]), t.hl_bits[key + "_diff_bits"])
        else:
            w.bit(int(cur[j]))


def _read_hl(r, layout, hl: list[int], direct: bool, t: DctTables, err, fap: int) -> None:
    at = r.pos
    if direct:
        for j, key in layout:
            hl[j] = r.read(t.hl_bits[key + "_bits"] if key else 1, HIGH_LEVEL_FIELDS[j])
    elif r.bit("high-level repeat flag") == 0:
        for j, key in layout:
            if key:
                hl[j] += _tc_read(r, t.hl_bits[key + "_diff_bits"], HIGH_LEVEL_FIELDS[j] + " difference")
            else:
                hl[j] = r.bit(HIGH_LEVEL_FIELDS[j])
    for j, key in layout:
        if key and not 0 <= hl[j] <= _HL_MAX[j]:
            rule = (
                "intensity-range"
                if "intensity" in HIGH_LEVEL_FIELDS[j] or "blend" in HIGH_LEVEL_FIELDS[j]
                else ("viseme-select-range" if fap == 1 else "expression-select-range")
            )
            raise err(f"{HIGH_LEVEL_FIELDS[j]} = {hl[j]} outside 0..{_HL_MAX[j]}", rule, at, fap)


# ---------------------------------------------------------------------------- decoder side


def decode_group(d, info) -> None:
    """Decode the segment data of one plane group (after its header) into FapFrames rows.

    ``d`` is the frame decoder (decoder._Decoder): reader, masks, current values, rows.
    ``d.frame_number`` / ``d.time_ms`` already hold the group's first frame."""
    t = dct_tables()
    first_row = len(d.rows_values)
    d.r.frame = first_row

    def err(msg, rule, at=None, fap=None):
        return d.err(msg, rule, at=at, fap=fap)

    r = StuffingReader(d.r, err)  # D9: the payload's own emulation prevention

    intra = info.is_intra
    if intra:
        d.dct_dc = {}
    L = r.read(t.length_bits, "segment_length_minus1") + 1
    if L > t.length:
        raise err(f"segment length {L} exceeds {t.length}", "segment-length", r.pos - t.length_bits)
    info.segment_length = L
    index = d.fap_quant
    hl_rows = []
    hl = list(d.high)
    coded = d.coded
    vis = [list(hl) for _ in range(L)]
    for j in range(L):
        if coded[0]:
            _read_hl(r, _VISEME_LAYOUT, hl, intra and j == 0, t, err, 1)
        vis[j] = hl[:4]
    for j in range(L):
        if coded[1]:
            _read_hl(r, _EXPRESSION_LAYOUT, hl, intra and j == 0, t, err, 2)
        hl_rows.append(vis[j] + hl[4:])
    samples: dict[int, list[int]] = {}
    for f in d.coded_low:
        start = r.pos
        if intra:
            level0 = read_se(r, t.dc_intra_order, t.dc_max_prefix, f"DC level of FAP {f}", err)
        else:
            prev = d.dct_dc.get(f)
            if prev is None:  # cannot happen: a predicted group keeps the intra group's mask
                raise err(f"predicted segment of FAP {f} without an intra segment", "dct-prediction", start, f)
            level0 = prev + read_se(r, t.dc_pred_order, t.dc_max_prefix, f"DC difference of FAP {f}", err)
        if abs(level0) > t.dc_max_level:
            raise err(f"DC level {level0} of FAP {f} exceeds {t.dc_max_level}", "coefficient-overflow", start, f)
        d.dct_dc[f] = level0
        levels = read_ac(r, t, lambda m, ru, at=None, fap=f: err(m, ru, at, fap))
        levels[0] = level0
        x = inverse(levels, t.ac_step(f, index), t)
        for v in x[:L]:
            if not -INT32_MAX <= v <= INT32_MAX:
                raise err(f"FAP {f} value {v} overflows 32 bits", "value-overflow", start, f)
        samples[f] = x[:L]
        info.blocks.append((f"dct FAP {f}", start, r.pos - start))
    r.end()
    rate = d.rate if d.rate is not None else default_frame_rate()
    fn, tm = d.frame_number, d.time_ms
    cur = d.cur
    for j in range(L):
        if j:
            fn += 1
            tm = tm + 1000.0 / rate
        for f, xs in samples.items():
            cur[f - 1] = xs[j]
        d.rows_values.append(list(cur))
        d.rows_status.append(d.status_template.copy())
        d.rows_high.append(list(hl_rows[j]))
        d.rows_meta.append((fn, tm, intra and j == 0, index, CODING_DCT, info.bit_offset))
    d.high[:] = hl_rows[-1]
    d.frame_number, d.time_ms = fn, tm


# ---------------------------------------------------------------------------- encoder side


@dataclass
class SectionResult:
    values: np.ndarray  # int64[n, 68]
    high: np.ndarray  # int64[n, 10]
    status: np.ndarray  # uint8[n, 68]
    time_ms: np.ndarray
    is_intra: np.ndarray
    bit_offset: np.ndarray
    plane_offsets: list[int]
    intra_frames: list[int]


def plan_groups(fn, coded, types, quants, intra_period: int, t: DctTables) -> list[tuple[int, int, bool]]:
    """(first, end, is_intra) of every plane group: consecutive frame numbers, constant mask,
    mask types and scaling index, at most ``length`` frames. Intra: the first group, a group
    whose mask / types / index differ from the previous one, and (intra_period > 0) a group
    starting ``intra_period`` or more frames after the last intra group's start."""
    n = len(fn)
    groups = []
    k = 0
    last_intra = 0
    while k < n:
        a = k
        k += 1
        while (
            k < n
            and k - a < t.length
            and fn[k] == fn[k - 1] + 1
            and (coded[k] == coded[a]).all()
            and (types[k] == types[a]).all()
            and quants[k] == quants[a]
        ):
            k += 1
        intra = a == 0 or bool(
            (coded[a] != coded[a - 1]).any() or (types[a] != types[a - 1]).any() or quants[a] != quants[a - 1]
        )
        if not intra and intra_period > 0 and a - last_intra >= intra_period:
            intra = True
        if intra:
            last_intra = a
        groups.append((a, k, intra))
    return groups


def write_section(ctx, src, opts, code, quants, types, header) -> SectionResult:
    """Write the frames of ``src`` as DCT plane groups to ``ctx.w``.

    ``header(ctx, intra, frame_number, q, types_row, coded_row)`` writes the plane header up to
    and excluding coding_type (shared with the frame-based mode) and returns the time of the
    group's first frame. Values of FAPs not coded carry ``ctx.cur`` / ``ctx.hcur``."""
    t = dct_tables()
    w = ctx.w
    n = len(src)
    fn = src.frame_number
    coded = src.status == SET
    vals = src.values.astype(np.int64)
    high = src.high.astype(np.int64)
    out_v = np.zeros((n, NUM_FAPS), dtype=np.int64)
    out_h = np.zeros((n, len(HIGH_LEVEL_FIELDS)), dtype=np.int64)
    status = np.zeros((n, NUM_FAPS), dtype=np.uint8)
    time_ms = np.zeros(n)
    is_intra = np.zeros(n, dtype=bool)
    bit_offset = np.zeros(n, dtype=np.int64)
    plane_offsets: list[int] = []
    intra_frames: list[int] = []
    cur = np.array(ctx.cur, dtype=np.int64)
    hcur = np.array(ctx.hcur, dtype=np.int64)
    group_of = tables.group_of_fap()
    rate = code.rate
    dc_prev: dict[int, int] = {}
    tmpl = np.zeros(NUM_FAPS, dtype=np.uint8)
    for a, b, intra in plan_groups(fn, coded, types, quants, opts.intra_period, t):
        q = int(quants[a])
        c = coded[a]
        start = w.position
        plane_offsets.append(start)
        tm = header(ctx, intra, int(fn[a]), q, types[a], c)
        if intra:
            w.bit(1)  # coding_type 1: DCT
            intra_frames.append(a)
            dc_prev = {}
            ctx.ever |= c
            ta = types[a][group_of - 1]
            tmpl = np.where(c, SET, np.where((ta == MASK_INTERPOLATE) | ~ctx.ever, FREE, RETAINED)).astype(np.uint8)
        L = b - a
        w = StuffingWriter(ctx.w)  # D9: the payload's own emulation prevention
        w.write(L - 1, t.length_bits)
        for layout, fap in ((_VISEME_LAYOUT, 1), (_EXPRESSION_LAYOUT, 2)):
            if not c[fap - 1]:
                continue
            sl = [j for j, _ in layout]
            for k in range(a, b):
                _write_hl(w, layout, high[k], hcur, intra and k == a, t)
                hcur[sl] = high[k, sl]
                out_h[k, sl] = hcur[sl]
        segs: dict[int, list[int]] = {}
        for f in range(3, NUM_FAPS + 1):
            if not c[f - 1]:
                continue
            x = list(vals[a:b, f - 1]) + [vals[b - 1, f - 1]] * (t.length - L)
            step = t.ac_step(f, q)
            levels = forward_levels(x, step, t)
            _check_levels(levels, dc_prev.get(f), intra, t, f, int(fn[a]), x)
            if intra:
                write_se(w, levels[0], t.dc_intra_order)
            else:
                write_se(w, levels[0] - dc_prev[f], t.dc_pred_order)
            dc_prev[f] = levels[0]
            write_ac(w, levels, t)
            segs[f] = inverse(levels, step, t)[:L]
        w.end()
        w = ctx.w
        for j, k in enumerate(range(a, b)):
            if j:
                tm = tm + 1000.0 / rate
            for f, xs in segs.items():
                cur[f - 1] = xs[j]
            out_v[k] = cur
            status[k] = tmpl
            time_ms[k] = tm
            is_intra[k] = intra and j == 0
            bit_offset[k] = start
        # rows of high-level FAPs not coded keep the carried values
        for fap, sl in ((1, slice(0, 4)), (2, slice(4, 10))):
            if not c[fap - 1]:
                out_h[a:b, sl] = hcur[sl]
        ctx.t_prev = tm
        ctx.prev_fn = int(fn[b - 1])
    ctx.cur = cur
    ctx.hcur = hcur
    return SectionResult(
        values=out_v,
        high=out_h,
        status=status,
        time_ms=time_ms,
        is_intra=is_intra,
        bit_offset=bit_offset,
        plane_offsets=plane_offsets,
        intra_frames=intra_frames,
    )


def _check_levels(levels, dc_prev, intra: bool, t: DctTables, fap: int, frame: int, x) -> None:
    big = max(x, key=abs)
    if (
        abs(levels[0]) > t.dc_max_level
        or se_prefix(levels[0] if intra else levels[0] - dc_prev, t.dc_intra_order if intra else t.dc_pred_order)
        > t.dc_max_prefix
    ):
        raise EncodeError(
            f"DC level {levels[0]} of FAP {fap} in the segment at frame {frame} is not codable "
            f"(limit {t.dc_max_level})",
            rule="value-range",
            frame=frame,
            fap=fap,
            value=int(big),
        )
    worst = max(abs(v) for v in levels[1:])
    if worst > t.ac_max_level:
        raise EncodeError(
            f"AC level {worst} of FAP {fap} in the segment at frame {frame} exceeds {t.ac_max_level}",
            rule="value-range",
            frame=frame,
            fap=fap,
            value=int(big),
        )
