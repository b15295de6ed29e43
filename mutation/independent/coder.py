"""Independent mutants: coder (see the package docstring).

The adaptive arithmetic decoder (spec notes §3, D7) — models, cumulative totals, halving,
renormalisation, stuffing, the 14-bit look-ahead — and the decoder STATE that lives across
planes and faces (range lists, retained values across a fap_quant change, default ranges,
prediction after an intra plane, several faces decoded in one process). Written from the
spec notes and the reference source only; each is one plausible misreading.
"""

from __future__ import annotations

import numpy as np

from fbaconf.bitstreams import arith, decoder, tables
from fbaconf.bitstreams.frames import HIGH_LEVEL_FIELDS
from fbaconf.mutation.core import Mutant, source_patch

AD = "fbaconf.bitstreams.arith:ArithDecoder"
MODEL = "fbaconf.bitstreams.arith:Model"
FAST = "fbaconf.bitstreams.arith:FastModel"
DEC = "fbaconf.bitstreams.decoder:_Decoder"


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


def _p(name, where, description, patch, rule, **kw) -> Mutant:
    return Mutant(
        name=name,
        where=where,
        description=description,
        patch=patch,
        pure_decoder=True,
        family="independent",
        rule=rule,
        **kw,
    )


# ---------------------------------------------------------------------------- patch functions


def _patch_zero_run_carried() -> None:
    """One zero-run counter for the whole stream: not reset at block start, look-ahead not undone."""
    arith.ArithDecoder._carry = 0
    source_patch(f"{AD}.__init__", "self.zeros = 0", "self.zeros = ArithDecoder._carry")
    source_patch(f"{AD}.finish", "r.pos = end\n", "r.pos = end\n    ArithDecoder._carry = self.zeros\n")


def _patch_first_q_alphabet() -> None:
    """S1's quirk: symbol alphabets divided by the fap_quant of the first intra plane only."""
    source_patch(
        f"{DEC}.intra_header",
        "    q = self.fap_quant\n",
        "    q = self.__dict__.setdefault('first_q', self.fap_quant)\n",
    )
    source_patch(
        f"{DEC}.payload",
        "lo, hi = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)",
        "lo, hi = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), self.first_q)",
    )


def _patch_pred_not_from_intra() -> None:
    """Prediction state updated by P planes only: the first P plane after an intra plane
    predicts from the last P value (0 at the start), not from the intra value."""
    source_patch(
        f"{DEC}.payload",
        "v = cur[f - 1] + s * steps[f - 1]",
        "pred = self.__dict__.setdefault('pred', {})\n"
        "            v = pred.get(f, 0) + s * steps[f - 1]\n"
        "            pred[f] = v",
    )


def _default_bounds_patch(fn) -> None:
    b = np.zeros((tables.NUM_FAPS, 4), dtype=np.int64)
    for f in tables.fap_table()[2:]:
        i, p = fn(f.intra_range), fn(f.pred_range)
        b[f.number - 1] = (i, -i, p, -p)
    tables.default_bounds = lambda: b


def _patch_defaults_unrounded() -> None:
    _default_bounds_patch(lambda v: v)


