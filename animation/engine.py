"""The reference animation engine: FapFrames + scene -> FaceState (vertices per frame).

``animate(frames, scene=None)``: ``scene`` is a parsed :class:`bt.Scene`, a path to a BT
file, or None for the bundled default head. Which face is animated:

* the FDP has a ``faceSceneGraph`` -> that downloaded model, animated exactly by the
  scene's FaceDefTables (Predictable profile); FAPU from its ``featurePointsCoord``;
* otherwise the bundled default head (its own generated FaceDefTables), calibrated to the
  FDP's ``featurePointsCoord`` when given (Calibration profile, see calibrate.py), with
  texture coordinates from ``textureCoord`` when given.

Per frame (all vectorised over frames): FAP values from the bitstream (a FAP that is
still FREE after interpolation keeps the value the FapFrames hold: the last value set, 0
when never set) -> FIT (when the Face has one) -> left/right fill -> visemes/expressions
(default tables, or the scene's FaceDefTables with fapID 1/2 + highLevelSelect) ->
FaceDefMesh displacements added to the neutral IndexedFaceSet points (several tables on one
vertex add up) -> FaceDefTransform fields -> Transform hierarchy (VRML order
T * C * R * SR * S * SR^-1 * C^-1, parents first) -> world vertices.

``featurePointsCoord`` holds the 84 points in label order (faceparams.FEATURE_POINTS); a
point is "not sent" when all three coordinates are >= ``UNSENT`` (3.4e38, the SFFloat
maximum) -- fbaconf's convention for subsets, see docs/animation.md.

FaceState extras: ``fap_values`` float64[F, 68] (after interpolation), ``fap_status``
uint8[F, 68], and ``feature_points`` float64[F, 84, 3] when every feature point of the
model lies on a vertex (the default head, calibrated or not).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fbaconf.bitstreams.frames import FapFrames
from fbaconf.bitstreams.tables import NUM_FAPS
from fbaconf.errors import SceneError
from fbaconf.scenes import bifs, bt

from .bundled import default_head_feature_vertices, default_head_scene
from .calibrate import calibrate
from .compiled import CompiledFace, PartInstance, local_matrices, neutral_world
from .facedef import MeshTable, TransformTable, transform_fields
from .faceparams import FEATURE_POINTS, NUM_FEATURE_POINTS, UNSENT, fapu_from_feature_points, fdp_point_rows
from .facestate import FaceState, MeshPart
from .highlevel import apply_high_level, high_level_weights
from .interp import FitGraph, lr_fill


# ---------------------------------------------------------------------------------- compile
def _find_face(scene: bt.Scene) -> tuple[bt.Node, str]:
    faces = scene.find("Face")
    if not faces:
        raise SceneError("the scene has no Face node", rule="scene-no-face", node_path="(top level)")
    return faces[0]


def feature_points_from_fdp(scene: bt.Scene, fdp: bt.Node | None, path: str) -> np.ndarray:
    """float64[84, 3] from FDP.featurePointsCoord (NaN rows = not sent); all NaN when absent."""
    out = np.full((NUM_FEATURE_POINTS, 3), np.nan)
    if fdp is None:
        return out
    c = scene.resolve(fdp.get("featurePointsCoord"))
    if c is None:
        return out
    pts, sent = fdp_point_rows(c.get("point"))
    if pts.shape[0] != NUM_FEATURE_POINTS:
        raise SceneError(
            f"featurePointsCoord must list the 84 feature points in label order (unsent ones as "
            f"{UNSENT:g}), got {pts.shape[0]}",
            rule="fdp-feature-point-count",
            node_path=f"{path}.featurePointsCoord",
        )
    out[sent] = pts[sent]
    return out


def _triangulate(ci: np.ndarray, n: int, ccw: bool, path: str) -> np.ndarray:
    ci = np.asarray(ci, dtype=np.int64)
    bad = np.nonzero((ci < -1) | (ci >= n))[0]
    if bad.size:
        raise SceneError(
            f"coordIndex[{int(bad[0])}] = {int(ci[bad[0]])} names a point the Coordinate does not have ({n} points)",
            rule="geometry-index",
            node_path=f"{path}.coordIndex",
        )
    tris = []
    # fast path: all triangles
    if ci.size % 4 == 0 and ci.size and np.all(ci[3::4] == -1) and np.all(ci.reshape(-1, 4)[:, :3] >= 0):
        t = ci.reshape(-1, 4)[:, :3]
    else:
        poly = []
        for v in list(ci) + [-1]:
            if v == -1:
                for k in range(1, len(poly) - 1):
                    tris.append((poly[0], poly[k], poly[k + 1]))
                poly = []
            else:
                poly.append(int(v))
        t = np.array(tris, dtype=np.int64).reshape(-1, 3)
    if not ccw:
        t = t[:, ::-1]
    return np.ascontiguousarray(t)


def compile_scene(scene: bt.Scene | None) -> CompiledFace:
    """Compile a scene (None = the bundled default head) into a CompiledFace."""
    if scene is None:
        return _compiled_default()
    face, fpath = _find_face(scene)
    fdp = scene.resolve(face.get("fdp"))
    fdp_path = f"{fpath}.fdp.FDP"
    fps = feature_points_from_fdp(scene, fdp, fdp_path)
    fit = None
    fit_node = scene.resolve(face.get("fit"))
    if fit_node is not None:
        fit = FitGraph.from_node(fit_node, node_path=f"{fpath}.fit.FIT")
    graph = fdp.get("faceSceneGraph") if fdp is not None else []
    if fdp is None or not graph:
        if fdp is not None and len(fdp.get("faceDefTables")):
            raise SceneError(
                "faceDefTables need a downloaded model (faceSceneGraph) to animate",
                rule="facedef-without-model",
                node_path=f"{fdp_path}.faceDefTables",
            )
        model = _compiled_default()
        if np.isfinite(fps).all(axis=1).any():
            tex = scene.resolve(fdp.get("textureCoord"))
            tc = None if tex is None else np.asarray(tex.get("point"), dtype=np.float64)
            model = calibrate(
                model,
                fps,
                texture_coords=tc,
                ortho=bool(fdp.get("useOrthoTexture")),
                texture=_first_texture(scene),
                node_path=fdp_path,
            )
        model.fit = fit
        return model
    model = _compile_graph(scene, graph, fdp, fdp_path, fps)
    model.fit = fit
    return model


def _first_texture(scene: bt.Scene) -> str | None:
    for n, _ in scene.find("ImageTexture"):
        urls = n.get("url")
        if urls:
            return urls[0]
    return None


def _compile_graph(scene, graph, fdp, fdp_path, fps) -> CompiledFace:
    points: dict[int, np.ndarray] = {}
    names: dict[int, str] = {}
    transforms: dict[int, dict] = {}
    parts: list[PartInstance] = []
    path_of: dict[int, str] = {}

    def visit(v, path, chain):
        node = scene.resolve(v)
        if node is None:
            return
        if node.type == "Transform":
            key = id(node)
            if key not in transforms:
                fields = {k: node.get(k) for k in ("center", "rotation", "scale", "scaleOrientation", "translation")}
                vals = [x for k in fields for x in fields[k]]
                if not np.all(np.isfinite(vals)):
                    raise SceneError("Transform fields must be finite", rule="geometry-finite", node_path=path)
                transforms[key] = dict(name=node.def_name or f"Transform@{path}", **fields)
            for i, c in enumerate(node.get("children")):
                visit(c, f"{path}.children[{i}]", chain + [key])
        elif node.type == "Group":
            for i, c in enumerate(node.get("children")):
                visit(c, f"{path}.children[{i}]", chain)
        elif node.type == "Shape":
            geo = scene.resolve(node.get("geometry"))
            if geo is None:
                return
            gpath = f"{path}.geometry.{geo.type}"
            if geo.type != "IndexedFaceSet":
                raise SceneError(
                    f"geometry {geo.type} is not supported (IndexedFaceSet only)",
                    rule="geometry-unsupported",
                    node_path=gpath,
                )
            key = id(geo)
            coord = scene.resolve(geo.get("coord"))
            if coord is None:
                raise SceneError("IndexedFaceSet without coord", rule="geometry-no-coord", node_path=gpath)
            pts = np.asarray(coord.get("point"), dtype=np.float64).reshape(-1, 3)
            if not np.all(np.isfinite(pts)):
                raise SceneError("non-finite coordinates", rule="geometry-finite", node_path=f"{gpath}.coord")
            points.setdefault(key, pts)
            names.setdefault(key, geo.def_name or f"IFS@{gpath}")
            path_of.setdefault(key, gpath)
            tris = _triangulate(geo.get("coordIndex"), len(pts), bool(geo.get("ccw")), gpath)
            color, spec, shin, texture = _appearance(scene, scene.resolve(node.get("appearance")))
            vcol, uv = _vertex_colors(scene, geo, len(pts)), _tex_coords(scene, geo, len(pts))
            name = names[key] if sum(1 for p in parts if p.ifs == key) == 0 else f"{names[key]}#{len(parts)}"
            parts.append(PartInstance(name, key, list(chain), tris, color, vcol, uv, texture, spec, shin))
        else:
            return  # other nodes carry no geometry for the face

    for i, v in enumerate(graph):
        visit(v, f"{fdp_path}.faceSceneGraph[{i}]", [])
    if not parts:
        raise SceneError(
            "faceSceneGraph has no IndexedFaceSet", rule="geometry-empty", node_path=f"{fdp_path}.faceSceneGraph"
        )
    fapu = fapu_from_feature_points(fps, node_path=f"{fdp_path}.featurePointsCoord")
    meshes, trs = _facedef_tables(scene, fdp, fdp_path, points, transforms)
    model = CompiledFace(
        points, names, transforms, parts, meshes, trs, fapu, fps, useOrtho=bool(fdp.get("useOrthoTexture"))
    )
    model.fp_vertices = _match_feature_points(model)
    return model


def _appearance(scene, app) -> tuple[tuple, float, float, str | None]:
    """A Shape's (diffuse colour, specular level, shininess, texture URL) from its Appearance."""
    mat = scene.resolve(app.get("material")) if app is not None else None
    color = tuple(mat.get("diffuseColor")) if mat is not None else (0.8, 0.8, 0.8)
    spec = float(np.mean(mat.get("specularColor"))) if mat is not None else 0.0
    shin = float(mat.get("shininess")) if mat is not None else 0.2
    tex = scene.resolve(app.get("texture")) if app is not None else None
    texture = (tex.get("url") or [None])[0] if tex is not None and tex.type == "ImageTexture" else None
    return color, spec, shin, texture


