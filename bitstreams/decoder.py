"""Reference decoder: face object bitstream bytes -> FapFrames (+ a record per plane).

Any byte string ends as a :class:`DecodeResult` or a :class:`BitstreamError` naming the
bit offset, plane/frame, FAP and the rule broken. Work is bounded by the input length
(every plane costs at least 6 bits, every skip-chain chunk 4 bits; a DCT plane group
at least 8 bits for at most 16 frames) and so is memory
(alphabets are bounded by the 5-bit range lists; no allocation depends on a coded count).

The arithmetic blocks run through the optional C extension (arith.native_decoder(),
bitstreams/_fastarith.c) when it is built; the pure-Python ArithDecoder is the reference
and the fallback (FBACONF_PURE_PYTHON=1 forces it). Both give identical frames, plane
records and errors (tests/unit/test_native.py).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fbaconf.errors import BitstreamError

from . import arith, dct, readings, tables
from .arith import MSG_ARITH_STATE, MSG_STUFFING, MSG_TRUNCATED, ArithDecoder, NativeSegment, UniformModel, make_model
from .bitio import (
    FACE_OBJECT_PLANE_START_CODE,
    FACE_OBJECT_START_CODE,
    START_CODE_NAMES,
    VISUAL_OBJECT_SEQUENCE_END_CODE,
    BitReader,
)
from .frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, FapFrames
from .syntax import (
    CODING_DCT,
    EXPRESSION_SELECT_MAX,
    FAPS_MASK,
    LIST_ORDER,
    MASK_ALL,
    MASK_INTERPOLATE,
    VISEME_SELECT_MAX,
    FrameRateCode,
    PlaneInfo,
    _tdiv,
    alphabet,
    default_frame_rate,
    intensity_bound,
    intensity_step,
    low_level_step,
    quant_div,
)
from .tables import NUM_FAPS, RANGE_DELTA

INT32_MAX = 2**31 - 1


@dataclass
class DecodeResult:
    frames: FapFrames
    planes: list[PlaneInfo]
    end_code: int | None  # the start code that ended the object, None if the data just ended
    end_offset: int  # bit offset where decoding stopped
    used_default_frame_rate: bool = False
    notes: list[str] = field(default_factory=list)


class _Decoder:
    def __init__(self, data: bytes, file: str | None) -> None:
        self.r = BitReader(data, file=file)
        self.file = file
        self.bounds = tables.default_bounds().copy()  # (i_max, i_min, p_max, p_min), D4
        self.steps_cache: dict[int, list[int]] = {}
        self.fap_quant = 0
        self.coded = np.zeros(NUM_FAPS, dtype=bool)
        self.coded_low: list[int] = []  # coded low-level FAP numbers of the segment
        self.group_types: tuple[int, ...] = ()
        self.coding_type = 0
        self.gender = 0
        self.status_template = np.zeros(NUM_FAPS, dtype=np.uint8)
        self.ever_set = np.zeros(NUM_FAPS, dtype=bool)
        self.cur = [0] * NUM_FAPS
        self.high = [0] * len(HIGH_LEVEL_FIELDS)
        self.p_alphabets: dict[int, tuple[int, int]] = {}
        self.p_models: dict = {}
        self.rate: float | None = None
        self.first_rate: float | None = None
        self.frame_number = -1
        self.time_ms: float | None = None
        self.planes: list[PlaneInfo] = []
        self.current: PlaneInfo | None = None  # the plane being read (after an error: how far it got)
        # output rows
        self.rows_values: list[list[int]] = []
        self.rows_status: list[np.ndarray] = []
        self.rows_high: list[list[int]] = []
        self.rows_meta: list[tuple] = []
        self.seen_intra = False
        self.scaling_div: int | None = None  # D4:keep-scaling only: the divisor the bounds are scaled by
        self.dct_dc: dict[int, int] = {}  # DCT mode: DC level of the previous segment per FAP
        # native fast path (arith.py, _fastarith.c): the module, or None for the pure-Python coder
        self.native = arith.native_decoder()
        self.nat_seg: NativeSegment | None = None

    # ------------------------------------------------------------------ helpers
    def err(self, msg: str, rule: str, *, at: int | None = None, fap: int | None = None) -> BitstreamError:
        e = self.r.error(msg, rule, bit_offset=at, fap=fap)
        e.partial = self._frames() if self.rows_values else None
        return e

    def marker(self, info: PlaneInfo, what: str) -> None:
        at = self.r.pos
        b = self.r.bit(what)
        info.marker_offsets.append((at, b))
        if b != 1:
            raise self.err(f"{what} must be 1", "marker", at=at)

    # ------------------------------------------------------------------ stream
    def run(self) -> DecodeResult:
        r = self.r
        if r.nbits < 32:
            raise self.err("stream shorter than a face_object_start_code", "truncated", at=0)
        code = r.read(32, "face_object_start_code")
        if code != FACE_OBJECT_START_CODE:
            raise self.err(
                f"stream must start with face_object_start_code 0x000001BA, found 0x{code:08X}", "start-code", at=0
            )
        end_code = None
        while True:
            start = r.pos
            sc = r.start_code_ahead()
            has_sc = False
            if sc is not None:
                code, n = sc
                if code != FACE_OBJECT_PLANE_START_CODE:
                    r.pos += n
                    end_code = code
                    break
                r.pos += n
                has_sc = True
            elif r.remaining == 0:
                break
            elif r.remaining < 8 and r.peek(r.remaining) == 0:
                break  # zero padding of the last byte: the stream ended without an end code
            self.plane(start, has_sc)
        frames = self._frames()
        return DecodeResult(
            frames=frames,
            planes=self.planes,
            end_code=end_code,
            end_offset=r.pos,
            used_default_frame_rate=self.first_rate is None and bool(self.planes),
        )

    def _frames(self) -> FapFrames:
        n = len(self.rows_values)
        values = np.array(self.rows_values, dtype=np.int64).reshape(n, NUM_FAPS)
        high = np.array(self.rows_high, dtype=np.int64).reshape(n, len(HIGH_LEVEL_FIELDS))
        meta = self.rows_meta
        return FapFrames(
            values=values.astype(np.int32),
            status=np.array(self.rows_status, dtype=np.uint8).reshape(n, NUM_FAPS),
            high=high.astype(np.int32),
            frame_number=np.array([m[0] for m in meta], dtype=np.int64),
            time_ms=np.array([m[1] for m in meta], dtype=np.float64),
            frame_rate=self.first_rate if self.first_rate is not None else default_frame_rate(),
            is_intra=np.array([m[2] for m in meta], dtype=bool),
            fap_quant=np.array([m[3] for m in meta], dtype=np.int16),
            coding_type=np.array([m[4] for m in meta], dtype=np.int8),
            bit_offset=np.array([m[5] for m in meta], dtype=np.int64),
            gender=self.gender,
        )

    # ------------------------------------------------------------------ plane
    def plane(self, start: int, has_sc: bool) -> None:
        r = self.r
        idx = len(self.planes)
        r.plane = idx
        r.frame = len(self.rows_values)  # output row (= plane index unless DCT groups came before)
        info = self.current = PlaneInfo(index=idx, bit_offset=start, header_offset=r.pos, start_code=has_sc)
        info.is_intra = bool(r.bit("is_intra"))
        at = r.pos
        info.object_mask = r.read(2, "fba_object_mask")
        if info.object_mask != FAPS_MASK:
            raise self.err(
                f"fba_object_mask {info.object_mask:02b}: only 01 (FAPs, no BAPs) is allowed (D1)", "object-mask", at=at
            )
        if not info.is_intra and not self.seen_intra:
            raise self.err("the first plane must be intra (D2)", "first-plane-intra", at=info.header_offset)
        if info.is_intra:
            if r.bit("is_frame_rate"):
                at = r.pos
                fr = FrameRateCode(r.read(8, "frame_rate"), r.read(4, "seconds"), bool(r.bit("frequency_offset")))
                if fr.frame_rate == 0 and fr.seconds == 0:
                    raise self.err("frame rate 0", "frame-rate-zero", at=at)
                info.frame_rate = fr
                self.rate = fr.rate
                if self.first_rate is None:
                    self.first_rate = fr.rate
            if r.bit("is_time_code"):
                at = r.pos
                h, m = r.read(5, "time_code_hours"), r.read(6, "time_code_minutes")
                mk = r.bit("marker_bit")
                info.marker_offsets.append((at + 11, mk))
                if mk != 1:
                    raise self.err("time code marker_bit must be 1", "marker", at=at + 11)
                s = r.read(6, "time_code_seconds")
                info.time_code = (h, m, mk, s)
        if r.bit("skip_frames"):  # 4-bit chunks: 15 continues the chain, the first chunk < 15 ends it
            info.skip = r.skip_chain("number_of_frames_to_skip")
        # timing (D6)
        rate = self.rate if self.rate is not None else default_frame_rate()
        self.frame_number = self.frame_number + info.skip + 1
        if info.time_code is not None:
            h, m, _, s = info.time_code
            self.time_ms = (3600.0 * h + 60.0 * m + s) * 1000.0
        elif self.time_ms is None:
            self.time_ms = info.skip * 1000.0 / rate
        else:
            self.time_ms = self.time_ms + (info.skip + 1) * 1000.0 / rate
        info.frame_number = self.frame_number
        info.time_ms = self.time_ms
        if info.is_intra:
            self.intra_header(info)
        else:
            info.fap_quant = self.fap_quant
            info.coding_type = self.coding_type
            info.coding_known = True
            info.coded = self.coded
            info.group_types = self.group_types
        if self.coding_type == CODING_DCT:  # one plane group: up to 16 frames (dct.py)
            dct.decode_group(self, info)
            info.end_offset = r.pos
            self.planes.append(info)
            self.current = None
            return
        self.payload(info)
        info.end_offset = r.pos
        self.planes.append(info)
        self.current = None
        self.rows_values.append(list(self.cur))
        self.rows_status.append(self.status_template.copy())
        self.rows_high.append(list(self.high))
        self.rows_meta.append((info.frame_number, info.time_ms, info.is_intra, self.fap_quant, self.coding_type, start))

    def intra_header(self, info: PlaneInfo) -> None:
        r = self.r
        self.seen_intra = True
        self.fap_quant = info.fap_quant = r.read(5, "fap_quant")
        coded = np.zeros(NUM_FAPS, dtype=bool)
        types = []
        for g in tables.groups():
            self.marker(info, f"marker_bit before group {g.group} mask")
            t = r.read(2, f"fap_mask_type of group {g.group}")
            types.append(t)
            if t == MASK_ALL:
                coded[g.first_fap - 1 : g.last_fap] = True
            elif t != 0:
                for fap in g.faps:
                    coded[fap - 1] = bool(r.bit(f"fap mask bit of FAP {fap}"))
        self.group_types = info.group_types = tuple(types)
        self.coded = info.coded = coded
        self.gender = info.gender = r.bit("suggested_gender")
        self.coding_type = info.coding_type = r.bit("coding_type")
        info.coding_known = True
        if self.coding_type == CODING_DCT:
            self._mask_state(types, coded)
            return
        flags = [r.bit(f"is_{name.replace('_', '_new_')}") for name in LIST_ORDER]
        for li, name in enumerate(LIST_ORDER):
            if not flags[li]:
                continue
            values: dict[int, int] = {}
            for g in tables.groups()[1:]:
                for j, fap in enumerate(g.faps):
                    if j % 4 == 0:
                        self.marker(info, f"marker_bit in {name} list (group {g.group})")
                    if coded[fap - 1]:
                        v = r.read(5, f"{name} value of FAP {fap}")
                        values[fap] = v
                        self.bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA
            info.new_lists[name] = values
        if readings.active(readings.KEEP_SCALING):
            self._keep_scaling(info)
        # segment state: status template, coded list, P alphabets (models created lazily)
        self._mask_state(types, coded)
        q = self.fap_quant
        self.p_models = {}
        if self.native is not None:
            self.p_alphabets = {}
            self.nat_seg = NativeSegment(self.coded_low, self.bounds, q)
            return
        self.p_alphabets = {
            f: alphabet(int(self.bounds[f - 1, 3]), int(self.bounds[f - 1, 2]), q) for f in self.coded_low
        }

    def _keep_scaling(self, info: PlaneInfo) -> None:
        """The other reading of D4 (S1): alphabets are not recomputed when fap_quant changes. A
        bound no new list replaced is restated in the new fap_quant's units so that it keeps the
        symbol alphabet it had (the defaults keep the first intra plane's scaling)."""
        d_new = quant_div(self.fap_quant)
        d_old = self.scaling_div
        self.scaling_div = d_new
        if d_old is None or d_old == d_new:
            return
        for li, name in enumerate(LIST_ORDER):
            renewed = info.new_lists.get(name, {})
            for f in range(3, NUM_FAPS + 1):
                if f not in renewed:
                    self.bounds[f - 1, li] = _tdiv(int(self.bounds[f - 1, li]), d_old) * d_new

    def _in_intra_range(self, f: int, v: int, step: int, at: int) -> None:
        """The other reading of D4's range rule (``D4:value-range-enforced``): the intra range is
        the range of every value, so a predicted value outside what the intra alphabet codes is an
        error (fbaconf's reading: it is decoded)."""
        lo, hi = alphabet(int(self.bounds[f - 1, 1]), int(self.bounds[f - 1, 0]), self.fap_quant)
        if not lo * step <= v <= hi * step:
            raise self.err(
                f"FAP {f} value {v} outside the intra range {lo * step}..{hi * step} (read as the "
                f"value range: D4:value-range-enforced)",
                "pred-value-range",
                at=at,
                fap=f,
            )

    def _mask_state(self, types, coded) -> None:
        """Status template (D3) and coded low-level FAPs of the planes that follow an intra header."""
        group_of = tables.group_of_fap()
        types_arr = np.array(types)[group_of - 1]
        self.ever_set |= coded
        free = (types_arr == MASK_INTERPOLATE) | ~self.ever_set
        if readings.active(readings.TYPE10_KEEPS):  # the other reading of D3: type 10 holds like 01
            free = ~self.ever_set
        tmpl = np.where(coded, SET, np.where(free, FREE, RETAINED))
        self.status_template = tmpl.astype(np.uint8)
        self.coded_low = [f for f in range(3, NUM_FAPS + 1) if coded[f - 1]]

    # ------------------------------------------------------------------ payload (arithmetic mode)
    def _p_model(self, key, lo: int, hi: int):
        m = self.p_models.get(key)
        if m is None:
            m = self.p_models[key] = make_model(hi - lo + 1)
        return m

    def payload(self, info: PlaneInfo) -> None:
        if self.native is not None:
            return self._payload_native(info)
        r = self.r
        intra = info.is_intra
        q = self.fap_quant
        hl = self.high
        if self.coded[0]:
            start = r.pos
            dec = ArithDecoder(r)
            ib = intensity_bound(q)
            istep = intensity_step(q)
            if intra:
                s1 = dec.decode(UniformModel(VISEME_SELECT_MAX + 1))
                s2 = dec.decode(UniformModel(VISEME_SELECT_MAX + 1))
                b = dec.decode(UniformModel(ib + 1))
                hl[0], hl[1], hl[2] = s1, s2, b * istep
            else:
                V = VISEME_SELECT_MAX
                d1 = dec.decode(self._p_model("vs1", -V, V)) - V
                d2 = dec.decode(self._p_model("vs2", -V, V)) - V
                db = dec.decode(self._p_model("vb", -ib, ib)) - ib
                hl[0] += d1
                hl[1] += d2
                hl[2] += db * istep
            info.blocks.append(("viseme", start, dec.finish()))
            for k, mx in ((0, VISEME_SELECT_MAX), (1, VISEME_SELECT_MAX)):
                if not 0 <= hl[k] <= mx:
                    raise self.err(
                        f"{HIGH_LEVEL_FIELDS[k]} = {hl[k]} outside 0..{mx}", "viseme-select-range", at=start, fap=1
                    )
            hl[3] = r.bit("viseme_def")
        if self.coded[1]:
            start = r.pos
            dec = ArithDecoder(r)
            ib = intensity_bound(q)
            istep = intensity_step(q)
            if intra:
                e1 = dec.decode(UniformModel(EXPRESSION_SELECT_MAX + 1))
                i1 = dec.decode(UniformModel(ib + 1))
                e2 = dec.decode(UniformModel(EXPRESSION_SELECT_MAX + 1))
                i2 = dec.decode(UniformModel(ib + 1))
                hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep
            else:
                E = EXPRESSION_SELECT_MAX
                hl[4] += dec.decode(self._p_model("es1", -E, E)) - E
                hl[5] += (dec.decode(self._p_model("ei1", -ib, ib)) - ib) * istep
                hl[6] += dec.decode(self._p_model("es2", -E, E)) - E
                hl[7] += (dec.decode(self._p_model("ei2", -ib, ib)) - ib) * istep
            info.blocks.append(("expression", start, dec.finish()))
            for k in (4, 6):
                if not 0 <= hl[k] <= EXPRESSION_SELECT_MAX:
                    raise self.err(
                        f"{HIGH_LEVEL_FIELDS[k]} = {hl[k]} outside 0..{EXPRESSION_SELECT_MAX}",
                        "expression-select-range",
                        at=start,
                        fap=2,
                    )
            hl[8] = r.bit("init_face")
            hl[9] = r.bit("expression_def")
        start = r.pos
        dec = ArithDecoder(r)
        cur = self.cur
        steps = self.steps_cache.get(q)
        if steps is None:
            steps = self.steps_cache[q] = [0, 0] + [low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]
        bounds = self.bounds
        symbols = info.symbols
        if intra:
            for f in self.coded_low:
                lo, hi = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)
                s = dec.decode(UniformModel(hi - lo + 1)) + lo
                symbols[f] = s
                cur[f - 1] = s * steps[f - 1]
        else:
            alph = self.p_alphabets
            models = self.p_models
            enforced = readings.active(readings.VALUE_RANGE)
            for f in self.coded_low:
                m = models.get(f)
                lo, hi = alph[f]
                if m is None:
                    m = models[f] = make_model(hi - lo + 1)
                s = dec.decode(m) + lo
                symbols[f] = s
                v = cur[f - 1] + s * steps[f - 1]
                if not -INT32_MAX <= v <= INT32_MAX:
                    raise self.err(f"FAP {f} value {v} overflows 32 bits", "value-overflow", at=start, fap=f)
                if enforced:
                    self._in_intra_range(f, v, steps[f - 1], start)
                cur[f - 1] = v
        info.blocks.append(("low-level", start, dec.finish()))

    # ------------------------------------------------------------------ payload, native fast path
    def _block_native(self, info: PlaneInfo, name: str, spec, pool, mode: int, cur) -> list[int]:
        """One arithmetic block through the C extension; raises exactly what the pure path raises."""
        r = self.r
        start = r.pos
        st, a, b = self.native.decode_block(r.data, r.nbits, start, spec, pool, mode, cur)
        if st == 0:
            r.pos = a
            info.blocks.append((name, start, a - start))
            return b
        if st == 1:
            r.pos = a
            raise r.error(MSG_ARITH_STATE, "arith-state")
        if st == 2:
            r.pos = a
            raise r.error(MSG_STUFFING, "stuffing")
        if st == 3:
            r.pos = r.nbits
            raise r.error(MSG_TRUNCATED, "truncated")
        f = self.coded_low[a]
        raise self.err(f"FAP {f} value {b} overflows 32 bits", "value-overflow", at=start, fap=f)

    def _payload_native(self, info: PlaneInfo) -> None:
        r = self.r
        intra = info.is_intra
        seg = self.nat_seg
        if not intra and seg.low_p is None:
            seg.build_p()
        hl = self.high
        istep = seg.istep
        block = self._block_native
        if self.coded[0]:
            start = r.pos
            if intra:
                s1, s2, b = block(info, "viseme", seg.vis_i, None, 0, None)
                hl[0], hl[1], hl[2] = s1, s2, b * istep
            else:
                d1, d2, db = block(info, "viseme", seg.vis_p, seg.vis_pool, 0, None)
                hl[0] += d1
                hl[1] += d2
                hl[2] += db * istep
            for k, mx in ((0, VISEME_SELECT_MAX), (1, VISEME_SELECT_MAX)):
                if not 0 <= hl[k] <= mx:
                    raise self.err(
                        f"{HIGH_LEVEL_FIELDS[k]} = {hl[k]} outside 0..{mx}", "viseme-select-range", at=start, fap=1
                    )
            hl[3] = r.bit("viseme_def")
        if self.coded[1]:
            start = r.pos
            if intra:
                e1, i1, e2, i2 = block(info, "expression", seg.exp_i, None, 0, None)
                hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep
            else:
                d1, di1, d2, di2 = block(info, "expression", seg.exp_p, seg.exp_pool, 0, None)
                hl[4] += d1
                hl[5] += di1 * istep
                hl[6] += d2
                hl[7] += di2 * istep
            for k in (4, 6):
                if not 0 <= hl[k] <= EXPRESSION_SELECT_MAX:
                    raise self.err(
                        f"{HIGH_LEVEL_FIELDS[k]} = {hl[k]} outside 0..{EXPRESSION_SELECT_MAX}",
                        "expression-select-range",
                        at=start,
                        fap=2,
                    )
            hl[8] = r.bit("init_face")
            hl[9] = r.bit("expression_def")
        if intra:
            vals = block(info, "low-level", seg.low_i, None, 1, self.cur)
        else:
            vals = block(info, "low-level", seg.low_p, seg.low_pool, 2, self.cur)
        info.symbols = dict(zip(self.coded_low, vals))


def decode(data: bytes, *, file: str | None = None) -> DecodeResult:
    """Decode a face object bitstream. Raises BitstreamError (never another exception)."""
    d = _Decoder(data, file)
    try:
        return d.run()
    except BitstreamError as e:
        if e.partial is None and d.rows_values:
            e.partial = d._frames()
        raise
    except (ValueError, IndexError, OverflowError, MemoryError, RecursionError) as e:  # defensive: never escape
        raise d.err(f"internal decoder failure on malformed input: {type(e).__name__}: {e}", "internal") from None


def decode_frames(data: bytes, *, file: str | None = None) -> FapFrames:
    return decode(data, file=file).frames


__all__ = ["decode", "decode_frames", "DecodeResult", "START_CODE_NAMES", "VISUAL_OBJECT_SEQUENCE_END_CODE"]
