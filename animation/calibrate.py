"""FDP calibration: adapt the default model to received feature points (Calibration profile).

Method (fbaconf's choice; the standard leaves the adaptation to the decoder):

* Source points = the model's own feature points (neutral, world), target points = the
  received ones (any subset of the 84, at least 1).
* The displacement field ``target - source`` is interpolated over space with radial basis
  functions, the construction and linear system of :mod:`.rbf`: thin-plate spline kernel +
  affine polynomial (degree 1) when >= 4 points whose source positions are not coplanar; the
  linear kernel + constant (degree 0) for 2-3 points or coplanar sets; a pure translation for
  1 point. No smoothing, so the field interpolates the data points. Points closer than
  ``rbf.MERGE_TOLERANCE`` (1e-4) of the set's extent -- the feature points that coincide on
  the model (lips in contact: 2.2/2.3, 2.6/2.8, 2.7/2.9) -- form one data point with their
  mean displacement; a system whose condition number exceeds ``rbf.CONDITION_BOUND`` (1e8) is
  refused (rule ``calibration-degenerate``). Afterwards every received feature point's
  vertex is set exactly onto the received point (this removes the solver's rounding
  residual, ~1e-9 of the model size, and opens coinciding points that received different
  targets).
* Every vertex of every part is moved by the field at its neutral world position;
  a Transform's translation is moved by the field at the Transform's origin (so eyes
  follow the warp); parts are then expressed back in their Transform's local frame
  (translation-only chains, as in the default head).
* FAPU are recomputed from the calibrated feature points; the FaceDefTables keep their
  displacements (they are in FAPU units, so motions scale with the new face).
* Texture coordinates (FDP.textureCoord: one (u, v) per feature point, same order and
  subset as featurePointsCoord): the vertex's projection -- orthographic onto the x-y plane
  when ``useOrthoTexture`` is TRUE, else cylindrical (angle atan2(x, z) around the y axis
  through the feature points' centroid, and y) -- is mapped to (u, v) by a 2D thin-plate
  RBF through the feature points' projections (merged and checked like the warp: two feature
  points one behind the other project to one point); applied to the skin part(s) (parts whose
  vertices carry feature points), clipped to [0, 1].
* The condition number of each system solved is kept in ``CompiledFace.extras["conditioning"]``
  (``warp``, ``texture``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fbaconf.errors import SceneError

from . import rbf
from .compiled import CompiledFace, neutral_world
from .faceparams import NUM_FEATURE_POINTS, fapu_from_feature_points


def rbf_warp(src: np.ndarray, dst: np.ndarray, node_path: str | None = None):
    """A function R^3 -> R^3 displacement, interpolating dst - src at src (see :mod:`.rbf`)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if len(src) == 0:
        raise SceneError("calibration needs at least one feature point", rule="calibration-empty")
    # feature points that coincide on the model (lips in contact ...) share one data point: the
    # mean of their displacements (the vertices are put exactly on their own targets afterwards)
    f = rbf.fit(src, dst - src, what="the feature points cannot calibrate the model", node_path=node_path)
    return _fitted(f, 3)


def _uv_map(proj_fp: np.ndarray, uv_fp: np.ndarray, node_path: str | None = None):
    """The map from projected feature points to their (u, v); feature points whose projections
    coincide (e.g. one in front of the other under the orthographic projection) are one point."""
    f = rbf.fit(proj_fp, uv_fp, what="the texture coordinates cannot be mapped", node_path=node_path)
    return _fitted(f, 2)


def _fitted(f: rbf.RbfFit, k: int):
    def apply(p):
        p = np.asarray(p, dtype=np.float64)
        return f(p.reshape(-1, k)).reshape(p.shape[:-1] + (-1,))

    apply.fit = f
    return apply


def _project(P: np.ndarray, ortho: bool, centre: np.ndarray) -> np.ndarray:
    if ortho:
        return P[:, :2].copy()
    q = P - centre
    return np.stack([np.arctan2(q[:, 0], q[:, 2]), q[:, 1]], axis=1)