def _vertex_colors(scene, geo, n: int) -> np.ndarray | None:
    """Per-vertex colours (colorPerVertex, no colorIndex, one finite colour per point) or None."""
    cnode = scene.resolve(geo.get("color"))
    if cnode is not None and geo.get("colorPerVertex") and len(geo.get("colorIndex")) == 0:
        c = np.asarray(cnode.get("color"), dtype=np.float64)
        if c.shape == (n, 3) and np.all(np.isfinite(c)):
            return c.astype(np.float32)
    return None


def _tex_coords(scene, geo, n: int) -> np.ndarray | None:
    """Per-vertex texture coordinates: per point, or per corner (the first assignment per vertex
    wins, documented), or None."""
    tnode = scene.resolve(geo.get("texCoord"))
    if tnode is None:
        return None
    uvp = np.asarray(tnode.get("point"), dtype=np.float64)
    tci = np.asarray(geo.get("texCoordIndex"), dtype=np.int64)
    if tci.size == 0 and len(uvp) == n:
        return uvp
    if tci.size == len(geo.get("coordIndex")):
        ci = np.asarray(geo.get("coordIndex"), dtype=np.int64)
        ok = (ci >= 0) & (tci >= 0) & (tci < len(uvp))
        uv = np.zeros((n, 2))
        vv, first = np.unique(ci[ok], return_index=True)
        uv[vv] = uvp[tci[ok][first]]
        return uv
    return None


