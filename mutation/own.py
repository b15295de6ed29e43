"""The suite's own mutant decoders: the reference with one realistic bug each, written with the
cases (:data:`MUTANTS_LIST`, then the independent ones of :mod:`.independent`), and :func:`apply`.

Each :class:`~fbaconf.mutation.core.Mutant` names the place it changes (``module:qualname``) and
how: most are source mutations (one exact snippet of the reference function replaced), a few
replace a function outright. The bitstream mutants run the pure-Python block decoder so that a
change of the reference's Python code takes effect. A mutant changes the whole process and is never
undone: :mod:`.run` runs each in a process of its own.
"""

from __future__ import annotations

import numpy as np

from fbaconf.animation import engine
from fbaconf.bitstreams import arith, decoder, syntax, tables
from fbaconf.mutation.core import Mutant, apply_mutant
from fbaconf.mutation.independent import MUTANTS_LIST as INDEPENDENT
from fbaconf.reference import decoder as refdecoder, pipeline
from fbaconf.rendering import raster, render

# ------------------------------------------------------------------ custom patches


def _floor_alphabet() -> None:

    def alphabet(lo, hi, q):  # floor division instead of D4's truncation toward zero
        d = syntax.quant_div(q)
        return lo // d, hi // d

    decoder.alphabet = alphabet


def _non_adaptive() -> None:
    decoder.make_model = lambda n, adaptive=True: arith.make_model(n, adaptive=False)


def _no_lr_fill() -> None:
    engine.lr_fill = lambda values, status: (np.array(values, dtype=np.float64), np.array(status, dtype=np.uint8))


def _camera_shift() -> None:
    orig = raster.project

    def project(vertices, camera, width, height):
        p = orig(vertices, camera, width, height)
        p.sx = p.sx + 1.0  # the image centre one pixel off
        return p

    raster.project = project
    if hasattr(render, "project"):
        render.project = project


def _retained_rescaled() -> None:
    orig = decoder._Decoder.intra_header

    def intra_header(self, info):  # held values re-scaled to a new fap_quant
        old = getattr(self, "fap_quant", None)
        orig(self, info)
        q = self.fap_quant
        if old and q and old != q:
            self.cur = [int(v * q / old) for v in self.cur]

    decoder._Decoder.intra_header = intra_header


def _late_group_defaults() -> None:
    orig = tables.default_bounds

    def default_bounds():  # the default-range table copied wrong for FAPs 40-50 (half their ranges)
        b = orig().copy()
        b[39:50] = b[39:50] // 2
        return b

    tables.default_bounds = default_bounds


def _faces_share_lists() -> None:
    orig = pipeline.multi_outputs

    def multi_outputs(streams, out_dir, fmt="npz"):  # one range-list table for every face decoded at once
        orig_init = decoder._Decoder.__init__
        shared: dict = {}

        def init(self, data, file=None):
            orig_init(self, data, file)
            if "bounds" in shared:
                self.bounds = shared["bounds"]
            shared["bounds"] = self.bounds

        decoder._Decoder.__init__ = init
        try:
            return orig(streams, out_dir, fmt)
        finally:
            decoder._Decoder.__init__ = orig_init

    pipeline.multi_outputs = refdecoder.multi_outputs = multi_outputs


def _hl_alphabet_first_quant() -> None:
    orig_header, orig_bound = decoder._Decoder.intra_header, syntax.intensity_bound
    first: dict = {}

    def intra_header(self, info):  # the blend/intensity alphabet fixed by the first intra plane's fap_quant
        orig_header(self, info)
        first["q"] = self.__dict__.setdefault("_first_q", self.fap_quant)

    decoder._Decoder.intra_header = intra_header
    decoder.intensity_bound = lambda q: orig_bound(first.get("q", q))


def _hl_alphabet(bound) -> None:
    decoder.intensity_bound = bound


# ------------------------------------------------------------------ the mutants

