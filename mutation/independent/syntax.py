"""Independent mutants: syntax (see the package docstring).

Binary bitstream decoder, structure: start codes, plane headers, group masks (D3), new
min/max range lists (D4), dequantisation, high-level FAP fields, DCT mode (D8). Written from
the spec notes and the reference source only; each is one plausible misreading.
"""

from __future__ import annotations

from fbaconf.bitstreams import bitio, decoder, syntax
from fbaconf.mutation.core import Mutant, source_patch

DEC = "fbaconf.bitstreams.decoder:_Decoder"
DCT = "fbaconf.bitstreams.dct"


def _m(name, where, description, old, new, rule, **kw) -> Mutant:
    return Mutant(
        name=name,
        where=where,
        description=description,
        old=old,
        new=new,
        pure_decoder=True,
        family="independent",
        rule=rule,
        **kw,
    )


def _patch_floor_alphabet() -> None:
    """Symbol alphabets with Python floor division (not C truncation) of negative bounds."""

    def alphabet(lo_bound: int, hi_bound: int, q: int) -> tuple[int, int]:
        d = syntax.quant_div(q)
        return lo_bound // d, hi_bound // d

    decoder.alphabet = alphabet
    syntax.alphabet = alphabet


def _patch_skip_chain_14() -> None:
    """Chunks of 14 and 15 both continue the skip chain."""

    def skip_chain(self, what: str = "number_of_frames_to_skip") -> int:
        total = 0
        while True:
            v = self.read(4, what)
            total += v
            if v < 14:
                return total

    bitio.BitReader.skip_chain = skip_chain


def _patch_list_marker_global() -> None:
    """Range-list marker bits counted over the whole list (every 4th FAP of 3..68), not per group."""
    source_patch(
        f"{DEC}.intra_header",
        """        values: dict[int, int] = {}
        for g in tables.groups()[1:]:
            for j, fap in enumerate(g.faps):
                if j % 4 == 0:""",
        """        values: dict[int, int] = {}
        for g in tables.groups()[1:]:
            for j, fap in enumerate(g.faps):
                if (fap - 3) % 4 == 0:""",
    )