def _facedef_tables(scene, fdp, fdp_path: str, points: dict, transforms: dict) -> tuple[list, list]:
    """The FDP's FaceDefTables compiled: (FaceDefMesh tables, FaceDefTransform tables)."""
    meshes, trs = [], []
    for ti, tnode in enumerate(fdp.get("faceDefTables")):
        tnode = scene.resolve(tnode)
        tpath = f"{fdp_path}.faceDefTables[{ti}]"
        fap = int(tnode.get("fapID"))
        hls = int(tnode.get("highLevelSelect"))
        if not 1 <= fap <= NUM_FAPS:
            raise SceneError(f"fapID {fap} out of range 1..68", rule="facedef-fap-id", node_path=f"{tpath}.fapID")
        for mi, mnode in enumerate(tnode.get("faceDefMesh")):
            mnode = scene.resolve(mnode)
            mpath = f"{tpath}.faceDefMesh[{mi}]"
            tgt = scene.resolve(mnode.get("faceSceneGraphNode"))
            if tgt is None or id(tgt) not in points:
                raise SceneError(
                    "faceSceneGraphNode must name an IndexedFaceSet of the faceSceneGraph",
                    rule="facedef-missing-node",
                    node_path=f"{mpath}.faceSceneGraphNode",
                )
            meshes.append(
                MeshTable.build(
                    fap,
                    id(tgt),
                    mnode.get("intervalBorders"),
                    mnode.get("coordIndex"),
                    mnode.get("displacements"),
                    len(points[id(tgt)]),
                    high_level_select=hls,
                    node_path=mpath,
                )
            )
        for xi, xnode in enumerate(tnode.get("faceDefTransform")):
            xnode = scene.resolve(xnode)
            xpath = f"{tpath}.faceDefTransform[{xi}]"
            tgt = scene.resolve(xnode.get("faceSceneGraphNode"))
            if tgt is None or id(tgt) not in transforms:
                raise SceneError(
                    "faceSceneGraphNode must name a Transform of the faceSceneGraph",
                    rule="facedef-missing-node",
                    node_path=f"{xpath}.faceSceneGraphNode",
                )
            trs.append(
                TransformTable.build(
                    fap,
                    id(tgt),
                    int(xnode.get("fieldId")),
                    xnode.get("rotationDef"),
                    xnode.get("scaleDef"),
                    xnode.get("translationDef"),
                    high_level_select=hls,
                    node_path=xpath,
                )
            )
    return meshes, trs