D = "fbaconf.bitstreams.decoder:_Decoder"
MUTANTS_LIST = [
    # --- dequantisation / prediction
    Mutant(
        "dequant-step-index",
        f"{D}.payload",
        "off-by-one in the dequantisation table: FAP f uses FAP f-1's step",
        "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
        "[low_level_step(f, q) for f in range(2, NUM_FAPS)]",
        pure_decoder=True,
    ),
    Mutant(
        "dequant-quant-plus-one",
        f"{D}.payload",
        "off-by-one in dequantisation: step x (fap_quant + 1)",
        "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
        "[low_level_step(f, q + 1) for f in range(3, NUM_FAPS + 1)]",
        pure_decoder=True,
    ),
    Mutant(
        "prediction-sign",
        f"{D}.payload",
        "wrong sign in prediction: value = previous - error",
        "v = cur[f - 1] + s * steps[f - 1]",
        "v = cur[f - 1] - s * steps[f - 1]",
        pure_decoder=True,
    ),
    Mutant(
        "intra-symbol-offset",
        f"{D}.payload",
        "intra symbols not offset by the alphabet minimum",
        "s = dec.decode(UniformModel(hi - lo + 1)) + lo",
        "s = dec.decode(UniformModel(hi - lo + 1))",
        pure_decoder=True,
    ),
    Mutant(
        "alphabet-floor-division",
        "fbaconf.bitstreams.decoder:alphabet",
        "alphabets by floor division instead of D4's truncation toward zero",
        patch=_floor_alphabet,
        pure_decoder=True,
    ),
    Mutant(
        "predicted-alphabet-from-intra-range",
        f"{D}.intra_header",
        "predicted alphabets built from the intra (not the predicted) range",
        "alphabet(int(self.bounds[f - 1, 3]), int(self.bounds[f - 1, 2]), q)",
        "alphabet(int(self.bounds[f - 1, 1]), int(self.bounds[f - 1, 0]), q)",
        pure_decoder=True,
    ),
    Mutant(
        "non-adaptive-model",
        "fbaconf.bitstreams.decoder:make_model",
        "predicted planes decoded with non-adaptive frequency models",
        patch=_non_adaptive,
        pure_decoder=True,
    ),
    # --- masks (D3)
    Mutant(
        "ignore-retained",
        f"{D}._mask_state",
        "mask type 01 leaves uncoded FAPs FREE (RETAINED ignored)",
        "FREE, RETAINED))",
        "FREE, FREE))",
    ),
    Mutant(
        "mask-type-2-as-1",
        f"{D}._mask_state",
        "mask type 10 treated as 01 (uncoded FAPs RETAINED, not FREE)",
        "(types_arr == MASK_INTERPOLATE) |",
        "(types_arr == -1) |",
    ),
    Mutant(
        "mask-bits-reversed",
        f"{D}.intra_header",
        "per-FAP mask bits of a group read in reverse FAP order",
        "for fap in g.faps:",
        "for fap in reversed(g.faps):",
    ),
    # --- new min/max lists (D4)
    Mutant(
        "minmax-marker-skipped",
        f"{D}.intra_header",
        "the marker bit every 4 list entries is not read",
        "if j % 4 == 0:\n",
        "if j % 4 == 0 and False:\n",
    ),
    Mutant(
        "minmax-lists-ignored",
        f"{D}.intra_header",
        "new min/max lists parsed but not applied",
        "self.bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
        "pass",
    ),
    Mutant(
        "minmax-sign-swapped",
        f"{D}.intra_header",
        "max lists taken as minima and vice versa",
        "v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
        "-v * RANGE_DELTA if li % 2 == 0 else v * RANGE_DELTA",
    ),
    # --- arithmetic block ends (D7)
    Mutant(
        "stuffing-not-removed",
        "fbaconf.bitstreams.arith:ArithDecoder._stuffing",
        "the stuffing bit after 22 zeros is not removed",
        "self.pos = at + 1",
        "self.pos = at",
        pure_decoder=True,
    ),
    Mutant(
        "wrong-rewind",
        "fbaconf.bitstreams.arith:ArithDecoder.finish",
        "block end: stuffing bits inside the 14-bit look-ahead counted too (S1's plain rewind)",
        "sum(1 for c in self.stuffing if c <= used)",
        "len(self.stuffing)",
        pure_decoder=True,
    ),
    Mutant(
        "model-no-halving",
        "fbaconf.bitstreams.arith:FastModel.update",
        "a predicted model is never halved at the total 16,383 (spec notes 3.2)",
        "if -int(a[0]) == MAX_FREQUENCY:",
        "if False:",
        pure_decoder=True,
    ),
    # --- high-level FAPs (D5)
    Mutant(
        "viseme-prediction-sign",
        f"{D}.payload",
        "predicted viseme_select1 subtracts the difference",
        "hl[0] += d1",
        "hl[0] -= d1",
        pure_decoder=True,
    ),
    Mutant(
        "intensity-not-scaled",
        f"{D}.payload",
        "expression_intensity1 not multiplied by the D5 step",
        "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep",
        "hl[4], hl[5], hl[6], hl[7] = e1, i1, e2, i2 * istep",
        pure_decoder=True,
    ),
    Mutant(
        "expression-field-order",
        f"{D}.payload",
        "intra expression fields read as select1, select2, intensity1...",
        "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep",
        "hl[4], hl[5], hl[6], hl[7] = e1, e2 * istep, i1, i2 * istep",
        pure_decoder=True,
    ),
    Mutant(
        "init-face-def-swapped",
        f"{D}.payload",
        "init_face and expression_def bits swapped",
        'hl[8] = r.bit("init_face")\n        hl[9] = r.bit("expression_def")',
        'hl[9] = r.bit("init_face")\n        hl[8] = r.bit("expression_def")',
        pure_decoder=True,
    ),
    # --- the blend/intensity alphabet across fap_quant changes and where D5's readings differ
    Mutant(
        "hl-alphabet-first-quant",
        f"{D}.payload",
        "blend/intensity alphabet computed once, from the first intra plane's fap_quant (values still x the "
        "current one)",
        patch=_hl_alphabet_first_quant,
        pure_decoder=True,
    ),
    Mutant(
        "hl-alphabet-floor",
        f"{D}.payload",
        "blend/intensity alphabet 0..floor(63/q) (S1's encoder, EPF tag FQU)",
        patch=lambda: _hl_alphabet(lambda q: syntax.INTENSITY_MAX // syntax.quant_div(q)),
        pure_decoder=True,
    ),
    Mutant(
        "hl-alphabet-ceil",
        f"{D}.payload",
        "blend/intensity alphabet 0..ceil(63/q) (D5's other reading)",
        patch=lambda: _hl_alphabet(syntax.intensity_bound_ceil),
        pure_decoder=True,
    ),
    Mutant(
        "viseme-select-unchecked",
        f"{D}.payload",
        "a decoded viseme_select outside 0..14 accepted",
        "if not 0 <= hl[k] <= mx:",
        "if False:",
        pure_decoder=True,
    ),
    # --- a marker bit of one new min/max list read but not checked
    *[
        Mutant(
            f"list-marker-unchecked-{name.replace('_', '-')}",
            f"{D}.intra_header",
            f"a 0 marker bit in the {name} list accepted (the other lists' markers checked)",
            'self.marker(info, f"marker_bit in {name} list (group {g.group})")',
            f'(r.bit if name == "{name}" else lambda w: self.marker(info, w))'
            '(f"marker_bit in {name} list (group {g.group})")',
        )
        for name in syntax.LIST_ORDER
    ],
    # --- the range rule (D4): a predicted value outside the range the intra alphabet codes
    Mutant(
        "pred-clamped-to-intra-range",
        f"{D}.payload",
        "a predicted value clamped to the range its intra alphabet codes",
        "cur[f - 1] = v\n",
        "lo_i, hi_i = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)\n"
        "            cur[f - 1] = min(max(v, lo_i * steps[f - 1]), hi_i * steps[f - 1])\n",
        pure_decoder=True,
    ),
    Mutant(
        "pred-outside-intra-rejected",
        f"{D}.payload",
        "a predicted value outside the range its intra alphabet codes rejected (the intra range read as the "
        "value range)",
        "cur[f - 1] = v\n",
        "lo_i, hi_i = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)\n"
        "            if not lo_i * steps[f - 1] <= v <= hi_i * steps[f - 1]:\n"
        "                raise self.err(f'FAP {f} value {v} outside the intra range', 'value-overflow', "
        "at=start, fap=f)\n"
        "            cur[f - 1] = v\n",
        pure_decoder=True,
    ),
    # --- timing (D6)
    Mutant(
        "skip-not-counted",
        f"{D}.plane",
        "skipped frames not counted in frame_number",
        "self.frame_number = self.frame_number + info.skip + 1",
        "self.frame_number = self.frame_number + 1",
    ),
    Mutant(
        "skip-chain-not-continued",
        "fbaconf.bitstreams.bitio:BitReader.skip_chain",
        "number_of_frames_to_skip = 15 does not continue the chain",
        "n15 = self.ones_run() // 4",
        "n15 = 0",
    ),
    Mutant(
        "time-code-ignored",
        f"{D}.plane",
        "time codes ignored: plane times keep counting frames",
        "if info.time_code is not None:",
        "if False:",
        pure_decoder=True,
    ),
    Mutant(
        "time-code-minutes-as-seconds",
        f"{D}.plane",
        "time code minutes counted as seconds",
        "(3600.0 * h + 60.0 * m + s) * 1000.0",
        "(3600.0 * h + m + s) * 1000.0",
        pure_decoder=True,
    ),
    Mutant(
        "default-rate-30",
        f"{D}.plane",
        "30 Hz (not 25 Hz, D6) when no frame rate is signalled",
        "rate = self.rate if self.rate is not None else default_frame_rate()",
        "rate = self.rate if self.rate is not None else 30.0",
        pure_decoder=True,
    ),
    Mutant(
        "skip-not-in-time",
        f"{D}.plane",
        "skipped frames not counted in the plane times",
        "self.time_ms = self.time_ms + (info.skip + 1) * 1000.0 / rate",
        "self.time_ms = self.time_ms + 1000.0 / rate",
        pure_decoder=True,
    ),
    Mutant(
        "frequency-offset-ignored",
        f"{D}.plane",
        "frequency_offset (x 1000/1001) ignored",
        "self.rate = fr.rate",
        "self.rate = fr.frame_rate + fr.seconds / 16.0",
        pure_decoder=True,
    ),
    # --- DCT (D8)
    Mutant(
        "dct-dc-prediction-ignored",
        "fbaconf.bitstreams.dct:decode_group",
        "predicted DCT groups: DC difference taken as the DC level",
        "level0 = prev + read_se(",
        "level0 = 0 * prev + read_se(",
    ),
    Mutant(
        "dct-scale-index-off-by-one",
        "fbaconf.bitstreams.dct:decode_group",
        "DCT scale factor of index + 1",
        "t.ac_step(f, index)",
        "t.ac_step(f, min(index + 1, 31))",
    ),
    # --- visemes, expressions, interpolation
    Mutant(
        "viseme-blend-inverted",
        "fbaconf.animation.highlevel:high_level_weights",
        "viseme_blend weights viseme 2 instead of viseme 1",
        "(v1, blend, vis_on, wv, NUM_VISEMES),\n        (v2, 1.0 - blend, vis_on, wv, NUM_VISEMES),",
        "(v1, 1.0 - blend, vis_on, wv, NUM_VISEMES),\n        (v2, blend, vis_on, wv, NUM_VISEMES),",
    ),
    Mutant(
        "left-right-fill-missing",
        "fbaconf.animation.engine:lr_fill",
        "left/right fill of unsent FAPs missing",
        patch=_no_lr_fill,
    ),
    Mutant(
        "fit-parent-order",
        "fbaconf.animation.interp:FitGraph.apply",
        "FIT: the last (not the first) available parent wins",
        "for ln in (l for l in self.links if l.child == child):",
        "for ln in reversed([l for l in self.links if l.child == child]):",
    ),
    Mutant(
        "fit-topological-order",
        "fbaconf.animation.interp:FitGraph._topological",
        "FIT: children evaluated before their parents",
        "return [i for i in order if i in has_parent]",
        "return [i for i in reversed(order) if i in has_parent]",
    ),
    Mutant(
        "fit-denominator-ignored",
        "fbaconf.animation.interp:FitGraph.apply",
        "FIT: denominator ignored",
        "val = num / np.where(den == 0, 1.0, den)",
        "val = num",
    ),
    Mutant(
        "fit-impulse-ignored",
        "fbaconf.animation.interp:RationalFunction._poly",
        "FIT: numeratorImpulse ignored",
        "terms[:, t] *= F[:, k - 1] == 0",
        "pass",
    ),
    # --- FaceDefTables
    Mutant(
        "facedefmesh-interval-clamp",
        "fbaconf.animation.facedef:interval_weights",
        "FaceDefMesh: the last interval clamped (not open upwards)",
        "wp = np.where(idx == n - 1, np.maximum(f - lo, 0.0), wp)",
        "wp = wp",
    ),
    Mutant(
        "facedefmesh-bottom-clamp",
        "fbaconf.animation.facedef:interval_weights",
        "FaceDefMesh: the first interval clamped (not open downwards)",
        "wn = np.where(idx == 0, np.maximum(hi - f, 0.0), wn)",
        "wn = wn",
    ),
    Mutant(
        "facedefmesh-zero-top",
        "fbaconf.animation.facedef:interval_weights",
        "FaceDefMesh: 0 as the top border not extended across 0",
        "if k == n:",
        "if False:",
    ),
    Mutant(
        "facedefmesh-no-fapu",
        "fbaconf.animation.facedef:MeshTable.displacement",
        "FaceDefMesh displacements not scaled by the FAPU",
        "return fapu * np.einsum(",
        "return np.einsum(",
    ),
    Mutant(
        "transform-axis-sign",
        "fbaconf.animation.facedef:transform_fields",
        "FaceDefTransform: rotation about the opposite axis direction",
        "axis_angle_matrices(tab.rotation[:3], a * tab.rotation[3])",
        "axis_angle_matrices(tab.rotation[:3], -a * tab.rotation[3])",
    ),
    Mutant(
        "transform-scale-absolute",
        "fbaconf.animation.facedef:transform_fields",
        "FaceDefTransform: scaleDef applied as is, not in proportion to the FAP",
        "s = s * (1.0 + a[:, None] * (np.asarray(tab.scale) - 1.0)[None, :])",
        "s = s * np.asarray(tab.scale)[None, :]",
    ),
    Mutant(
        "transform-no-fapu",
        "fbaconf.animation.facedef:transform_fields",
        "FaceDefTransform amplitudes not scaled by the FAPU",
        "* fapu_of(tab)",
        "",
    ),
    # --- FDP calibration, FAPU
    Mutant(
        "calibration-ignores-subset",
        "fbaconf.animation.calibrate:calibrate",
        "calibration ignores the feature points of groups 9-11 (nose, hair, ears)",
        "use = sent & have",
        "use = sent & have & np.array([not lab.startswith(('9.', '10.', '11.')) for lab in "
        "__import__('fbaconf.animation.faceparams', fromlist=['_']).FEATURE_POINTS])",
    ),
    Mutant(
        "wrong-fapu",
        "fbaconf.animation.faceparams:fapu_from_feature_points",
        "MNS (mouth-nose separation) taken from ENS (eye-nose separation)",
        "return Fapu(**{n: vals[n] for n in FAPU_NAMES})",
        'return Fapu(**{n: vals["ENS" if n == "MNS" else n] for n in FAPU_NAMES})',
    ),
    # --- decoder state across planes and faces
    Mutant(
        "lists-reset-at-intra",
        f"{D}.intra_header",
        "range lists forgotten at each intra plane: ranges not sent again fall back to the defaults",
        "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]",
        "self.bounds = tables.default_bounds().copy()\n    "
        "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]",
        pure_decoder=True,
    ),
    Mutant(
        "defaults-late-groups",
        "fbaconf.bitstreams.tables:default_bounds",
        "the default ranges of FAPs 40-50 copied wrong (halved)",
        patch=_late_group_defaults,
        pure_decoder=True,
    ),
    Mutant(
        "retained-rescaled",
        f"{D}.intra_header",
        "values held across a fap_quant change re-scaled to the new quantiser",
        patch=_retained_rescaled,
        pure_decoder=True,
    ),
    Mutant(
        "faces-share-lists",
        "fbaconf.reference.pipeline:multi_outputs",
        "faces decoded at once share one range-list table",
        patch=_faces_share_lists,
        pure_decoder=True,
    ),
    # --- rendering
    Mutant(
        "render-shifted-camera", "fbaconf.rendering.raster:project", "image centre one pixel off", patch=_camera_shift
    ),
]
# --- the look-ahead at a block end, position by position (D7; the coder-lookahead-* cases): a
# decoder that mishandles one window position p only (a bit-mask or index slip in its window bookkeeping)
_FINISH = "fbaconf.bitstreams.arith:ArithDecoder.finish"
LOOKAHEAD = arith.LOOKAHEAD
MUTANTS_LIST += [
    Mutant(
        f"lookahead-rewind-at-{p}",
        _FINISH,
        f"block end: a stuffing bit removed at look-ahead position {p} is counted in the block (D7 says hand it "
        "back): the next field starts one bit late",
        "sum(1 for c in self.stuffing if c <= used)",
        f"sum(1 for c in self.stuffing if c <= used or c == used + {p})",
        pure_decoder=True,
    )
    for p in range(1, LOOKAHEAD + 1)
] + [
    Mutant(
        f"lookahead-error-at-{p}",
        _FINISH,
        f"block end: a '0' in the stuffing slot at look-ahead position {p} is reported as an error (D7: those bits "
        "belong to the next field)",
        "if count <= used:",
        f"if count <= used or count == used + {p}:",
        pure_decoder=True,
    )
    for p in range(1, LOOKAHEAD + 1)
]
MUTANTS_LIST = MUTANTS_LIST + INDEPENDENT  # the suite's own (family "suite"), then the independent ones
MUTANTS: dict[str, Mutant] = {m.name: m for m in MUTANTS_LIST}
FAMILIES = ("suite", "independent")


def apply(name: str) -> Mutant:
    """Apply mutant ``name`` to this process (irreversible)."""
    return apply_mutant(MUTANTS[name])
