"""The coverage points a scene exercises (conformance/data/coverage.toml): its nodes,
FaceDefTables, FIT graph and what the reference compiles of it."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from fbaconf.animation.engine import compile_scene, effective_faps
from fbaconf.animation.faceparams import NUM_FEATURE_POINTS, fdp_point_rows
from fbaconf.animation.interp import FitGraph, lr_fill
from fbaconf.bitstreams.frames import DERIVED, FREE
from fbaconf.scenes import bt

# ------------------------------------------------------------------ scene extractors


def _compiled(scene_path: Path):
    """A scene and its compiled model, read once per file version (the views of a case, and the
    cases that share a scene, read the same file; neither result is changed by its readers)."""
    st = Path(scene_path).stat()
    return _compiled_at(str(Path(scene_path).resolve()), st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=16)
def _compiled_at(path: str, _mtime_ns: int, _size: int):
    scene = bt.read(path)
    return scene, compile_scene(scene)


def scene_points(scene_path: Path | None, frames) -> set[str]:  # noqa: C901
    """Points of a case's scene, with the case's decoded frames (for value-dependent points)."""
    hits: set[str] = set()
    if frames is not None and len(frames):
        v, s = lr_fill(frames.values.astype(np.float64), frames.status)
        if (s == DERIVED).any():
            hits.add("lrfill.derived")
    if scene_path is None:
        hits.add("model.default")
        return hits
    scene, model = _compiled(scene_path)
    faces = scene.find("Face")
    face = faces[0][0]
    fdp = scene.resolve(face.get("fdp"))
    graph = fdp.get("faceSceneGraph") if fdp is not None else []
    if graph:
        hits.add("model.downloaded")
        depth = _transform_depth(scene, graph)
        if depth >= 2:
            hits.add("model.nested-transforms")
    else:
        hits.add("model.default")
    if fdp is not None:
        fpc = scene.resolve(fdp.get("featurePointsCoord"))
        if fpc is not None and not graph:
            rows, sent = fdp_point_rows(fpc.get("point"))
            n = int(sent.sum())
            if n == NUM_FEATURE_POINTS:
                hits.add("calibration.all")
            elif n > 0:
                hits.add("calibration.subset")
            if 0 < n < 4:
                hits.add("calibration.few")
        if scene.resolve(fdp.get("textureCoord")) is not None:
            hits.add("calibration.texture")
        if fdp.get("useOrthoTexture"):
            hits.add("calibration.ortho")
    fit = scene.resolve(face.get("fit"))
    if fit is not None:
        hits |= _fit_points(fit)
    if graph and model.fp_vertices is None:
        hits.add("model.nonhuman")
    for t in model.mesh_tables:
        hits.add("facedef.mesh")
        if t.fap == 1:
            hits.add("facedef.highlevel-viseme")
        if t.fap == 2:
            hits.add("facedef.highlevel-expression")
        b = t.borders
        n = b.size - 1
        if n == 1:
            hits.add("facedef.interval.single")
        else:
            k = int(np.nonzero(b == 0)[0][0])
            hits.add(
                "facedef.interval.zero-bottom"
                if k == 0
                else "facedef.interval.zero-top"
                if k == n
                else "facedef.interval.zero-inner"
            )
    for t in model.transform_tables:
        hits.add(f"facedef.transform.{t.field}")
        if t.fap == 1:
            hits.add("facedef.highlevel-viseme")
        if t.fap == 2:
            hits.add("facedef.highlevel-expression")
    if frames is not None and len(frames):
        values, status = effective_faps(frames, model)
        if model.fit is not None and (status == DERIVED).any():
            # DERIVED also comes from left/right fill and visemes: FIT derived iff a child FAP is DERIVED
            # where it was FREE and its node has a parent available
            kids = {f for nd in (model.fit.nodes[c] for c in model.fit.order) for f in nd}
            if any(((status[:, f - 1] == DERIVED) & (frames.status[:, f - 1] == FREE)).any() for f in kids):
                hits.add("fit.derived")
        for tt in model.transform_tables:
            held = status[:, tt.fap - 1] != FREE
            if (values[held, tt.fap - 1] != 0).any():
                hits.add(f"facedef.transform.{tt.field}.driven")
        for t in model.mesh_tables:
            if t.fap <= 2 or t.borders.size <= 2:
                continue
            x = values[:, t.fap - 1]
            x = x[status[:, t.fap - 1] != FREE]
            b = t.borders
            if (x > b[-1]).any():
                hits.add("facedef.value.beyond-top")
            if (x < b[0]).any():
                hits.add("facedef.value.below-bottom")
            if b.size > 3 and ((x > b[1]) & (x < b[-2]) & ~np.isin(x, b)).any():
                hits.add("facedef.value.inner")
            if (x < 0).any():
                hits.add("facedef.value.negative")
    return hits


def _transform_depth(scene, graph) -> int:
    best = 0

    def visit(v, d):
        nonlocal best
        n = scene.resolve(v)
        if n is None:
            return
        if n.type == "Transform":
            d += 1
            best = max(best, d)
        if n.type in ("Transform", "Group"):
            for c in n.get("children"):
                visit(c, d)

    for v in graph:
        visit(v, 0)
    return best


def _fit_points(fit) -> set[str]:
    g = FitGraph.from_node(fit)
    hits = {"fit.link"} if g.links else set()
    children: dict[int, set] = {}
    parents: dict[int, set] = {}
    for ln in g.links:
        children.setdefault(ln.parent, set()).add(ln.child)
        parents.setdefault(ln.child, set()).add(ln.parent)
        for fn in ln.functions:
            if fn.num_exps.size and fn.num_exps.max() > 1 or fn.den_exps.size and fn.den_exps.max() > 1:
                hits.add("fit.polynomial")
            if fn.den_coefs.size and (fn.den_exps.any()):
                hits.add("fit.denominator")
            if fn.num_impulse.size and fn.num_impulse.any():
                hits.add("fit.impulse")
        if any(f in (1, 2) for f in g.nodes[ln.parent]):
            hits.add("fit.highlevel-parent")
    if any(len(c) >= 2 for c in children.values()):
        hits.add("fit.fan-out")
    if any(len(p) >= 2 for p in parents.values()):
        hits.add("fit.fan-in")
    if any(c in parents for c in children) and any(p in parents for p in children):
        if any(p in parents for c, ps in parents.items() for p in ps):
            hits.add("fit.chain")
    if any(len(nd) > 1 for i, nd in enumerate(g.nodes) if i in parents or i in children):
        hits.add("fit.multi-fap-node")
    return hits