def _match_feature_points(model: CompiledFace) -> list | None:
    """(part index, vertex) of each defined feature point that coincides with a neutral vertex."""
    world = neutral_world(model)
    allv = np.concatenate(world)
    scale = float(np.ptp(allv, axis=0).max()) or 1.0
    offs = np.cumsum([0] + [len(w) for w in world])
    out = []
    used: set[int] = set()
    for k in range(NUM_FEATURE_POINTS):
        p = model.feature_points[k]
        if not np.all(np.isfinite(p)):
            return None
        d = np.linalg.norm(allv - p, axis=1)
        cand = np.nonzero(d <= 1e-6 * scale)[0]
        if cand.size == 0:
            return None
        free = [int(c) for c in cand if int(c) not in used]  # coinciding points: distinct vertices, in order
        j = free[0] if free else int(cand[0])
        used.add(j)
        pi = int(np.searchsorted(offs, j, side="right") - 1)
        out.append((pi, j - int(offs[pi])))
    return out


_DEFAULT: CompiledFace | None = None


def _compiled_default() -> CompiledFace:
    """A fresh copy of the compiled bundled default head (callers may modify it)."""
    global _DEFAULT
    if _DEFAULT is None:
        d = compile_scene(default_head_scene())
        # the data file says which vertex carries each feature point (coinciding points such as
        # 2.2/2.3 -- lips in contact -- cannot be told apart by position)
        fpv = default_head_feature_vertices()
        index = {p.name: i for i, p in enumerate(d.parts)}
        d.fp_vertices = [(index[fpv[label][0]], fpv[label][1]) for label in FEATURE_POINTS]
        _DEFAULT = d
    d = _DEFAULT
    return CompiledFace(
        {k: v.copy() for k, v in d.points.items()},
        dict(d.ifs_names),
        {k: dict(v) for k, v in d.transforms.items()},
        list(d.parts),
        list(d.mesh_tables),
        list(d.transform_tables),
        d.fapu,
        d.feature_points.copy(),
        None,
        None,
        list(d.fp_vertices) if d.fp_vertices else None,
        d.useOrtho,
    )