def _patch_defaults_round_down() -> None:
    _default_bounds_patch(lambda v: v // 60 * 60)


def _patch_default_p_is_i() -> None:
    b = np.zeros((tables.NUM_FAPS, 4), dtype=np.int64)
    for f in tables.fap_table()[2:]:
        i = tables.round_up_range(f.intra_range)
        b[f.number - 1] = (i, -i, i, -i)
    tables.default_bounds = lambda: b


def _patch_shared(attr_line: str, shared_name: str, init_expr: str):
    def patch() -> None:
        setattr(
            decoder,
            shared_name,
            eval(  # noqa: S307 - fixed expressions of this module, never input
                init_expr,
                {
                    "np": np,
                    "HIGH_LEVEL_FIELDS": HIGH_LEVEL_FIELDS,
                    "NUM_FAPS": decoder.NUM_FAPS,
                },
            ),
        )
        old = attr_line
        new = attr_line.split("=")[0] + f"= {shared_name}"
        source_patch(f"{DEC}.__init__", old, new)

    return patch


_patch_shared_ever = _patch_shared(
    "self.ever_set = np.zeros(NUM_FAPS, dtype=bool)", "_SHARED_EVER", "np.zeros(NUM_FAPS, dtype=bool)"
)
_patch_shared_high = _patch_shared(
    "self.high = [0] * len(HIGH_LEVEL_FIELDS)", "_SHARED_HIGH", "[0] * len(HIGH_LEVEL_FIELDS)"
)
_patch_shared_cur = _patch_shared("self.cur = [0] * NUM_FAPS", "_SHARED_CUR", "[0] * NUM_FAPS")


MUTANTS_LIST: list[Mutant] = [
    # ------------------------------------------------------------------ symbol decoding (§3.3)
    _m(
        "ind-cod-target-no-plus1",
        f"{AD}.decode",
        "target = ((value - low) * total - 1) / len (the +1 forgotten)",
        "target = ((value - low + 1) * total - 1) // length",
        "target = ((value - low) * total - 1) // length",
        "§3.3 target formula",
    ),
    _m(
        "ind-cod-target-no-minus1",
        f"{AD}.decode",
        "target = ((value - low + 1) * total) / len (the -1 forgotten)",
        "target = ((value - low + 1) * total - 1) // length",
        "target = ((value - low + 1) * total) // length",
        "§3.3 target formula",
    ),
    _m(
        "ind-cod-high-no-minus1",
        f"{AD}.decode",
        "new high = low + len*c[k-1]/c[0] (the -1 forgotten)",
        "high = low - 1 + (length * hi_c) // total",
        "high = low + (length * hi_c) // total",
        "§3.3 interval update",
    ),
    _m(
        "ind-cod-interval-uses-next-count",
        f"{AD}.decode",
        "the interval is narrowed with c[k] and c[k+1] of the found index k (one symbol too low)",
        "hi_c, lo_c, _ = model.bounds(s)",
        "hi_c, lo_c, _ = model.bounds(s + 1) if s + 1 < model.n else (1, 0, 0)",
        "§3.3 c[k-1], c[k]",
    ),
    # ------------------------------------------------------------------ renormalisation (§3.3)
    _m(
        "ind-cod-renorm-high-le-q2",
        f"{AD}.decode",
        "lower-half renormalisation when high <= q2 (boundary included)",
        "if high < Q2:",
        "if high <= Q2:",
        "§3.3 renormalisation at q2",
    ),
    _m(
        "ind-cod-renorm-low-gt-q2",
        f"{AD}.decode",
        "upper-half renormalisation only when low > q2 (boundary excluded)",
        "elif low >= Q2:",
        "elif low > Q2:",
        "§3.3 renormalisation at q2",
    ),
    _m(
        "ind-cod-renorm-middle-high-le-q3",
        f"{AD}.decode",
        "middle renormalisation when high <= q3 (boundary included)",
        "elif low >= Q1 and high < Q3:",
        "elif low >= Q1 and high <= Q3:",
        "§3.3 q1/q3 middle case",
    ),
    # (once listed as equivalent: the tie needs a symbol of probability above 1/4 ending exactly at q3, and the
    # extra middle step — interval doubled, one bit more of value — rounds a later boundary the other way when
    # the coded point sits at an edge; the case coder-tie-high-q3 is such a stream)
    _m(
        "ind-cod-renorm-middle-low-gt-q1",
        f"{AD}.decode",
        "middle renormalisation only when low > q1 (boundary excluded)",
        "elif low >= Q1 and high < Q3:",
        "elif low > Q1 and high < Q3:",
        "§3.3 q1/q3 middle case",
    ),
    _m(
        "ind-cod-renorm-middle-first",
        f"{AD}.decode",
        "the middle (q1/q3) case is tested before the upper-half case",
        """        elif low >= Q2:
            value -= Q2
            low -= Q2
            high -= Q2
        elif low >= Q1 and high < Q3:
            value -= Q1
            low -= Q1
            high -= Q1""",
        """        elif low >= Q1 and high < Q3:
            value -= Q1
            low -= Q1
            high -= Q1
        elif low >= Q2:
            value -= Q2
            low -= Q2
            high -= Q2""",
        "§3.3 renormalisation order",
        equivalent="an interval inside [q2, q3) is shifted by q1 instead of q2: after doubling all three "
        "registers sit exactly q2 above the reference's, whose interval is then in the lower half; "
        "the offset only persists while the reference keeps renormalising and is gone (0) when the "
        "loop stops, the same bits are read and target/len use differences only",
    ),
    # ------------------------------------------------------------------ stuffing (§3.3, D7)
    _m(
        "ind-cod-stuffing-after-23-zeros",
        f"{AD}.decode",
        "during renormalisation a stuffing bit is expected after 23 zeros, not 22",
        "if zeros == ZERO_RUN_LIMIT:",
        "if zeros > ZERO_RUN_LIMIT:",
        "§3.3 stuffing after 22 zeros",
    ),
    _m(
        "ind-cod-stuffing-bit-kept",
        f"{AD}._stuffing",
        "the stuffing bit is checked but not removed (read again as an arithmetic bit)",
        "self.pos = at + 1",
        "self.pos = at",
        "§3.3 stuffing bit discarded",
    ),
    _m(
        "ind-cod-stuffing-run-not-reset",
        f"{AD}.decode",
        "after a stuffing bit the zero-run count is not restarted in the renormalisation loop",
        "pos = self.pos\n                zeros = 0",
        "pos = self.pos",
        "§3.3 zero run restarts after stuffing",
    ),
    _m(
        "ind-cod-priming-bits-not-counted",
        f"{AD}._bit",
        "the 16 priming bits of a block do not count toward the 22-zero run",
        "self.zeros += 1\n",
        "pass\n",
        "§3.3 stuffing / D7 zero-run count per block",
    ),
    _p(
        "ind-cod-zero-run-carried-across-blocks",
        f"{AD}.__init__",
        "one zero-run counter for the whole stream: not reset at block start (look-ahead included)",
        _patch_zero_run_carried,
        "D7 zero-run count reset at the start of each block",
    ),
    # ------------------------------------------------------------------ block end / look-ahead (D7)
    _m(
        "ind-cod-d7-rewind-14-stream-bits",
        f"{AD}.finish",
        "S1's rewind: the next field starts exactly 14 stream bits before the read position "
        "(stuffing bits in the look-ahead not accounted)",
        "end = self.start + used + sum(1 for c in self.stuffing if c <= used)",
        "end = self.pos - LOOKAHEAD",
        "D7 hand back look-ahead plus its stuffing bits",
    ),
    _m(
        "ind-cod-d7-boundary-stuffing-excluded",
        f"{AD}.finish",
        "a stuffing bit right after the block's last arithmetic bit is left to the next field",
        "end = self.start + used + sum(1 for c in self.stuffing if c <= used)",
        "end = self.start + used + sum(1 for c in self.stuffing if c < used)",
        "D7 stuffing bit completing the block belongs to it",
    ),
    _m(
        "ind-cod-d7-lookahead-stuffing-error",
        f"{AD}.finish",
        "a bad stuffing bit inside the 14 look-ahead bits is reported as an error",
        "if count <= used:",
        "if True:",
        "D7 stuffing error in the look-ahead is not an error",
    ),
    _m(
        "ind-cod-lookahead-16",
        f"{AD}.finish",
        "hands back all 16 primed bits at block end (the 2 flush bits forgotten)",
        "used = self.count - LOOKAHEAD",
        "used = self.count - 16",
        "D7 14-bit look-ahead",
    ),
    _m(
        "ind-cod-lookahead-13",
        f"{AD}.finish",
        "hands back only 13 bits at block end",
        "used = self.count - LOOKAHEAD",
        "used = self.count - 13",
        "D7 14-bit look-ahead",
    ),
    # ------------------------------------------------------------------ models (§3.2)
    _m(
        "ind-cod-halving-round-down-small",
        f"{MODEL}.update",
        "halving rounds frequencies down (f/2, not (f+1)/2) in small-alphabet models",
        "freqs = [(neg[k + 1] - neg[k] + 1) >> 1 for k in range(n)]",
        "freqs = [(neg[k + 1] - neg[k]) >> 1 for k in range(n)]",
        "§3.2 halving with round-up",
    ),
    _m(
        "ind-cod-halving-round-down-large",
        f"{FAST}.update",
        "halving rounds frequencies down (f/2, not (f+1)/2) in large-alphabet models",
        "f = (np.diff(a) + 1) >> 1",
        "f = np.diff(a) >> 1",
        "§3.2 halving with round-up",
    ),
    _m(
        "ind-cod-halving-above-limit",
        f"{MODEL}.update",
        "halving only when the total exceeds 16383 (lets it reach 16384)",
        "if -neg[0] == MAX_FREQUENCY:",
        "if -neg[0] > MAX_FREQUENCY:",
        "§3.2 halving at c[0] = 16383",
    ),
    _m(
        "ind-cod-halving-after-increment",
        f"{FAST}.update",
        "large models: the +1 is added before the halving test (halves after reaching 16383)",
        """if -int(a[0]) == MAX_FREQUENCY:
        f = (np.diff(a) + 1) >> 1
        a[:-1] = -np.cumsum(f[::-1])[::-1]
        a[-1] = 0
    a[: s + 1] -= 1""",
        """a[: s + 1] -= 1
    if -int(a[0]) == MAX_FREQUENCY:
        f = (np.diff(a) + 1) >> 1
        a[:-1] = -np.cumsum(f[::-1])[::-1]
        a[-1] = 0""",
        "§3.2 halve first, then add 1",
    ),
    _m(
        "ind-cod-update-off-by-one-small",
        f"{MODEL}.update",
        "small models: the +1 goes to c[0..s-1] (frequency of symbol s-1 instead of s; nothing for s=0)",
        "for k in range(s + 1):",
        "for k in range(s):",
        "§3.2 add 1 to c[0..s]",
    ),
    _m(
        "ind-cod-update-skips-total-large",
        f"{FAST}.update",
        "large models: the +1 goes to c[1..s] (total c[0] never grows)",
        "a[: s + 1] -= 1",
        "a[1: s + 1] -= 1",
        "§3.2 add 1 to c[0..s]",
    ),
    _m(
        "ind-cod-find-strict-small",
        f"{MODEL}.find",
        "adaptive small models: symbol search uses c[k] < target (not <=)",
        "return bisect_left(self.neg, -target, 1) - 1",
        "return bisect_left(self.neg, -target + 1, 1) - 1",
        "§3.3 first k with c[k] <= target",
    ),
    _m(
        "ind-cod-find-strict-large",
        f"{FAST}.find",
        "adaptive large models: symbol search uses c[k] < target (not <=)",
        "return int(self.arr.searchsorted(-target)) - 1",
        "return int(self.arr.searchsorted(-target, side='right')) - 1",
        "§3.3 first k with c[k] <= target",
    ),
    _m(
        "ind-cod-empty-block-skipped",
        f"{DEC}.payload",
        "no low-level arithmetic block is read when no low-level FAP is coded",
        "start = r.pos\n    dec = ArithDecoder(r)\n    cur = self.cur",
        "if not self.coded_low:\n        return\n    start = r.pos\n    dec = ArithDecoder(r)\n    cur = self.cur",
        "§1.3 an empty block still costs its flush bits",
    ),
    # ------------------------------------------------------------------ state across planes
    _m(
        "ind-state-p-models-survive-intra",
        f"{DEC}.intra_header",
        "adaptive P models are not re-initialised at an intra plane",
        "self.p_models = {}\n",
        "pass\n",
        "§3.2 models re-initialised at every intra plane",
    ),
    _m(
        "ind-state-p-models-reset-each-plane",
        f"{DEC}.payload",
        "low-level P models are re-created uniform at every predicted plane (never adapt across planes)",
        "m = models.get(f)",
        "m = None",
        "§3.2 P models adapt until the next intra plane",
    ),
    _m(
        "ind-state-viseme-select-models-shared",
        f"{DEC}.payload",
        "viseme_select1 and viseme_select2 share one adaptive P model",
        'self._p_model("vs2", -V, V)',
        'self._p_model("vs1", -V, V)',
        "§3.2 one model per field",
    ),
    _m(
        "ind-state-intensity-models-shared",
        f"{DEC}.payload",
        "expression_intensity1 and 2 share one adaptive P model",
        'self._p_model("ei2", -ib, ib)',
        'self._p_model("ei1", -ib, ib)',
        "§3.2 one model per field",
    ),
    _m(
        "ind-state-ranges-reset-at-intra",
        f"{DEC}.intra_header",
        "range bounds return to the defaults at every intra plane (lists do not persist)",
        "self.seen_intra = True",
        "self.seen_intra = True\n    self.bounds = tables.default_bounds().copy()",
        "D4 bounds persist until a new list replaces them",
    ),
    _m(
        "ind-state-list-resets-unmasked",
        f"{DEC}.intra_header",
        "a new list resets the bound of every FAP it does not carry (unmasked FAPs) to the default",
        "values: dict[int, int] = {}",
        "values: dict[int, int] = {}\n        self.bounds[:, li] = tables.default_bounds()[:, li]",
        "D4 bounds persist until a new list replaces them",
    ),
    _m(
        "ind-state-list-max-sets-min",
        f"{DEC}.intra_header",
        "a new max (min) list also sets the min (max) bound to its mirror (ranges assumed symmetric)",
        "self.bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
        "self.bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA\n"
        "                    self.bounds[fap - 1, li ^ 1] = -self.bounds[fap - 1, li]",
        "D4 four independent lists",
    ),
    _p(
        "ind-state-alphabet-first-fap-quant",
        f"{DEC}.intra_header",
        "symbol alphabets divided by the fap_quant of the first intra plane only (S1 quirk)",
        _patch_first_q_alphabet,
        "D4 alphabet at each intra plane with its fap_quant",
    ),
    _m(
        "ind-state-fap-quant-change-rescales",
        f"{DEC}.intra_header",
        "values are kept as levels: at a fap_quant change every held value is re-dequantised with the new step",
        'self.fap_quant = info.fap_quant = r.read(5, "fap_quant")',
        "_oq = self.fap_quant\n"
        '    self.fap_quant = info.fap_quant = r.read(5, "fap_quant")\n'
        "    if _oq != self.fap_quant:\n"
        "        self.cur = [v // low_level_step(f + 1, _oq) * low_level_step(f + 1, self.fap_quant) if f > 1 else v\n"
        "                    for f, v in enumerate(self.cur)]",
        "§3.4 retained values across a fap_quant change",
    ),
    _m(
        "ind-state-steps-cache-stale",
        f"{DEC}.payload",
        "the step table is computed once (first fap_quant) and reused after fap_quant changes",
        "steps = self.steps_cache.get(q)",
        "steps = next(iter(self.steps_cache.values()), None)",
        "§3.4 step = QP x current fap_quant",
    ),
    _p(
        "ind-state-prediction-ignores-intra",
        f"{DEC}.payload",
        "P planes predict from the last P-plane value (0 at first), not from the preceding intra value",
        _patch_pred_not_from_intra,
        "§3.4 P value = previous reconstructed value + delta",
    ),
    _m(
        "ind-state-high-level-reset-when-unmasked",
        f"{DEC}.intra_header",
        "viseme / expression values reset to 0 at an intra plane that does not code them",
        "self.group_types = info.group_types = tuple(types)",
        "self.group_types = info.group_types = tuple(types)\n"
        "    if not coded[0]:\n        self.high[0:4] = [0] * 4\n"
        "    if not coded[1]:\n        self.high[4:10] = [0] * 6",
        "D3 retained high-level values",
    ),
    # ------------------------------------------------------------------ default ranges (D4)
    _p(
        "ind-state-default-ranges-unrounded",
        "fbaconf.bitstreams.tables:default_bounds",
        "default ranges used as listed (680 for raise_nose), not rounded up to a multiple of 60",
        _patch_defaults_unrounded,
        "D4 defaults rounded away from zero to multiples of 60",
    ),
    _p(
        "ind-state-default-ranges-rounded-down",
        "fbaconf.bitstreams.tables:default_bounds",
        "default ranges rounded toward zero to a multiple of 60 (680 -> 660)",
        _patch_defaults_round_down,
        "D4 defaults rounded away from zero",
    ),
    _p(
        "ind-state-default-p-range-is-i",
        "fbaconf.bitstreams.tables:default_bounds",
        "the default P range of every FAP is taken from the I column",
        _patch_default_p_is_i,
        "§2 default I / P columns",
    ),
    # ------------------------------------------------------------------ several faces, one process
    _m(
        "ind-state-multiface-shared-bounds",
        f"{DEC}.__init__",
        "range lists write into the shared default table: the next face starts with the previous face's lists",
        "self.bounds = tables.default_bounds().copy()",
        "self.bounds = tables.default_bounds()",
        "multi-face streams keep separate state",
    ),
    _p(
        "ind-state-multiface-shared-ever-set",
        f"{DEC}.__init__",
        "'ever set' flags shared by all faces decoded in the process (RETAINED leaks between faces)",
        _patch_shared_ever,
        "multi-face streams keep separate state / D3",
    ),
    _p(
        "ind-state-multiface-shared-high-level",
        f"{DEC}.__init__",
        "viseme / expression state shared by all faces decoded in the process",
        _patch_shared_high,
        "multi-face streams keep separate state",
        equivalent="faces are decoded one after another and every intra plane that codes FAP 1 or 2 sets all "
        "of its fields, so a value left by an earlier face lives only in fields of a FAP that is "
        "FREE for this face, and FREE FAPs carry no value (D3); the outputs compared are equal",
    ),
    _p(
        "ind-state-multiface-shared-values",
        f"{DEC}.__init__",
        "current FAP values shared by all faces decoded in the process",
        _patch_shared_cur,
        "multi-face streams keep separate state",
    ),
]
