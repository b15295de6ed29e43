"""Mutant decoders: the reference pipeline with one realistic bug injected, to measure the suites.

Each :class:`Mutant` names the place it changes (``module:qualname``) and how: most are
source mutations (one exact snippet of the reference function replaced, the function
recompiled in its module's namespace and installed), a few replace a function outright.
The bitstream mutants run the pure-Python block decoder (the C fast path is switched off
for the mutant) so that a change of the reference's Python code takes effect.

A mutant is applied to the WHOLE process and never undone, so it always runs in a process of
its own:

- ``python -m fbaconf.mutation.measure run NAME [--claim C] [--all-cases]`` applies the
  mutant and runs the required cases of the claim through the harness (in-process reference
  adapter, one case at a time, cheapest first), stopping at the first case that fails
  ("killed"); prints one JSON line.
- ``python -m fbaconf.mutation.measure decode NAME ...`` is the reference decoder program
  (``reference.decoder``) with the mutant applied: what :class:`MutantAdapter` (a manifest
  ``python = "fbaconf.mutation.measure:MutantAdapter"`` with ``[options] mutant = "NAME"``,
  bundled as ``harness/adapters/mutant.toml``) runs per case, so ``fbaconf run`` can run any
  mutant like any other decoder, in parallel, with no patch leaking into the harness.

``fbaconf suites mutants [-j N]`` runs every mutant (``-j`` processes at a time) and prints
the table and, last, ``mutation score: K/N``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from fbaconf.animation import engine
from fbaconf.bitstreams import arith, decoder, syntax, tables
from fbaconf.conformance.suite import CaseKind, golden_root, load_suites
from fbaconf.harness.adapters import ManifestError, PythonAdapter, resolve
from fbaconf.harness.runner import RunContext, run_case
from fbaconf.harness.selection import claim_covers
from fbaconf.mutation.core import Mutant, apply_mutant
from fbaconf.mutation.independent import MUTANTS_LIST as INDEPENDENT
from fbaconf.reference import decoder as refdecoder
from fbaconf.reference import pipeline
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
    Mutant("dequant-step-index", f"{D}.payload", "off-by-one in the dequantisation table: FAP f uses FAP f-1's step",
           "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
           "[low_level_step(f, q) for f in range(2, NUM_FAPS)]", pure_decoder=True),
    Mutant("dequant-quant-plus-one", f"{D}.payload", "off-by-one in dequantisation: step x (fap_quant + 1)",
           "[low_level_step(f, q) for f in range(3, NUM_FAPS + 1)]",
           "[low_level_step(f, q + 1) for f in range(3, NUM_FAPS + 1)]", pure_decoder=True),
    Mutant("prediction-sign", f"{D}.payload", "wrong sign in prediction: value = previous - error",
           "v = cur[f - 1] + s * steps[f - 1]", "v = cur[f - 1] - s * steps[f - 1]", pure_decoder=True),
    Mutant("intra-symbol-offset", f"{D}.payload", "intra symbols not offset by the alphabet minimum",
           "s = dec.decode(UniformModel(hi - lo + 1)) + lo", "s = dec.decode(UniformModel(hi - lo + 1))",
           pure_decoder=True),
    Mutant("alphabet-floor-division", "fbaconf.bitstreams.decoder:alphabet",
           "alphabets by floor division instead of D4's truncation toward zero", patch=_floor_alphabet,
           pure_decoder=True),
    Mutant("predicted-alphabet-from-intra-range", f"{D}.intra_header",
           "predicted alphabets built from the intra (not the predicted) range",
           "alphabet(int(self.bounds[f - 1, 3]), int(self.bounds[f - 1, 2]), q)",
           "alphabet(int(self.bounds[f - 1, 1]), int(self.bounds[f - 1, 0]), q)", pure_decoder=True),
    Mutant("non-adaptive-model", "fbaconf.bitstreams.decoder:make_model",
           "predicted planes decoded with non-adaptive frequency models", patch=_non_adaptive, pure_decoder=True),
    # --- masks (D3)
    Mutant("ignore-retained", f"{D}._mask_state", "mask type 01 leaves uncoded FAPs FREE (RETAINED ignored)",
           "FREE, RETAINED))", "FREE, FREE))"),
    Mutant("mask-type-2-as-1", f"{D}._mask_state", "mask type 10 treated as 01 (uncoded FAPs RETAINED, not FREE)",
           "(types_arr == MASK_INTERPOLATE) |", "(types_arr == -1) |"),
    Mutant("mask-bits-reversed", f"{D}.intra_header", "per-FAP mask bits of a group read in reverse FAP order",
           "for fap in g.faps:", "for fap in reversed(g.faps):"),
    # --- new min/max lists (D4)
    Mutant("minmax-marker-skipped", f"{D}.intra_header", "the marker bit every 4 list entries is not read",
           "if j % 4 == 0:\n", "if j % 4 == 0 and False:\n"),
    Mutant("minmax-lists-ignored", f"{D}.intra_header", "new min/max lists parsed but not applied",
           "self.bounds[fap - 1, li] = v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA", "pass"),
    Mutant("minmax-sign-swapped", f"{D}.intra_header", "max lists taken as minima and vice versa",
           "v * RANGE_DELTA if li % 2 == 0 else -v * RANGE_DELTA",
           "-v * RANGE_DELTA if li % 2 == 0 else v * RANGE_DELTA"),
    # --- arithmetic block ends (D7)
    Mutant("stuffing-not-removed", "fbaconf.bitstreams.arith:ArithDecoder._stuffing",
           "the stuffing bit after 22 zeros is not removed", "self.pos = at + 1", "self.pos = at",
           pure_decoder=True),
    Mutant("wrong-rewind", "fbaconf.bitstreams.arith:ArithDecoder.finish",
           "block end: stuffing bits inside the 14-bit look-ahead counted too (S1's plain rewind)",
           "sum(1 for c in self.stuffing if c <= used)", "len(self.stuffing)", pure_decoder=True),
    Mutant("model-no-halving", "fbaconf.bitstreams.arith:FastModel.update",
           "a predicted model is never halved at the total 16,383 (spec notes 3.2)",
           "if -int(a[0]) == MAX_FREQUENCY:", "if False:", pure_decoder=True),
    # --- high-level FAPs (D5)
    Mutant("viseme-prediction-sign", f"{D}.payload", "predicted viseme_select1 subtracts the difference",
           "hl[0] += d1", "hl[0] -= d1", pure_decoder=True),
    Mutant("intensity-not-scaled", f"{D}.payload", "expression_intensity1 not multiplied by the D5 step",
           "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep",
           "hl[4], hl[5], hl[6], hl[7] = e1, i1, e2, i2 * istep", pure_decoder=True),
    Mutant("expression-field-order", f"{D}.payload", "intra expression fields read as select1, select2, intensity1...",
           "hl[4], hl[5], hl[6], hl[7] = e1, i1 * istep, e2, i2 * istep",
           "hl[4], hl[5], hl[6], hl[7] = e1, e2 * istep, i1, i2 * istep", pure_decoder=True),
    Mutant("init-face-def-swapped", f"{D}.payload", "init_face and expression_def bits swapped",
           'hl[8] = r.bit("init_face")\n        hl[9] = r.bit("expression_def")',
           'hl[9] = r.bit("init_face")\n        hl[8] = r.bit("expression_def")', pure_decoder=True),
    # --- the blend/intensity alphabet across fap_quant changes and where D5's readings differ (issue 37)
    Mutant("hl-alphabet-first-quant", f"{D}.payload",
           "blend/intensity alphabet computed once, from the first intra plane's fap_quant (values still x the "
           "current one)", patch=_hl_alphabet_first_quant, pure_decoder=True),
    Mutant("hl-alphabet-floor", f"{D}.payload", "blend/intensity alphabet 0..floor(63/q) (S1's encoder, EPF tag FQU)",
           patch=lambda: _hl_alphabet(lambda q: syntax.INTENSITY_MAX // syntax.quant_div(q)), pure_decoder=True),
    Mutant("hl-alphabet-ceil", f"{D}.payload", "blend/intensity alphabet 0..ceil(63/q) (D5's other reading)",
           patch=lambda: _hl_alphabet(syntax.intensity_bound_ceil), pure_decoder=True),
    Mutant("viseme-select-unchecked", f"{D}.payload", "a decoded viseme_select outside 0..14 accepted",
           "if not 0 <= hl[k] <= mx:", "if False:", pure_decoder=True),
    # --- a marker bit of one new min/max list read but not checked (issue 37)
    *[Mutant(f"list-marker-unchecked-{name.replace('_', '-')}", f"{D}.intra_header",
             f"a 0 marker bit in the {name} list accepted (the other lists' markers checked)",
             'self.marker(info, f"marker_bit in {name} list (group {g.group})")',
             f'(r.bit if name == "{name}" else lambda w: self.marker(info, w))'
             '(f"marker_bit in {name} list (group {g.group})")') for name in syntax.LIST_ORDER],
    # --- the range rule (D4): a predicted value outside the range the intra alphabet codes (issue 37)
    Mutant("pred-clamped-to-intra-range", f"{D}.payload",
           "a predicted value clamped to the range its intra alphabet codes",
           "cur[f - 1] = v\n",
           "lo_i, hi_i = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)\n"
           "            cur[f - 1] = min(max(v, lo_i * steps[f - 1]), hi_i * steps[f - 1])\n", pure_decoder=True),
    Mutant("pred-outside-intra-rejected", f"{D}.payload",
           "a predicted value outside the range its intra alphabet codes rejected (the intra range read as the "
           "value range)", "cur[f - 1] = v\n",
           "lo_i, hi_i = alphabet(int(bounds[f - 1, 1]), int(bounds[f - 1, 0]), q)\n"
           "            if not lo_i * steps[f - 1] <= v <= hi_i * steps[f - 1]:\n"
           "                raise self.err(f'FAP {f} value {v} outside the intra range', 'value-overflow', "
           "at=start, fap=f)\n"
           "            cur[f - 1] = v\n", pure_decoder=True),
    # --- timing (D6)
    Mutant("skip-not-counted", f"{D}.plane", "skipped frames not counted in frame_number",
           "self.frame_number = self.frame_number + info.skip + 1", "self.frame_number = self.frame_number + 1"),
    Mutant("skip-chain-not-continued", "fbaconf.bitstreams.bitio:BitReader.skip_chain",
           "number_of_frames_to_skip = 15 does not continue the chain",
           "n15 = self.ones_run() // 4", "n15 = 0"),
    Mutant("time-code-ignored", f"{D}.plane", "time codes ignored: plane times keep counting frames",
           "if info.time_code is not None:", "if False:", pure_decoder=True),
    Mutant("time-code-minutes-as-seconds", f"{D}.plane", "time code minutes counted as seconds",
           "(3600.0 * h + 60.0 * m + s) * 1000.0", "(3600.0 * h + m + s) * 1000.0", pure_decoder=True),
    Mutant("default-rate-30", f"{D}.plane", "30 Hz (not 25 Hz, D6) when no frame rate is signalled",
           "rate = self.rate if self.rate is not None else default_frame_rate()",
           "rate = self.rate if self.rate is not None else 30.0", pure_decoder=True),
    Mutant("skip-not-in-time", f"{D}.plane", "skipped frames not counted in the plane times",
           "self.time_ms = self.time_ms + (info.skip + 1) * 1000.0 / rate",
           "self.time_ms = self.time_ms + 1000.0 / rate", pure_decoder=True),
    Mutant("frequency-offset-ignored", f"{D}.plane", "frequency_offset (x 1000/1001) ignored",
           "self.rate = fr.rate", "self.rate = fr.frame_rate + fr.seconds / 16.0", pure_decoder=True),
    # --- DCT (D8)
    Mutant("dct-dc-prediction-ignored", "fbaconf.bitstreams.dct:decode_group",
           "predicted DCT groups: DC difference taken as the DC level", "level0 = prev + read_se(",
           "level0 = 0 * prev + read_se("),
    Mutant("dct-scale-index-off-by-one", "fbaconf.bitstreams.dct:decode_group",
           "DCT scale factor of index + 1", "t.ac_step(f, index)", "t.ac_step(f, min(index + 1, 31))"),
    # --- visemes, expressions, interpolation
    Mutant("viseme-blend-inverted", "fbaconf.animation.highlevel:high_level_weights",
           "viseme_blend weights viseme 2 instead of viseme 1",
           "((v1, blend, vis_on, wv, NUM_VISEMES), (v2, 1.0 - blend, vis_on, wv, NUM_VISEMES),",
           "((v1, 1.0 - blend, vis_on, wv, NUM_VISEMES), (v2, blend, vis_on, wv, NUM_VISEMES),"),
    Mutant("left-right-fill-missing", "fbaconf.animation.engine:lr_fill", "left/right fill of unsent FAPs missing",
           patch=_no_lr_fill),
    Mutant("fit-parent-order", "fbaconf.animation.interp:FitGraph.apply",
           "FIT: the last (not the first) available parent wins",
           "for ln in (l for l in self.links if l.child == child):",
           "for ln in reversed([l for l in self.links if l.child == child]):"),
    Mutant("fit-topological-order", "fbaconf.animation.interp:FitGraph._topological",
           "FIT: children evaluated before their parents", "return [i for i in order if i in has_parent]",
           "return [i for i in reversed(order) if i in has_parent]"),
    Mutant("fit-denominator-ignored", "fbaconf.animation.interp:FitGraph.apply", "FIT: denominator ignored",
           "val = num / np.where(den == 0, 1.0, den)", "val = num"),
    Mutant("fit-impulse-ignored", "fbaconf.animation.interp:RationalFunction._poly",
           "FIT: numeratorImpulse ignored", "terms[:, t] *= (F[:, k - 1] == 0)", "pass"),
    # --- FaceDefTables
    Mutant("facedefmesh-interval-clamp", "fbaconf.animation.facedef:interval_weights",
           "FaceDefMesh: the last interval clamped (not open upwards)",
           "wp = np.where(idx == n - 1, np.maximum(f - lo, 0.0), wp)", "wp = wp"),
    Mutant("facedefmesh-bottom-clamp", "fbaconf.animation.facedef:interval_weights",
           "FaceDefMesh: the first interval clamped (not open downwards)",
           "wn = np.where(idx == 0, np.maximum(hi - f, 0.0), wn)", "wn = wn"),
    Mutant("facedefmesh-zero-top", "fbaconf.animation.facedef:interval_weights",
           "FaceDefMesh: 0 as the top border not extended across 0", "if k == n:", "if False:"),
    Mutant("facedefmesh-no-fapu", "fbaconf.animation.facedef:MeshTable.displacement",
           "FaceDefMesh displacements not scaled by the FAPU", "return fapu * np.einsum(", "return np.einsum("),
    Mutant("transform-axis-sign", "fbaconf.animation.facedef:transform_fields",
           "FaceDefTransform: rotation about the opposite axis direction",
           "axis_angle_matrices(tab.rotation[:3], a * tab.rotation[3])",
           "axis_angle_matrices(tab.rotation[:3], -a * tab.rotation[3])"),
    Mutant("transform-scale-absolute", "fbaconf.animation.facedef:transform_fields",
           "FaceDefTransform: scaleDef applied as is, not in proportion to the FAP",
           "s = s * (1.0 + a[:, None] * (np.asarray(tab.scale) - 1.0)[None, :])",
           "s = s * np.asarray(tab.scale)[None, :]"),
    Mutant("transform-no-fapu", "fbaconf.animation.facedef:transform_fields",
           "FaceDefTransform amplitudes not scaled by the FAPU",
           "* fapu_of(tab)", ""),
    # --- FDP calibration, FAPU
    Mutant("calibration-ignores-subset", "fbaconf.animation.calibrate:calibrate",
           "calibration ignores the feature points of groups 9-11 (nose, hair, ears)",
           "use = sent & have", "use = sent & have & np.array([not lab.startswith(('9.', '10.', '11.')) for lab in "
           "__import__('fbaconf.animation.faceparams', fromlist=['_']).FEATURE_POINTS])"),
    Mutant("wrong-fapu", "fbaconf.animation.faceparams:fapu_from_feature_points",
           "MNS (mouth-nose separation) taken from ENS (eye-nose separation)",
           "return Fapu(**{n: vals[n] for n in FAPU_NAMES})",
           'return Fapu(**{n: vals["ENS" if n == "MNS" else n] for n in FAPU_NAMES})'),
    # --- decoder state across planes and faces (issue 15)
    Mutant("lists-reset-at-intra", f"{D}.intra_header",
           "range lists forgotten at each intra plane: ranges not sent again fall back to the defaults",
           "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]",
           "self.bounds = tables.default_bounds().copy()\n    "
           "flags = [r.bit(f\"is_{name.replace('_', '_new_')}\") for name in LIST_ORDER]", pure_decoder=True),
    Mutant("defaults-late-groups", "fbaconf.bitstreams.tables:default_bounds",
           "the default ranges of FAPs 40-50 copied wrong (halved)", patch=_late_group_defaults, pure_decoder=True),
    Mutant("retained-rescaled", f"{D}.intra_header",
           "values held across a fap_quant change re-scaled to the new quantiser", patch=_retained_rescaled,
           pure_decoder=True),
    Mutant("faces-share-lists", "fbaconf.reference.pipeline:multi_outputs",
           "faces decoded at once share one range-list table", patch=_faces_share_lists, pure_decoder=True),
    # --- rendering
    Mutant("render-shifted-camera", "fbaconf.rendering.raster:project", "image centre one pixel off",
           patch=_camera_shift),
]
# --- the look-ahead at a block end, position by position (D7; the coder-lookahead-* cases, issue 33): a
# decoder that mishandles one window position p only (a bit-mask or index slip in its window bookkeeping)
_FINISH = "fbaconf.bitstreams.arith:ArithDecoder.finish"
LOOKAHEAD = arith.LOOKAHEAD
MUTANTS_LIST += [
    Mutant(f"lookahead-rewind-at-{p}", _FINISH,
           f"block end: a stuffing bit removed at look-ahead position {p} is counted in the block (D7 says hand it "
           "back): the next field starts one bit late",
           "sum(1 for c in self.stuffing if c <= used)",
           f"sum(1 for c in self.stuffing if c <= used or c == used + {p})",
           pure_decoder=True) for p in range(1, LOOKAHEAD + 1)] + [
    Mutant(f"lookahead-error-at-{p}", _FINISH,
           f"block end: a '0' in the stuffing slot at look-ahead position {p} is reported as an error (D7: those bits "
           "belong to the next field)", "if count <= used:", f"if count <= used or count == used + {p}:",
           pure_decoder=True) for p in range(1, LOOKAHEAD + 1)]
MUTANTS_LIST = MUTANTS_LIST + INDEPENDENT  # the suite's own (family "suite"), then the independent ones
MUTANTS: dict[str, Mutant] = {m.name: m for m in MUTANTS_LIST}
FAMILIES = ("suite", "independent")


def apply(name: str) -> Mutant:
    """Apply mutant ``name`` to this process (irreversible)."""
    return apply_mutant(MUTANTS[name])


# ------------------------------------------------------------------ running one mutant


def _case_cost(c) -> tuple:
    order = {"decode": 0, "multi": 1, "error": 3}
    heavy = 2 if "images" in c.stages else 1 if "vertices" in c.stages else 0
    return (order.get(c.kind, 2), heavy, c.frames, c.full_id)


def run_mutant(name: str | None, claim: str = "predictable@2", *, stop_at_first: bool = True,
               out_dir: Path | None = None, cases=None, formats: tuple[str, ...] = ("npz", "fap")) -> dict:
    """Apply ``name`` (None: the plain reference) and run the cases of ``claim`` through the
    harness, cheapest first: the required ones and the .fap player cases (the reference reads
    both, and a decoder's .fap reader is code a mutant can break), once with each FAP output
    format in ``formats`` (the second format only for the cases that compare FAPs, only while
    the mutant lives). Returns {mutant, killed, killed_by, failing, ran, total, seconds}."""
    t0 = time.perf_counter()
    if name is not None:
        apply(name)
    adapter = resolve("reference-inprocess")
    all_outputs = list(adapter.outputs)
    if cases is None:
        cases = [c for s in load_suites() for c in s.cases if claim_covers(claim, c.claim)]
    cases = sorted(cases, key=_case_cost)
    if stop_at_first:
        cases = [c for c in cases if c.kind != CaseKind.ERROR] + [c for c in cases if c.kind == CaseKind.ERROR]
    plan = [(c, formats[0]) for c in cases]
    for fmt in formats[1:]:
        plan += [(c, fmt) for c in cases if "faps" in (c.stages or ["faps"]) and c.kind != CaseKind.ERROR]
    failing, ran = [], 0
    with tempfile.TemporaryDirectory(prefix="fbaconf-mutant-") as tmp:
        ctx = RunContext(adapter, claim, Path(out_dir or tmp), golden_root(), False, Path(tmp))
        for c, fmt in plan:
            # produce only what the case compares (the in-process reference renders otherwise)
            adapter.outputs = [s for s in all_outputs if s in (c.stages or ["faps"])] or ["faps"]
            adapter.faps_format = fmt
            r = run_case(ctx, c)
            ran += 1
            if r.outcome.failing:
                failing.append({"case": c.full_id if fmt == formats[0] else f"{c.full_id} ({fmt})",
                                "outcome": r.outcome.value, "message": r.message[:300]})
                if stop_at_first:
                    break
    return {"mutant": name or "reference", "killed": bool(failing),
            "killed_by": failing[0]["case"] if failing else None,
            "failing": failing, "ran": ran, "total": len(plan), "seconds": round(time.perf_counter() - t0, 2)}


def run_all(names: list[str] | None = None, *, claim: str = "predictable@2", jobs: int | None = None,
            stop_at_first: bool = True, timeout: float = 900.0) -> list[dict]:
    """Every mutant (or ``names``) in its own process, ``jobs`` at a time."""
    names = names or list(MUTANTS)
    jobs = jobs or os.cpu_count() or 1

    def one(n: str) -> dict:
        argv = [sys.executable, "-m", "fbaconf.mutation.measure", "run", n, "--claim", claim]
        if not stop_at_first:
            argv.append("--all-cases")
        try:
            p = subprocess.run(argv, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"mutant": n, "killed": False, "killed_by": None, "error": f"timed out after {timeout:g} s"}
        for line in reversed(p.stdout.splitlines()):
            if line.startswith("{"):
                return json.loads(line)
        return {"mutant": n, "killed": False, "killed_by": None,
                "error": f"exit {p.returncode}: {p.stderr.strip()[-400:]}"}

    with ThreadPoolExecutor(max_workers=jobs) as ex:
        return list(ex.map(one, names))


def score(results: list[dict], family: str | None = None) -> tuple[int, int, int]:
    """(killed, scored, equivalent) over ``results`` (of one mutant ``family``, or all)."""
    rows = [r for r in results if family is None or getattr(MUTANTS.get(r["mutant"]), "family", None) == family]
    equivalent = [r for r in rows if getattr(MUTANTS.get(r["mutant"]), "equivalent", "")]
    scored = [r for r in rows if r not in equivalent]
    return sum(1 for r in scored if r["killed"]), len(scored), len(equivalent)


def format_results(results: list[dict]) -> str:
    lines = [f"{'mutant':38s} {'verdict':10s} killed by"]
    for r in results:
        m = MUTANTS.get(r["mutant"])
        eq = getattr(m, "equivalent", "")
        verdict = "killed" if r["killed"] else "equivalent" if eq else "SURVIVED"
        by = r.get("killed_by") or r.get("error") or "-"
        lines.append(f"{r['mutant']:38s} {verdict:10s} {by}")
        if not r["killed"] and m is not None:
            lines.append(f"{'':38s}            ({eq or m.description}; {m.where})")
    for fam in FAMILIES:
        k, n, e = score(results, fam)
        if n or e:
            lines.append(f"{fam} mutants: {k}/{n} killed" + (f", {e} equivalent (not scored)" if e else ""))
    k, n, _ = score(results)
    lines.append(f"mutation score: {k}/{n}")
    return "\n".join(lines)


# ------------------------------------------------------------------ adapter


class MutantAdapter(PythonAdapter):
    """In-process adapter class for manifests: each case runs the mutant decoder program in a
    subprocess (``python -m fbaconf.mutation.measure decode NAME ...``), so the mutant's
    patches never touch the harness process (thread-safe with ``-j``)."""
    supports_multi = True
    description = "fbaconf reference decoder with one injected bug (mutation/measure.py)"

    def __init__(self, mutant: str = "") -> None:
        super().__init__()
        if mutant not in MUTANTS:
            raise ManifestError(f"[options] mutant = {mutant!r}: unknown (known: {', '.join(MUTANTS)})",
                                rule="manifest-options")
        self.mutant = mutant

    def run(self, job) -> None:
        base = [sys.executable, "-m", "fbaconf.mutation.measure", "decode", self.mutant]
        if job.faces:
            argv = base + ["decode-multi", "--out-dir", str(job.path("faps_out_dir")),
                           "--format", self.faps_format] + list(job.faces)
        else:
            argv = base + ["decode", str(job.path("input"))]
            for opt, key in (("--scene", "scene"), ("--scenario", "scenario")):
                if job.values.get(key):
                    argv += [opt, job.values[key]]
            if "faps" in self.outputs:
                argv += ["--faps-out", job.values["faps_out"]]
            if "vertices" in self.outputs:
                argv += ["--vertices-out", job.values["vertices_out"]]
            if "images" in self.outputs:
                argv += ["--images-dir", job.values["images_dir"]]
        p = subprocess.run(argv, capture_output=True, text=True, timeout=self.limits.timeout_s)
        if p.returncode != 0:
            raise RuntimeError(f"mutant decoder exited {p.returncode}: {p.stderr.strip()[-300:]}")


# ------------------------------------------------------------------ program


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fbaconf.mutation.measure",
                                 description="Run one mutant decoder (see the module doc).")
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="run the suites against one mutant; prints one JSON line")
    r.add_argument("name", help="mutant name, or 'reference' for the unmodified reference")
    r.add_argument("--claim", default="predictable@2")
    r.add_argument("--all-cases", action="store_true")
    d = sub.add_parser("decode", help="the reference decoder program with the mutant applied")
    d.add_argument("name")
    d.add_argument("rest", nargs=argparse.REMAINDER, help="arguments of python -m fbaconf.reference.decoder")
    sub.add_parser("list", help="list the mutants")
    a = ap.parse_args(argv)
    if a.cmd == "list":
        for m in MUTANTS_LIST:
            print(f"{m.name:38s} {m.description}")
        return 0
    if a.name != "reference" and a.name not in MUTANTS:
        print(f"unknown mutant {a.name!r}", file=sys.stderr)
        return 2
    if a.cmd == "decode":
        if a.name != "reference":
            apply(a.name)
        return refdecoder.main(a.rest)
    res = run_mutant(None if a.name == "reference" else a.name, a.claim, stop_at_first=not a.all_cases)
    print(json.dumps(res))
    return 0


if __name__ == "__main__":
    sys.exit(main())
