"""Reference encoder: FapFrames (values + which FAPs are coded + high-level fields) -> bytes.

Closed-loop quantisation (predicts from its own reconstruction). Intra planes are placed
at the first frame, wherever the coded set or mask types change (masks change only in
intra planes), where fap_quant changes, every ``intra_period`` planes, and wherever a
predicted symbol would not fit the largest codable P range. Ranges are chosen so that no
symbol is ever out of range; a value that no range can code is refused with an
EncodeError naming FAP, frame and value — never clipped.

Input semantics: a FAP with status SET in frame k is coded in k. For the others the
group mask type decides what the decoder does (D3); by default the encoder picks type 11
when the whole group is coded, 10 when an uncoded FAP of the group is FREE although it
was set before, 00 when nothing is coded, else 01.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from fractions import Fraction

import numpy as np

from fbaconf.errors import EncodeError

from . import dct, tables
from .arith import ArithEncoder, UniformModel, make_model, native_encoder
from .bitio import FACE_OBJECT_PLANE_START_CODE, FACE_OBJECT_START_CODE, VISUAL_OBJECT_SEQUENCE_END_CODE, BitWriter
from .emulation import find_emulations
from .encode_native import write_payload_native
from .encoder_options import CODING_MODES, PLANE_START_CODE_MODES, RANGE_MODES, EncodeResult, EncoderOptions  # noqa: F401 (re-exported)
from .encoder_plan import MAX_EMULATION_FIXES, Plan, bound_code
from .frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames
from .prepare import _check_input, _derive_group_types, resample
from .syntax import (
    EXPRESSION_SELECT_MAX,
    FAPS_MASK,
    LIST_ORDER,
    MASK_ALL,
    MASK_INTERPOLATE,
    MASK_NONE,
    MASK_RETAIN,
    VISEME_SELECT_MAX,
    FrameRateCode,
    _tdiv,
    alphabet,
    frame_rate_code,
    intensity_bound,
    low_level_step,
    quant_div,
    skip_chunks,
)
from .tables import MAX_RANGE, MAX_RANGE_CODE, NUM_FAPS, RANGE_DELTA

# ---------------------------------------------------------------------------- encoder


def encode(frames: FapFrames, options: EncoderOptions | None = None) -> EncodeResult:
    """Encode ``frames``; the stream never emulates a start code (D9): where a plane would
    complete a byte-aligned 0x000001, a plane start code is written before it (or before the
    plane preceding it), which ends the zero run and moves the plane's alignment; where that
    is not enough, the plane is coded as an intra plane. (The DCT mode has its own stuffing.)"""
    opts = options or EncoderOptions()
    sc, intra, wide = frozenset(opts.start_codes_before), frozenset(opts.intra_at), frozenset(opts.widen_at)
    tried: set = set()
    for _ in range(MAX_EMULATION_FIXES):
        res = _encode_once(frames, replace(opts, start_codes_before=sc, intra_at=intra, widen_at=wide))
        em = find_emulations(res.data, start_codes=res.start_codes)
        if not em:
            return res
        tried.add((sc, intra, wide))
        bit = em[0] * 8 + 23  # the '1' that completes the prefix
        # the planes in stream order (a DCT plane group: its first frame), by their first bit
        offs = res.recon.bit_offset
        firsts = [i for i in range(len(offs)) if i == 0 or offs[i] != offs[i - 1]]
        k = max(j for j, i in enumerate(firsts) if offs[i] <= bit)
        fns = [int(res.recon.frame_number[i]) for i in firsts]
        here, before = fns[k], (fns[k - 1] if k else None)
        # choices every reading allows, the lightest first: a plane start code before the plane
        # (or the one before it: moves the plane's alignment), then coding the plane as intra
        cands = [(sc | {here}, intra, wide)]
        # a start code before one of the planes before it moves this plane's alignment by that
        # plane's and its successors' lengths: up to 8 different alignments
        cands += [(sc | {fns[j]}, intra, wide) for j in range(k - 1, max(-1, k - 8), -1)]
        cands += [(sc | {fns[j], here}, intra, wide) for j in range(k - 1, max(-1, k - 8), -1)]
        if k + 1 < len(fns):
            cands.append((sc | {fns[k + 1]}, intra, wide))
        # then coding the plane (or the one before it) as intra: other symbols, other bits
        cands += [(sc, intra | {here}, wide), (sc | {here}, intra | {here}, wide)]
        if before is not None:
            cands += [
                (sc, intra | {before}, wide),
                (sc | {here}, intra | {before}, wide),
                (sc | {before}, intra | {here}, wide),
            ]
        # last: that intra plane's range lists wider (other alphabets, other arithmetic codes)
        cands += [(sc, intra | {here}, frozenset({p for p in wide if p[0] != here} | {(here, n)})) for n in (1, 2, 3)]
        nxt = next((c_ for c_ in cands if c_ not in tried), None)
        if nxt is None:
            break
        sc, intra, wide = nxt
    raise EncodeError(
        f"cannot avoid a start-code emulation at byte {em[0]} (D9) with plane start codes or "
        f"intra planes or wider range lists",
        rule="start-code-emulation",
    )


def _encode_once(frames: FapFrames, opts: EncoderOptions) -> EncodeResult:
    opts.validate()
    _check_input(frames)
    src = frames
    if opts.frame_rate is not None:
        code = _rate_code(opts.frame_rate)
        if abs(code.rate - frames.frame_rate) > 1e-9 * max(1.0, code.rate):
            src = resample(frames, code.rate)
    else:
        code = _rate_code(frames.frame_rate)
    n = len(src)
    if n == 0:
        raise EncodeError("no frames to encode", rule="empty")
    quants = (
        np.asarray(opts.fap_quant_per_frame, dtype=np.int64)
        if opts.fap_quant_per_frame is not None
        else np.full(n, opts.fap_quant, dtype=np.int64)
    )
    if quants.shape != (n,) or (quants < 0).any() or (quants > 31).any():
        raise EncodeError("fap_quant_per_frame must hold one value 0..31 per frame", rule="option")
    if opts.group_types is not None:
        types = np.asarray(opts.group_types, dtype=np.int64)
        if types.shape != (n, 10) or (types < 0).any() or (types > 3).any():
            raise EncodeError("group_types must be int[n_frames, 10] with values 0..3", rule="option")
        coded = src.status == SET
        for gi, g in enumerate(tables.groups()):
            sl = slice(g.first_fap - 1, g.last_fap)
            bad = np.nonzero(
                ((types[:, gi] == MASK_ALL) & ~coded[:, sl].all(axis=1))
                | ((types[:, gi] == MASK_NONE) & coded[:, sl].any(axis=1))
            )[0]
            if len(bad):
                raise EncodeError(
                    f"group {g.group} mask type contradicts the coded FAPs", rule="option", frame=int(bad[0])
                )
    else:
        types = _derive_group_types(src, opts.partial_mask_type)
    if opts.coding_per_frame is not None or opts.coding == "dct":
        return _encode_sections(src, opts, code, quants, types)
    plan = _plan_arithmetic(src, opts, quants, types)
    return _write(src, opts, code, quants, types, plan)


def _plan_arithmetic(src: FapFrames, opts: EncoderOptions, quants, types) -> Plan:
    forced: set[int] = {k for k, f in enumerate(src.frame_number.tolist()) if f in opts.intra_at}
    while True:
        plan = Plan(src, opts, quants, types, forced)
        if not plan.p_overflow:
            break
        forced.update(plan.p_overflow)
    # values that no intra (value) range can hold
    coded = plan.coded
    for a, b in plan.segments:
        d = quant_div(int(quants[a]))
        over = (np.abs(plan.levels[a:b]) * d > MAX_RANGE) & coded[a:b]
        over[:, :2] = False
        if over.any():
            k, f = (int(v) for v in np.argwhere(over)[0])
            k += a
            q = int(quants[a])
            lim = MAX_RANGE // d * low_level_step(f + 1, q)
            raise EncodeError(
                f"value {int(src.values[k, f])} of FAP {f + 1} at frame {int(src.frame_number[k])} is outside the "
                f"codable range +-{lim} at fap_quant {q} (+-1860 x step; spec notes 1.4)",
                rule="value-range",
                frame=int(src.frame_number[k]),
                fap=f + 1,
                value=int(src.values[k, f]),
            )
    return plan


def _rate_code(rate) -> FrameRateCode:
    try:
        return frame_rate_code(rate)
    except (ValueError, ZeroDivisionError) as e:
        raise EncodeError(str(e), rule="frame-rate") from None


@dataclass
class _StreamContext:
    """State of one face object stream shared by its sections (a mode switch starts a section)."""

    w: BitWriter
    bounds: np.ndarray  # current (i_max, i_min, p_max, p_min) per FAP (D4)
    ever: np.ndarray  # FAPs ever coded (D3 status)
    prev_q: int | None = None
    t_prev: float | None = None  # time of the previous frame (D6)
    prev_fn: int | None = None  # frame number of the previous frame
    cur: np.ndarray | None = None  # last reconstructed values / high-level fields (carried)
    hcur: np.ndarray | None = None

    @classmethod
    def new(cls) -> _StreamContext:
        w = BitWriter()
        w.start_code(FACE_OBJECT_START_CODE)
        return cls(
            w=w,
            bounds=tables.default_bounds().copy(),
            ever=np.zeros(NUM_FAPS, dtype=bool),
            cur=np.zeros(NUM_FAPS, dtype=np.int64),
            hcur=np.zeros(len(HIGH_LEVEL_FIELDS), dtype=np.int64),
        )


def _plane_header(
    ctx: _StreamContext, opts: EncoderOptions, code: FrameRateCode, intra: bool, frame_no: int, q: int, types_row, c
) -> float:
    """Write a plane header up to (excluding) coding_type, shared by both modes; return the time of
    the plane (of a DCT group's first frame) exactly as the decoder computes it (D6)."""
    w = ctx.w
    if (
        opts.plane_start_codes == "all"
        or (opts.plane_start_codes == "intra" and intra)
        or frame_no in opts.start_codes_before
    ):
        w.next_start_code()
        w.start_code(FACE_OBJECT_PLANE_START_CODE)
    w.bit(1 if intra else 0)
    w.write(FAPS_MASK, 2)
    skip = frame_no if ctx.prev_fn is None else frame_no - ctx.prev_fn - 1
    tc = None
    if intra:
        # frame rate: signalled in every intra plane (conformance streams never rely on the default)
        w.bit(1)
        w.write(code.frame_rate, 8)
        w.write(code.seconds, 4)
        w.bit(1 if code.frequency_offset else 0)
        if opts.time_codes:
            t = Fraction(frame_no) / code.exact
            secs = int(t)
            h, m, s = secs // 3600, (secs // 60) % 60, secs % 60
            if h > 31:
                raise EncodeError("time code hours exceed 31", rule="time-code", frame=frame_no)
            w.bit(1)
            w.write(h, 5)
            w.write(m, 6)
            w.bit(1)
            w.write(s, 6)
            tc = (h, m, s)
        else:
            w.bit(0)
    if skip:
        w.bit(1)
        for ch in skip_chunks(skip):
            w.write(ch, 4)
    else:
        w.bit(0)
    rate = code.rate
    if tc is not None:
        ctx.t_prev = (3600.0 * tc[0] + 60.0 * tc[1] + tc[2]) * 1000.0
    elif ctx.t_prev is None:
        ctx.t_prev = skip * 1000.0 / rate
    else:
        ctx.t_prev = ctx.t_prev + (skip + 1) * 1000.0 / rate
    ctx.prev_fn = frame_no
    if intra:
        w.write(q, 5)
        for gi, g in enumerate(tables.groups()):
            w.bit(1)
            t = int(types_row[gi])
            w.write(t, 2)
            if t in (MASK_RETAIN, MASK_INTERPOLATE):
                for fap in g.faps:
                    w.bit(1 if c[fap - 1] else 0)
        w.bit(opts.gender)
    return ctx.t_prev


def _write(
    src: FapFrames,
    opts: EncoderOptions,
    code: FrameRateCode,
    quants,
    types,
    plan: Plan,
    ctx: _StreamContext | None = None,
) -> EncodeResult:
    """Write the planes of the frame-based (arithmetic) mode. Without ``ctx`` the frames are a
    whole stream (object start code ... end code); with it, one section of a mode-switching stream."""
    n = len(src)
    own = ctx is None
    if own:
        ctx = _StreamContext.new()
    w = ctx.w
    bounds = ctx.bounds
    explicit = None
    if opts.bounds is not None:
        explicit = np.asarray(opts.bounds, dtype=np.int64)
        if (
            explicit.shape != (NUM_FAPS, 4)
            or (explicit[:, [0, 2]] < 0).any()
            or (explicit[:, [1, 3]] > 0).any()
            or (explicit % RANGE_DELTA).any()
            or (np.abs(explicit) > MAX_RANGE).any()
        ):
            raise EncodeError(
                "bounds must be int[68, 4] (i_max>=0, i_min<=0, p_max>=0, p_min<=0), multiples of 60 within +-1860",
                rule="option",
            )
    offsets: list[int] = []
    status_rows = np.zeros((n, NUM_FAPS), dtype=np.uint8)
    ever = ctx.ever
    tmpl = np.zeros(NUM_FAPS, dtype=np.uint8)
    time_ms = np.zeros(n)
    group_of = tables.group_of_fap()
    p_models: dict = {}
    fn = src.frame_number
    rate = code.rate
    nat = native_encoder()  # the C extension's block coder, or None (pure-Python reference coder)
    for k in range(n):
        intra = bool(plan.intra[k])
        q = int(quants[k])
        c = plan.coded[k]
        offsets.append(w.position)
        time_ms[k] = _plane_header(ctx, opts, code, intra, int(fn[k]), q, types[k], c)
        if intra:
            w.bit(0)  # coding_type 0: arithmetic
            lists = _choose_lists(
                opts, explicit, bounds, plan.need[k], c, q, ctx.prev_q, dict(opts.widen_at).get(int(fn[k]), 0)
            )
            for name in LIST_ORDER:
                w.bit(1 if name in lists else 0)
            for li, name in enumerate(LIST_ORDER):
                if name not in lists:
                    continue
                vals = lists[name]
                for g in tables.groups()[1:]:
                    for j, fap in enumerate(g.faps):
                        if j % 4 == 0:
                            w.bit(1)
                        if c[fap - 1]:
                            v = vals[fap - 1]
                            w.write(v, 5)
                            bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA
            ctx.prev_q = q
            ever |= c
            ta = types[k][group_of - 1]
            tmpl = np.where(c, SET, np.where((ta == MASK_INTERPOLATE) | ~ever, FREE, RETAINED)).astype(np.uint8)
            p_models = {}
        status_rows[k] = tmpl
        if nat is not None:
            write_payload_native(nat, w, plan, k, intra, q, c, bounds, p_models)
        else:
            _write_payload(w, plan, k, intra, q, c, bounds, p_models)
    if own and opts.end_code:
        w.next_start_code()
        w.start_code(VISUAL_OBJECT_SEQUENCE_END_CODE)
    recon = FapFrames(
        values=plan.recon.astype(np.int32),
        status=status_rows,
        high=plan.rhigh.astype(np.int32),
        frame_number=fn.copy(),
        time_ms=time_ms,
        frame_rate=rate,
        is_intra=plan.intra.copy(),
        fap_quant=quants.astype(np.int16),
        coding_type=np.zeros(n, np.int8),
        bit_offset=np.array(offsets, dtype=np.int64),
        gender=opts.gender,
    )
    recon.values[:, :2] = 0
    return EncodeResult(
        data=w.getvalue(),
        recon=recon,
        intra_frames=[int(i) for i in np.nonzero(plan.intra)[0]],
        plane_offsets=offsets,
        start_codes=list(w.start_codes),
    )


def _coding_modes(opts: EncoderOptions, n: int) -> np.ndarray:
    """int8[n]: coding_type per frame (0 arithmetic, 1 DCT)."""
    if opts.coding_per_frame is None:
        return np.full(n, CODING_MODES.index(opts.coding), dtype=np.int8)
    raw = list(opts.coding_per_frame)
    if len(raw) != n:
        raise EncodeError(f"coding_per_frame must hold one entry per frame ({n})", rule="option")
    out = np.zeros(n, dtype=np.int8)
    for k, v in enumerate(raw):
        if isinstance(v, str) and v in CODING_MODES:
            out[k] = CODING_MODES.index(v)
        elif not isinstance(v, str) and int(v) in (0, 1) and int(v) == v:
            out[k] = int(v)
        else:
            raise EncodeError(f"coding_per_frame[{k}] = {v!r}: use 'arithmetic'/'dct' or 0/1", rule="option")
    return out


def _encode_sections(src: FapFrames, opts: EncoderOptions, code: FrameRateCode, quants, types) -> EncodeResult:
    """DCT mode, or a stream that switches mode: one section per run of frames with the same
    coding type, each starting with an intra plane. Values not coded in a section carry over
    from the previous one (as the decoder keeps them)."""

    n = len(src)
    modes = _coding_modes(opts, n)
    if opts.ranges == "persist" and len(set(modes.tolist())) > 1:
        raise EncodeError("ranges='persist' is not supported in a mode-switching stream", rule="option")
    ctx = _StreamContext.new()
    values = np.zeros((n, NUM_FAPS), dtype=np.int64)
    high = np.zeros((n, len(HIGH_LEVEL_FIELDS)), dtype=np.int64)
    status = np.zeros((n, NUM_FAPS), dtype=np.uint8)
    time_ms = np.zeros(n)
    is_intra = np.zeros(n, dtype=bool)
    bit_offset = np.zeros(n, dtype=np.int64)
    offsets: list[int] = []
    intra_frames: list[int] = []
    cuts = [0] + [k for k in range(1, n) if modes[k] != modes[k - 1]] + [n]
    for a, b in zip(cuts[:-1], cuts[1:]):
        sub = src.select(slice(a, b))
        if modes[a] == 0:
            plan = _plan_arithmetic(sub, opts, quants[a:b], types[a:b])
            res = _write(sub, opts, code, quants[a:b], types[a:b], plan, ctx)
            r = res.recon
            v, h = r.values.astype(np.int64), r.high.astype(np.int64)
            # the section's planes start from zero values: FAPs / fields it does not code keep
            # the values carried from earlier sections instead
            low_set = r.status == SET
            prev_v, prev_h = ctx.cur.copy(), ctx.hcur.copy()
            for k in range(b - a):
                v[k] = np.where(low_set[k], v[k], prev_v)
                for fap, sl in ((1, slice(0, 4)), (2, slice(4, 10))):
                    if not low_set[k, fap - 1]:
                        h[k, sl] = prev_h[sl]
                prev_v, prev_h = v[k], h[k]
            ctx.cur, ctx.hcur = prev_v.copy(), prev_h.copy()
            values[a:b], high[a:b], status[a:b] = v, h, r.status
            time_ms[a:b], is_intra[a:b], bit_offset[a:b] = r.time_ms, r.is_intra, r.bit_offset
            offsets += res.plane_offsets
            intra_frames += [a + i for i in res.intra_frames]
        else:
            res = dct.write_section(
                ctx,
                sub,
                opts,
                code,
                quants[a:b],
                types[a:b],
                lambda c_, intra, fno, q, trow, crow: _plane_header(c_, opts, code, intra, fno, q, trow, crow),
            )
            values[a:b], high[a:b], status[a:b] = res.values, res.high, res.status
            time_ms[a:b], is_intra[a:b], bit_offset[a:b] = res.time_ms, res.is_intra, res.bit_offset
            offsets += res.plane_offsets
            intra_frames += [a + i for i in res.intra_frames]
    if opts.end_code:
        ctx.w.next_start_code()
        ctx.w.start_code(VISUAL_OBJECT_SEQUENCE_END_CODE)
    recon = FapFrames(
        values=values.astype(np.int32),
        status=status,
        high=high.astype(np.int32),
        frame_number=src.frame_number.copy(),
        time_ms=time_ms,
        frame_rate=code.rate,
        is_intra=is_intra,
        fap_quant=quants.astype(np.int16),
        coding_type=modes.copy(),
        bit_offset=bit_offset,
        gender=opts.gender,
    )
    recon.values[:, :2] = 0
    return EncodeResult(
        data=ctx.w.getvalue(),
        recon=recon,
        intra_frames=intra_frames,
        plane_offsets=offsets,
        start_codes=list(ctx.w.start_codes),
    )


def _choose_lists(
    opts: EncoderOptions, explicit, bounds, need, coded, q: int, prev_q, widen: int = 0
) -> dict[str, list[int]]:
    """Which new min/max lists an intra plane sends, as 5-bit codes per FAP (index FAP-1);
    ``widen`` makes every sent bound that many codes wider (D9: other alphabets, other bits)."""
    codes = {}
    if explicit is not None:
        insufficient = (np.abs(need) > np.abs(explicit)) & coded[:, None]
        insufficient[:2] = False
        if insufficient.any():
            f, li = map(int, np.argwhere(insufficient)[0])
            raise EncodeError(
                f"explicit {LIST_ORDER[li]} bound {int(explicit[f, li])} of FAP {f + 1} is too small "
                f"(needs {int(need[f, li])})",
                rule="value-range",
                fap=f + 1,
            )
        for li, name in enumerate(LIST_ORDER):
            codes[name] = [abs(int(v)) // RANGE_DELTA for v in explicit[:, li]]
        return codes
    send_all = opts.ranges == "auto" or (prev_q is not None and prev_q != q)
    for li, name in enumerate(LIST_ORDER):
        needed = [bound_code(v) for v in need[:, li]]
        if send_all:
            if opts.ranges == "auto":
                codes[name] = needed
            else:
                codes[name] = [max(n_, abs(int(b)) // RANGE_DELTA) for n_, b in zip(needed, bounds[:, li])]
            continue
        short = [
            f
            for f in range(2, NUM_FAPS)
            if coded[f] and _tdiv(abs(int(bounds[f, li])), quant_div(q)) < _tdiv(abs(int(need[f, li])), quant_div(q))
        ]
        if short:
            codes[name] = [max(n_, abs(int(b)) // RANGE_DELTA) for n_, b in zip(needed, bounds[:, li])]
    if widen:
        for name in list(codes):
            codes[name] = [
                min(MAX_RANGE_CODE, v + widen) if coded[f] and f >= 2 else v for f, v in enumerate(codes[name])
            ]
    for vals in codes.values():
        if max(vals[2:], default=0) > MAX_RANGE_CODE:  # cannot happen: symbols were range-checked
            raise EncodeError("range list value exceeds 31", rule="value-range")
    return codes


def _write_payload(w: BitWriter, plan: Plan, k: int, intra: bool, q: int, c, bounds, p_models: dict) -> None:
    hs = plan.hsym[k]
    src_high = plan.rhigh[k]
    ib = intensity_bound(q)
    if c[0]:
        enc = ArithEncoder(w)
        if intra:
            enc.encode(UniformModel(VISEME_SELECT_MAX + 1), int(hs[0]))
            enc.encode(UniformModel(VISEME_SELECT_MAX + 1), int(hs[1]))
            enc.encode(UniformModel(ib + 1), int(hs[2]))
        else:
            V = VISEME_SELECT_MAX
            for key, j, lim in (("vs1", 0, V), ("vs2", 1, V), ("vb", 2, ib)):
                m = p_models.get(key) or p_models.setdefault(key, make_model(2 * lim + 1))
                enc.encode(m, int(hs[j]) + lim)
        enc.flush()
        w.bit(int(src_high[3]))
    if c[1]:
        enc = ArithEncoder(w)
        if intra:
            enc.encode(UniformModel(EXPRESSION_SELECT_MAX + 1), int(hs[4]))
            enc.encode(UniformModel(ib + 1), int(hs[5]))
            enc.encode(UniformModel(EXPRESSION_SELECT_MAX + 1), int(hs[6]))
            enc.encode(UniformModel(ib + 1), int(hs[7]))
        else:
            E = EXPRESSION_SELECT_MAX
            for key, j, lim in (("es1", 4, E), ("ei1", 5, ib), ("es2", 6, E), ("ei2", 7, ib)):
                m = p_models.get(key) or p_models.setdefault(key, make_model(2 * lim + 1))
                enc.encode(m, int(hs[j]) + lim)
        enc.flush()
        w.bit(int(src_high[8]))
        w.bit(int(src_high[9]))
    enc = ArithEncoder(w)
    sym = plan.sym[k]
    for f in range(3, NUM_FAPS + 1):
        if not c[f - 1]:
            continue
        if intra:
            lo, hi = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)
            enc.encode(UniformModel(hi - lo + 1), int(sym[f - 1]) - lo)
        else:
            lo, hi = alphabet(int(bounds[f - 1, 3]), int(bounds[f - 1, 2]), q)
            m = p_models.get(f)
            if m is None:
                m = p_models[f] = make_model(hi - lo + 1)
            enc.encode(m, int(sym[f - 1]) - lo)
    enc.flush()