MUTANTS_LIST: list[Mutant] = [
    # ------------------------------------------------------------------ headers / start codes (D1, D2)
    _m(
        "ind-syn-object-mask-first-bit-faps",
        f"{DEC}.plane",
        "reads the FAP flag of fba_object_mask from the first bit (accepts only mask 10, rejects 01)",
        "if info.object_mask != FAPS_MASK:",
        "if info.object_mask != 0b10:",
        "D1 object form / §1.2 mask bits",
    ),
    _m(
        "ind-syn-object-mask-11-accepted",
        f"{DEC}.plane",
        "accepts fba_object_mask 11 (FAPs and BAPs) and decodes the FAP part as if no BAPs followed",
        "if info.object_mask != FAPS_MASK:",
        "if not info.object_mask & FAPS_MASK:",
        "D1 object mask = 01 only",
    ),
    _m(
        "ind-syn-first-plane-predicted-accepted",
        f"{DEC}.plane",
        "does not reject a stream whose first plane is predicted (decodes it with default state)",
        "if not info.is_intra and not self.seen_intra:",
        "if False:",
        "D2 the first plane is intra",
    ),
    _m(
        "ind-syn-timecode-marker-unchecked",
        f"{DEC}.plane",
        "ignores the value of the marker bit inside the time code",
        "if mk != 1:\n",
        "if False:\n",
        "§1.2 time code marker_bit",
    ),
    _m(
        "ind-syn-frame-rate-offset-before-seconds",
        f"{DEC}.plane",
        "reads frequency_offset before the 4-bit seconds field of the frame rate",
        'fr = FrameRateCode(r.read(8, "frame_rate"), r.read(4, "seconds"), bool(r.bit("frequency_offset")))',
        'fr8 = r.read(8, "frame_rate"); fo = bool(r.bit("frequency_offset"))\n'
        '            fr = FrameRateCode(fr8, r.read(4, "seconds"), fo)',
        "§1.2 temporal header field order",
    ),
    # (written against the chunk-by-chunk loop in _Decoder.plane; retargeted, same bug, when the
    # chain reading moved to BitReader.skip_chain)
    _m(
        "ind-syn-skip-chain-last-chunk-only",
        "fbaconf.bitstreams.bitio:BitReader.skip_chain",
        "number_of_frames_to_skip keeps only the last 4-bit chunk of a chain (15 + v read as v)",
        "return 15 * n15 + self.read(4, what)",
        "return self.read(4, what)",
        "§1.2 skip_frames chain",
    ),
    Mutant(
        name="ind-syn-skip-chain-stops-at-14",
        where="fbaconf.bitstreams.bitio:BitReader.skip_chain",
        description="the skip chain continues on chunk values 14 and 15 (off by one in the escape value)",
        patch=_patch_skip_chain_14,
        pure_decoder=True,
        family="independent",
        rule="§1.2 skip_frames chain",
    ),
    _m(
        "ind-syn-trailing-zero-byte-as-padding",
        f"{DEC}.run",
        "treats up to 8 trailing zero bits (a whole zero byte) as end-of-data padding",
        "elif r.remaining < 8 and r.peek(r.remaining) == 0:",
        "elif r.remaining <= 8 and r.peek(r.remaining) == 0:",
        "§1.1 stream end / zero padding",
    ),
    Mutant(
        name="ind-syn-start-code-stuffing-unchecked",
        where="fbaconf.bitstreams.bitio:BitReader.start_code_ahead",
        description="finds a plane/end start code at the next byte boundary without checking the "
        "next_start_code() stuffing bits",
        old="if stuff is None or stuff != (1 << (n - 1)) - 1:",
        new="if stuff is None:",
        pure_decoder=True,
        family="independent",
        rule="D1 next_start_code() stuffing before a start code",
    ),
    # ------------------------------------------------------------------ masks (D3)
    _m(
        "ind-syn-mask-01-10-swapped",
        f"{DEC}._mask_state",
        "mask type 01 read as 'may interpolate' (FREE) and 10 as 'keep previous' (RETAINED)",
        "(types_arr == MASK_INTERPOLATE)",
        "(types_arr == 1)",
        "D3 mask types 01/10",
    ),
    _m(
        "ind-syn-mask-00-free",
        f"{DEC}._mask_state",
        "FAPs of a group with mask type 00 are FREE even when set before (not RETAINED)",
        "(types_arr == MASK_INTERPOLATE)",
        "((types_arr == MASK_INTERPOLATE) | (types_arr == 0))",
        "D3 mask type 00",
    ),
    _m(
        "ind-syn-mask-ever-set-per-segment",
        f"{DEC}._mask_state",
        "'ever set' is forgotten at each intra plane (only the current mask counts): uncoded FAPs become FREE",
        "self.ever_set |= coded",
        "self.ever_set = coded.copy()",
        "D3 RETAINED if ever set",
    ),
    _m(
        "ind-syn-mask-type-10-is-all",
        f"{DEC}.intra_header",
        "mask type 10 read as 'all FAPs of the group' (no per-FAP mask bits)",
        "if t == MASK_ALL:",
        "if t & 2:",
        "D3 mask type 10 / §1.2 per-FAP mask",
    ),
    _m(
        "ind-syn-mask-bits-reversed",
        f"{DEC}.intra_header",
        "per-FAP mask bits of a group read in decreasing FAP order",
        "for fap in g.faps:\n                coded[fap - 1]",
        "for fap in reversed(g.faps):\n                coded[fap - 1]",
        "§1.2 per-FAP mask order",
    ),
    _m(
        "ind-syn-mask-marker-after-type",
        f"{DEC}.intra_header",
        "the group marker bit is read after the 2-bit mask type instead of before it",
        """        self.marker(info, f"marker_bit before group {g.group} mask")
        t = r.read(2, f"fap_mask_type of group {g.group}")""",
        """        t = r.read(2, f"fap_mask_type of group {g.group}")
        self.marker(info, f"marker_bit before group {g.group} mask")""",
        "§1.2 marker_bit before mask type",
    ),
    _m(
        "ind-syn-mask-11-last-fap-missing",
        f"{DEC}.intra_header",
        "mask type 11 marks all FAPs of the group but the last one as coded (exclusive end index)",
        "coded[g.first_fap - 1 : g.last_fap] = True",
        "coded[g.first_fap - 1 : g.last_fap - 1] = True",
        "D3 mask type 11 / group sizes",
    ),
    # ------------------------------------------------------------------ range lists (D4, §1.4)
    _m(
        "ind-syn-list-order-min-first",
        f"{DEC}.intra_header",
        "new lists read in the order i_min, i_max, p_min, p_max (min before max)",
        "for li, name in enumerate(LIST_ORDER):\n        if not flags[li]:",
        "for li, name in [(1, 'i_min'), (0, 'i_max'), (3, 'p_min'), (2, 'p_max')]:\n        if not flags[li]:",
        "§1.4 list order i_max, i_min, p_max, p_min",
    ),
    _m(
        "ind-syn-list-flags-p-before-i",
        f"{DEC}.intra_header",
        "the four is_new flags read as p_max, p_min, i_max, i_min",
        "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]",
        "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]; flags = flags[2:] + flags[:2]",
        "§1.2 is_i_new_max, is_i_new_min, is_p_new_max, is_p_new_min",
    ),
    _m(
        "ind-syn-list-marker-masked-only",
        f"{DEC}.intra_header",
        "range-list marker bits counted only over masked FAPs (the spec: regardless of the mask)",
        """                if j % 4 == 0:
                    self.marker(info, f"marker_bit in {name} list (group {g.group})")
                if coded[fap - 1]:""",
        """                if coded[fap - 1] and sum(coded[g.first_fap - 1:fap - 1]) % 4 == 0:
                    self.marker(info, f"marker_bit in {name} list (group {g.group})")
                if coded[fap - 1]:""",
        "§1.4 markers regardless of the mask",
    ),
    Mutant(
        name="ind-syn-list-marker-global-count",
        where=f"{DEC}.intra_header",
        description="range-list marker bits every 4 FAPs counted over the whole list, not restarted per group",
        patch=_patch_list_marker_global,
        pure_decoder=True,
        family="independent",
        rule="§1.4 marker per group",
    ),
    _m(
        "ind-syn-list-includes-group1",
        f"{DEC}.intra_header",
        "range lists walk groups 1..10 (FAP 1/2 included: a marker and, if masked, a value)",
        "for g in tables.groups()[1:]:",
        "for g in tables.groups():",
        "§1.4 lists over FAP 3..68",
    ),
    _m(
        "ind-syn-list-min-positive",
        f"{DEC}.intra_header",
        "a new min value v is stored as +v*60 (sign of the lower bound forgotten)",
        "v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
        "v * RANGE_DELTA",
        "D4 min = -v*60",
    ),
    _m(
        "ind-syn-list-value-quantised-units",
        f"{DEC}.intra_header",
        "a new list value v*60 is taken as already in units of the current fap_quant (not divided by q)",
        "v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
        "(v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA) * max(self.fap_quant, 1)",
        "D4 alphabet = v*60 / fap_quant",
    ),
    _m(
        "ind-syn-intra-uses-p-list",
        f"{DEC}.payload",
        "intra planes take their alphabets from the P range lists",
        "lo, hi = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)",
        "lo, hi = alphabet(int(bounds[f - 1, 3]), int(bounds[f - 1, 2]), q)",
        "D4 which list applies to intra",
    ),
    _m(
        "ind-syn-p-uses-i-list",
        f"{DEC}.intra_header",
        "predicted planes take their alphabets from the I range lists",
        "alphabet(int(self.bounds[f - 1, 3]), int(self.bounds[f - 1, 2]), q)",
        "alphabet(int(self.bounds[f - 1, 1]), int(self.bounds[f - 1, 0]), q)",
        "D4 which list applies to P",
    ),
    Mutant(
        name="ind-syn-alphabet-floor-division",
        where="fbaconf.bitstreams.syntax:alphabet",
        description="symbol alphabet bounds divided by fap_quant with floor division (lower bound one "
        "symbol lower when q does not divide it)",
        patch=_patch_floor_alphabet,
        pure_decoder=True,
        family="independent",
        rule="D4 C-style truncating division",
    ),
    # ------------------------------------------------------------------ dequantisation (§3.4)
    _m(
        "ind-syn-step-q0-uses-qp",
        f"{DEC}.payload",
        "with fap_quant 0 the step is QP (q treated as 1) instead of 1",
        "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
        "[low_level_step(f, max(q, 1)) for f in range(3, NUM_FAPS + 1)]",
        "§3.4 fap_quant 0 = no quantisation",
    ),
    _m(
        "ind-syn-step-ignores-qp",
        f"{DEC}.payload",
        "low-level step = fap_quant only (the per-FAP QP is forgotten)",
        "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
        "[(q if q > 0 else 1) for f in range(3, NUM_FAPS + 1)]",
        "§3.4 qstep = QP x fap_quant",
    ),
    _m(
        "ind-syn-step-qp-shifted",
        f"{DEC}.payload",
        "QP table indexed off by one (each FAP uses the previous FAP's QP)",
        "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
        "[low_level_step(f - 1, q) for f in range(3, NUM_FAPS + 1)]",
        "§2 QP column",
    ),
    _m(
        "ind-syn-viseme-blend-p-step-missing",
        f"{DEC}.payload",
        "a predicted viseme_blend difference is not multiplied by fap_quant",
        "hl[2] += db * istep",
        "hl[2] += db",
        "D5 blend dequantised by q",
    ),
    _m(
        "ind-syn-expression-bound-no-rounding",
        f"{DEC}.payload",
        "expression intensity alphabet 0..floor(63/q) (the +floor(q/2) rounding forgotten)",
        """    if self.coded[1]:
        start = r.pos
        dec = ArithDecoder(r)
        ib = intensity_bound(q)""",
        """    if self.coded[1]:
        start = r.pos
        dec = ArithDecoder(r)
        ib = 63 // (q if q > 0 else 1)""",
        "D5 intensity alphabet",
    ),
    # ------------------------------------------------------------------ high-level fields (§1.3, D5)
    _m(
        "ind-syn-expression-intra-order",
        f"{DEC}.payload",
        "intra expression block read as select1, select2, intensity1, intensity2",
        """            i1 = dec.decode(UniformModel(ib + 1))
            e2 = dec.decode(UniformModel(EXPRESSION_SELECT_MAX + 1))""",
        """            e2 = dec.decode(UniformModel(EXPRESSION_SELECT_MAX + 1))
            i1 = dec.decode(UniformModel(ib + 1))""",
        "§1.3 expression field order",
    ),
    _m(
        "ind-syn-init-face-expression-def-swapped",
        f"{DEC}.payload",
        "the two raw bits after the expression block read as expression_def, init_face",
        'hl[8] = r.bit("init_face")\n        hl[9] = r.bit("expression_def")\n    start = r.pos',
        'hl[9] = r.bit("expression_def")\n        hl[8] = r.bit("init_face")\n    start = r.pos',
        "§1.3 init_face then expression_def",
    ),
    _m(
        "ind-syn-viseme-select-range-unchecked",
        f"{DEC}.payload",
        "a predicted viseme_select outside 0..14 is accepted",
        "if not 0 <= hl[k] <= mx:",
        "if False:",
        "D5 viseme_select 0..14",
    ),
    # ------------------------------------------------------------------ DCT mode (D8)
    _m(
        "ind-syn-dct-dc-pred-from-intra",
        f"{DCT}:decode_group",
        "predicted DC levels are predicted from the intra group's DC, not the previous group's",
        "d.dct_dc[f] = level0",
        "d.dct_dc.setdefault(f, level0)",
        "D8 DC prediction from previous segment",
    ),
    _m(
        "ind-syn-dct-pred-order-intra",
        f"{DCT}:decode_group",
        "predicted DC differences read with the intra Exp-Golomb order",
        "read_se(r, t.dc_pred_order,",
        "read_se(r, t.dc_intra_order,",
        "D8 DC codes",
    ),
    _m(
        "ind-syn-dct-scale-index-one-based",
        f"{DCT}:decode_group",
        "the scaling index is read as 1-based (fap_quant k selects scale_factors[k-1])",
        "index = d.fap_quant",
        "index = max(d.fap_quant - 1, 0)",
        "D8 scale index",
    ),
    _m(
        "ind-syn-dct-run-from-last-coefficient",
        f"{DCT}:read_ac",
        "a run counts zeros from the last coded coefficient itself (position not advanced past it)",
        "levels[k] = -mag if neg else mag\n        k += 1",
        "levels[k] = -mag if neg else mag",
        "D8 run/level",
    ),
    _m(
        "ind-syn-dct-no-eob-after-15",
        f"{DCT}:read_ac",
        "no end-of-block codeword is read after a nonzero coefficient 15",
        "levels[k] = -mag if neg else mag\n        k += 1",
        "levels[k] = -mag if neg else mag\n        k += 1\n        if k >= N:\n            return levels",
        "D8 EOB always sent",
    ),
    _m(
        "ind-syn-dct-segment-length-no-minus1",
        f"{DCT}:decode_group",
        "segment length read as L (not L-1): a group of L frames is taken as L-1 frames",
        'L = r.read(t.length_bits, "segment_length_minus1") + 1',
        'L = max(r.read(t.length_bits, "segment_length_minus1"), 1)',
        "D8 segment length",
    ),
    _m(
        "ind-syn-dct-hl-direct-whole-intra-group",
        f"{DCT}:decode_group",
        "every frame of an intra group codes the viseme fields directly (not only the first)",
        "_read_hl(r, _VISEME_LAYOUT, hl, intra and j == 0, t, err, 1)",
        "_read_hl(r, _VISEME_LAYOUT, hl, intra, t, err, 1)",
        "D8 high-level fields",
    ),
    _m(
        "ind-syn-dct-hl-diff-unsigned",
        f"{DCT}:_tc_read",
        "high-level difference fields read unsigned (two's complement sign ignored)",
        "return v - (1 << bits) if v >> (bits - 1) else v",
        "return v",
        "D8 high-level differences",
    ),
    _m(
        "ind-syn-dct-rdiv-half-up",
        f"{DCT}:rdiv",
        "inverse-transform rounding: halves rounded up (toward +inf), not away from zero",
        "return -((h - a) // b)",
        "return (a + h) // b",
        "D8 rounding half away from zero",
    ),
    _m(
        "ind-syn-dct-escape-no-sign",
        f"{DCT}:read_ac",
        "an escaped level is taken as unsigned and positive with no sign bit after it",
        """        else:
            run, mag = s
        neg = r.bit("AC level sign")""",
        """            neg = 0
        else:
            run, mag = s
            neg = r.bit("AC level sign")""",
        "D8 escape then sign bit",
    ),
    _m(
        "ind-syn-dct-end-stuffing-missing",
        f"{DCT}:decode_group",
        "the '1' stuffed after a plane group's payload that ends in 20+ zeros is not removed",
        "    r.end()\n",
        "    pass\n",
        "D9 DCT payload end stuffing",
    ),
    _m(
        "ind-syn-dct-stuffing-after-23-zeros",
        "fbaconf.bitstreams.dct_stuffing:StuffingReader.bit",
        "DCT payload stuffing expected after 23 zeros, not 22",
        "if self.run == STUFF_AFTER:",
        "if self.run > STUFF_AFTER:",
        "D9 DCT payload stuffing after 22 zeros",
    ),
    _m(
        "ind-syn-dct-stuffing-run-from-payload",
        "fbaconf.bitstreams.dct_stuffing:StuffingReader.__init__",
        "the DCT zero run is counted from the payload start (header zeros before it ignored)",
        "self.run = run",
        "self.run = 0",
        "D9 zero run counted from the last '1' of the stream",
    ),
]