# ---------------------------------------------------------------------------------- transforms
# ---------------------------------------------------------------------------------- animate
def effective_faps(frames: FapFrames, model: CompiledFace) -> tuple[np.ndarray, np.ndarray]:
    """FAP values float64[F, 68] and status after FIT, left/right fill and visemes/expressions."""
    values = frames.values.astype(np.float64)
    status = frames.status.copy()
    if model.fit is not None:
        values, status = model.fit.apply(values, status, frames.high)
    values, status = lr_fill(values, status)
    hl_meshes = {(t.fap, t.high_level_select) for t in model.mesh_tables + model.transform_tables if t.fap <= 2}
    values, status = apply_high_level(
        values,
        status,
        frames.high,
        model.high_level_tables,
        exclude_visemes=[s for f, s in hl_meshes if f == 1 and 1 <= s <= 14],
        exclude_expressions=[s for f, s in hl_meshes if f == 2 and 1 <= s <= 6],
    )
    return values, status


def animate_model(frames: FapFrames, model: CompiledFace) -> FaceState:
    F = len(frames)
    values, status = effective_faps(frames, model)
    wv, we = high_level_weights(frames.high, frames.status)
    units = model.fapu.per_fap()

    def amp(t) -> np.ndarray:
        if t.fap == 1:
            return wv[:, t.high_level_select] * 63.0 if 0 <= t.high_level_select <= 14 else np.zeros(F)
        if t.fap == 2:
            return we[:, t.high_level_select] * 63.0 if 0 <= t.high_level_select <= 6 else np.zeros(F)
        return values[:, t.fap - 1]

    def unit(t) -> float:
        return 1.0 if t.fap <= 2 else float(units[t.fap - 1])

    pos = {k: np.broadcast_to(p, (F,) + p.shape).copy() for k, p in model.points.items()}
    for t in model.mesh_tables:
        t.apply(pos[t.target], amp(t), unit(t))
    by_target: dict[int, list] = {}
    for t in model.transform_tables:
        by_target.setdefault(t.target, []).append(t)
    local = {
        k: local_matrices(tr, transform_fields(tr, by_target[k], amp, unit) if k in by_target else None, F)
        for k, tr in model.transforms.items()
    }
    verts, parts, first = [], [], 0
    chain_cache: dict[tuple, np.ndarray] = {}
    for p in model.parts:
        key = tuple(p.chain)
        if key not in chain_cache:
            M = np.broadcast_to(np.eye(4), (F, 4, 4))
            for k in p.chain:
                M = M @ local[k]
            chain_cache[key] = M
        M = chain_cache[key]
        P = pos[p.ifs]
        W = np.einsum("fvj,fij->fvi", P, M[:, :3, :3]) + M[:, None, :3, 3]
        verts.append(W)
        parts.append(
            MeshPart(
                p.name,
                first,
                P.shape[1],
                p.triangles,
                tuple(float(c) for c in p.color),
                p.vertex_colors,
                p.texcoords,
                p.texture,
                p.specular,
                p.shininess,
            )
        )
        first += P.shape[1]
    V = np.concatenate(verts, axis=1) if verts else np.zeros((F, 0, 3))
    if not np.all(np.isfinite(V)):
        bad = np.argwhere(~np.isfinite(V))[0]
        raise SceneError(
            f"animation produced a non-finite vertex (frame {int(bad[0])}, vertex {int(bad[1])}); "
            "FAP values too large for the model?",
            rule="animation-finite",
        )
    extras = {"fap_values": values, "fap_status": status}
    if model.fp_vertices is not None:
        idx = np.array([parts[pi].first_vertex + v for pi, v in model.fp_vertices])
        extras["feature_points"] = V[:, idx, :]
    return FaceState(parts, V, frames.time_ms.copy(), extras)


def load_scene(scene) -> bt.Scene | None:
    """``scene`` as a scene model: None and bt.Scene pass through; a path is read by its
    extension (``.bifs``/``.bif`` binary BIFS, anything else BT text)."""
    if scene is None or isinstance(scene, bt.Scene):
        return scene
    p = Path(scene)
    if not p.is_file():
        raise SceneError(f"scene file not found: {p}", rule="scene-missing", node_path=None)
    return bifs.load_scene(p)


def animate(frames: FapFrames, scene=None) -> FaceState:
    """Animate ``frames`` on ``scene`` (bt.Scene, BT path, or None = bundled default head)."""
    return animate_model(frames, compile_scene(load_scene(scene)))