def calibrate(
    model,
    received: np.ndarray,
    *,
    texture_coords: np.ndarray | None = None,
    ortho: bool = False,
    texture: str | None = None,
    node_path: str | None = None,
):
    """Warp a CompiledFace to received feature points.

    ``received``: float64[84, 3] in label order, NaN rows = not sent. Returns a new
    CompiledFace (the input is not modified). ``node_path`` (the FDP node) locates errors."""
    received = np.asarray(received, dtype=np.float64).reshape(NUM_FEATURE_POINTS, 3)
    sent = np.all(np.isfinite(received), axis=1)
    have = np.all(np.isfinite(model.feature_points), axis=1)
    use = sent & have
    if not use.any():
        raise SceneError("no received feature point is defined on the model", rule="calibration-empty")
    warp = rbf_warp(
        model.feature_points[use], received[use], node_path=f"{node_path}.featurePointsCoord" if node_path else None
    )
    # transform origins (world), parents first
    parent = {}
    for p in model.parts:
        for i, k in enumerate(p.chain):
            parent[k] = p.chain[i - 1] if i else None
    for _k, tr in model.transforms.items():
        if tr["rotation"][3] != 0 or tuple(tr["scale"]) != (1.0, 1.0, 1.0):
            raise SceneError(
                f"calibration supports translation-only Transforms ({tr['name']} rotates or scales)",
                rule="calibration-transform",
            )

    def world_origin(k):
        o = np.asarray(model.transforms[k]["translation"], dtype=np.float64)
        return o + (world_origin(parent[k]) if parent.get(k) is not None else 0.0)

    new_tr = {}
    warped_origin = {}
    for k in model.transforms:
        o = world_origin(k)
        warped_origin[k] = o + warp(o[None])[0]
    for k, tr in model.transforms.items():
        par = parent.get(k)
        t = warped_origin[k] - (warped_origin[par] if par is not None else 0.0)
        new_tr[k] = dict(tr, translation=tuple(float(v) for v in t))
    world = neutral_world(model)
    new_points = {}
    for p, W in zip(model.parts, world):
        if p.ifs in new_points:
            continue
        Wn = W + warp(W)
        origin = warped_origin[p.chain[-1]] if p.chain else 0.0
        new_points[p.ifs] = Wn - origin
    # put every received feature point's vertex exactly on the received point (removes the RBF's
    # rounding residual and separates coinciding model points that received different targets)
    if model.fp_vertices is not None:
        for k, (pi, v) in enumerate(model.fp_vertices):
            if sent[k]:
                p = model.parts[pi]
                origin = warped_origin[p.chain[-1]] if p.chain else 0.0
                new_points[p.ifs][v] = received[k] - origin
    # feature points: received where sent, warped model points elsewhere
    fps = model.feature_points.copy()
    fps[have] = fps[have] + warp(fps[have])
    fps[sent] = received[sent]
    parts = list(model.parts)
    out = CompiledFace(
        new_points,
        dict(model.ifs_names),
        new_tr,
        parts,
        list(model.mesh_tables),
        list(model.transform_tables),
        fapu_from_feature_points(fps),
        fps,
        model.fit,
        model.high_level_tables,
        model.fp_vertices,
        ortho,
    )
    # the condition number of each linear system the calibration solved (fbaconf suites build prints the worst)
    out.extras["conditioning"] = {"warp": warp.fit.condition}
    if texture_coords is not None:
        tc = np.asarray(texture_coords, dtype=np.float64).reshape(-1, 2)
        if tc.shape[0] != NUM_FEATURE_POINTS or not np.all(np.isfinite(tc[sent])):
            raise SceneError(
                "textureCoord must hold one (u, v) per feature point (84, label order)", rule="fdp-texture-coord-count"
            )
        centre = fps[sent].mean(0)
        uvmap = _uv_map(
            _project(fps[sent], ortho, centre), tc[sent], node_path=f"{node_path}.textureCoord" if node_path else None
        )
        out.extras["conditioning"]["texture"] = uvmap.fit.condition
        fp_parts = {pi for pi, _ in (model.fp_vertices or [])} or {0}
        new_world = neutral_world(out)
        for pi in sorted(fp_parts):
            uv = np.clip(uvmap(_project(new_world[pi], ortho, centre)), 0.0, 1.0)
            parts[pi] = replace(parts[pi], texcoords=uv, texture=texture or parts[pi].texture)
    return out
