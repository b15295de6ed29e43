"""Independent mutants: animation (see the package docstring).

The animation of a face model from FAP values (animation/): left/right fill of unsent
symmetric FAPs, the FAP Interpolation Table (FIT) graph, visemes/expressions applied to FREE
FAPs only, FaceDefMesh interval weights (Ostermann 1998 steps 1-6), FaceDefTransform
rotation / scale / translation, FAPU from the feature points and FDP calibration. Written
from the spec notes, the seed papers and the reference source only; each is one plausible
misreading.
"""

from __future__ import annotations

from fbaconf.mutation.core import Mutant

INTERP = "fbaconf.animation.interp"
HL = "fbaconf.animation.highlevel"
FDEF = "fbaconf.animation.facedef"
ENG = "fbaconf.animation.engine"


def _m(name, where, description, old, new, rule, **kw) -> Mutant:
    return Mutant(
        name=name, where=where, description=description, old=old, new=new, family="independent", rule=rule, **kw
    )


MUTANTS_LIST: list[Mutant] = [
    # ------------------------------------------------------------------ left/right fill (IST 3.5.2)
    _m(
        "ind-anim-lr-negated",
        f"{INTERP}:lr_fill",
        "left/right fill copies the value with its sign flipped (reads 'mirror' as negation)",
        "values[to_b, ib] = values[to_b, ia]\n        values[to_a, ia] = values[to_a, ib]",
        "values[to_b, ib] = -values[to_b, ia]\n        values[to_a, ia] = -values[to_a, ib]",
        "IST 3.5.2 left/right fill is a plain copy",
    ),
    _m(
        "ind-anim-lr-left-to-right-only",
        f"{INTERP}:lr_fill",
        "left/right fill only copies the left FAP onto a free right FAP, never right onto left",
        "to_a = has_b & ~has_a",
        "to_a = has_b & False",
        "IST 3.5.2 left/right fill, both directions",
    ),
    _m(
        "ind-anim-lr-source-not-derived",
        f"{INTERP}:lr_fill",
        "a side derived by the FIT does not count as having a value (only SET/RETAINED are copied)",
        "has_a, has_b = status[:, ia] != FREE, status[:, ib] != FREE",
        "has_a, has_b = np.isin(status[:, ia], (1, 2)), np.isin(status[:, ib], (1, 2))",
        "interp.py: fill from SET/RETAINED/DERIVED",
    ),
    _m(
        "ind-anim-lr-sent-this-frame",
        f"{INTERP}:lr_fill",
        "left/right fill keys on 'sent in this frame' (SET): a RETAINED side is overwritten by the other side",
        "has_a, has_b = status[:, ia] != FREE, status[:, ib] != FREE",
        "has_a, has_b = status[:, ia] == 1, status[:, ib] == 1",
        "D3 / interp.py: only FREE FAPs are filled",
    ),
    _m(
        "ind-anim-lr-before-fit",
        f"{ENG}:effective_faps",
        "left/right fill runs before the FIT (so FIT-derived FAPs are never mirrored)",
        "if model.fit is not None:\n        values, status = model.fit.apply(values, status, frames.high)\n"
        "    values, status = lr_fill(values, status)\n",
        "values, status = lr_fill(values, status)\n    if model.fit is not None:\n"
        "        values, status = model.fit.apply(values, status, frames.high)\n",
        "interp.py order: FIT, then left/right fill",
    ),
    # ------------------------------------------------------------------ visemes / expressions
    _m(
        "ind-anim-hl-into-retained",
        f"{HL}:apply_high_level",
        "visemes/expressions overwrite every low-level FAP not sent in the frame (RETAINED/DERIVED too)",
        "target = touched & (status == FREE)",
        "target = touched & (status != 1)",
        "IST 3.1.1 high-level FAPs only touch FREE FAPs",
    ),
    _m(
        "ind-anim-viseme-blend-swapped",
        f"{HL}:high_level_weights",
        "viseme_blend weights viseme_select2 (v1 gets 1 - blend/63)",
        "v1, v2, blend = high[:, 0], high[:, 1], high[:, 2] / 63.0",
        "v2, v1, blend = high[:, 0], high[:, 1], high[:, 2] / 63.0",
        "§2.2 v1 * blend/63 + v2 * (1 - blend/63)",
    ),
    _m(
        "ind-anim-expression2-complement",
        f"{HL}:high_level_weights",
        "expression 2 weighted 1 - i1/63 like the viseme blend (expression_intensity2 ignored)",
        "e1, i1, e2, i2 = high[:, 4], high[:, 5] / 63.0, high[:, 6], high[:, 7] / 63.0",
        "e1, i1, e2, i2 = high[:, 4], high[:, 5] / 63.0, high[:, 6], 1.0 - high[:, 5] / 63.0",
        "§2.2 e1 * i1/63 + e2 * i2/63",
    ),
    _m(
        "ind-anim-hl-ignores-status",
        f"{HL}:high_level_weights",
        "the viseme is applied whatever FAP 1's status (a FREE viseme's held fields still animate)",
        "vis_on = status[:, 0] != FREE",
        "vis_on = np.ones(F, dtype=bool)",
        "highlevel.py: viseme applies where FAP 1 is not FREE",
    ),
    _m(
        "ind-anim-hl-writes-untouched",
        f"{HL}:apply_high_level",
        "in frames with a viseme/expression every FREE low-level FAP becomes DERIVED (0 where no table entry)",
        "target = touched & (status == FREE)",
        "touched[:, 2:] = ((wv.sum(axis=1) + we.sum(axis=1)) > 0)[:, None]\n    target = touched & (status == FREE)",
        "highlevel.py: only FAPs the tables mention",
        equivalent="it runs last (after the FIT and the left/right fill) and turns only FAPs no table mentions "
        "into DERIVED 0: a FAP of value 0 moves no vertex, and a FREE FAP's value is the decoder's "
        "choice (docs/harness.md), so vertices, images and the compared FAPs are equal; only the "
        "status bookkeeping in extra_fap_status differs",
    ),
    # ------------------------------------------------------------------ FaceDefMesh (Ostermann 1998 2.3.2)
    _m(
        "ind-anim-mesh-top-interval-closed",
        f"{FDEF}:interval_weights",
        "a FAP above the last border saturates (the last interval is not extended, step 3 ignored)",
        "wp = np.where(idx == n - 1, np.maximum(f - lo, 0.0), wp)",
        "wp = wp",
        "seed step 3: beyond I_max the last interval continues",
    ),
    _m(
        "ind-anim-mesh-bottom-interval-closed",
        f"{FDEF}:interval_weights",
        "a FAP below the first border saturates (the first interval is not extended, step 5 ignored)",
        "wn = np.where(idx == 0, np.maximum(hi - f, 0.0), wn)",
        "wn = wn",
        "seed step 5: below I_1 the first interval continues",
    ),
    _m(
        "ind-anim-mesh-negative-signed",
        f"{FDEF}:interval_weights",
        "for FAP < 0 the covered lengths are taken signed (negative), reversing the motion",
        "return np.where(f >= 0, wp, wn)",
        "return np.where(f >= 0, wp, -wn)",
        "seed step 4: positive interval lengths for FAP < 0",
    ),
    _m(
        "ind-anim-mesh-single-interval-clipped",
        f"{FDEF}:interval_weights",
        "with one interval the FAP is clipped to the two borders instead of strictly linear",
        "return f.copy()  # step 6: strictly linear",
        "return np.clip(f, b[0], b[1])",
        "seed step 6: one interval, P' = P + FAPU * FAP * D",
    ),
    _m(
        "ind-anim-mesh-zero-top-no-extension",
        f"{FDEF}:interval_weights",
        "when 0 is the top border a positive FAP moves nothing (no interval covers it)",
        "if k == n:  # 0 is the top border",
        "if False:  # 0 is the top border",
        "facedef.py: the interval touching 0 extends across 0",
    ),
    _m(
        "ind-anim-borders-equal-accepted",
        f"{FDEF}:validate_borders",
        "equal interval borders are accepted (only decreasing ones rejected)",
        "if np.any(np.diff(b) <= 0):",
        "if np.any(np.diff(b) < 0):",
        "intervalBorders strictly increasing",
    ),
    # ------------------------------------------------------------------ FaceDefTransform
    _m(
        "ind-anim-rotation-order",
        f"{FDEF}:transform_fields",
        "each FAP rotation is applied after (outside) the accumulated rotation, not inside it",
        "R = R @ axis_angle_matrices(tab.rotation[:3], a * tab.rotation[3])",
        "R = axis_angle_matrices(tab.rotation[:3], a * tab.rotation[3]) @ R",
        "facedef.py: R = R_neutral * R(FAP), tables in ascending fapID",
    ),
    _m(
        "ind-anim-transform-scene-order",
        f"{FDEF}:transform_fields",
        "tables on one Transform accumulate in scene order, not ascending fapID",
        "for tab in sorted(tables, key=lambda x: (x.fap, x.high_level_select)):",
        "for tab in tables:",
        "facedef.py: ascending fapID",
    ),
    _m(
        "ind-anim-scale-additive",
        f"{FDEF}:transform_fields",
        "the FAP scale is added to the neutral scale instead of multiplying it",
        "s = s * (1.0 + a[:, None] * (np.asarray(tab.scale) - 1.0)[None, :])",
        "s = s + a[:, None] * (np.asarray(tab.scale) - 1.0)[None, :]",
        "facedef.py: s = s_neutral * (1 + a (scaleDef - 1))",
    ),
    # ------------------------------------------------------------------ FAPU, calibration
    _m(
        "ind-anim-fapu-mns-ens-swapped",
        "fbaconf.animation.faceparams:Fapu.per_fap",
        "MNS FAPs are scaled by ENS and ENS FAPs by MNS (the two nose rows swapped)",
        "out[f.number - 1] = self.unit(f.fapu)",
        "out[f.number - 1] = self.unit({'MNS': 'ENS', 'ENS': 'MNS'}.get(f.fapu, f.fapu))",
        "§2.1 FAPU table",
    ),
    _m(
        "ind-anim-fapu-divisor-1000",
        "fbaconf.animation.faceparams:fapu_from_feature_points",
        "FAPU = distance / 1000 instead of / 1024",
        "vals[name] = d / info.divisor",
        "vals[name] = d / 1000.0",
        "§2.1 FAPU = distance / 1024",
    ),
    _m(
        "ind-anim-calib-fapu-not-recomputed",
        "fbaconf.animation.calibrate:calibrate",
        "after calibration the default model's FAPU are kept (not recomputed from the received points)",
        "fapu_from_feature_points(fps),",
        "model.fapu,",
        "calibrate.py: FAPU from the calibrated feature points",
    ),
    # ------------------------------------------------------------------ FIT (Ostermann 1998 3.3)
    _m(
        "ind-anim-fit-last-parent-first",
        f"{INTERP}:FitGraph.apply",
        "a child with several parents is interpolated from the last available parent, not the first",
        "for ln in (l for l in self.links if l.child == child):",
        "for ln in reversed([l for l in self.links if l.child == child]):",
        "interp.py: first parent in link order",
    ),
    _m(
        "ind-anim-fit-derived-parent-unavailable",
        f"{INTERP}:FitGraph.apply",
        "a parent FAP derived earlier in the pass does not count as available (chains stop after one level)",
        "avail = need & (status[:, pidx] != FREE).all(axis=1)",
        "avail = need & np.isin(status[:, pidx], (1, 2)).all(axis=1)",
        "interp.py: DERIVED parents available",
    ),
    _m(
        "ind-anim-fit-overwrites-node",
        f"{INTERP}:FitGraph.apply",
        "where a child node needs interpolation all its FAPs are written, also the ones sent",
        "free_here = status[rows, fap_idx] == FREE",
        "free_here = np.ones(len(rows), dtype=bool)",
        "interp.py: only FREE FAPs are written",
    ),
    _m(
        "ind-anim-fit-order-by-index",
        f"{INTERP}:FitGraph._topological",
        "child nodes are evaluated in node-number order, not in topological order of the graph",
        "return [i for i in order if i in has_parent]",
        "return [i for i in range(len(self.nodes)) if i in has_parent]",
        "interp.py: topological order",
    ),
    _m(
        "ind-anim-fit-fap1-is-select",
        f"{INTERP}:FitGraph.apply",
        "FAP 1 as a FIT parent takes the value viseme_select1 instead of viseme_blend",
        "ext[:, 0] = np.asarray(high)[:, 2]",
        "ext[:, 0] = np.asarray(high)[:, 0]",
        "interp.py: FAP 1 value = viseme_blend",
    ),
]
