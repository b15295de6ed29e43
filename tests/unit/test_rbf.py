"""Calibration's linear systems are well posed: coincident and near-coincident points
are merged, every system's condition number is checked against a documented bound, and a scene
above it is refused by the reference, reported by the checker (FAP-SCENE-004) and refused by the
suite builder -- instead of the result depending on how a LAPACK build meets a singular matrix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fbaconf.animation import engine, rbf
from fbaconf.animation.calibrate import _project, _uv_map
from fbaconf.animation.faceparams import fp_index
from fbaconf.conformance.suite import Case, SuiteError, suites_root
from fbaconf.errors import SceneError
from fbaconf.generators.suites import reference_conditioning
from fbaconf.profiles.checker import analyse
from fbaconf.scenes import bifs, bt


def _fdp(scene):
    face, _ = engine._find_face(scene)
    fdp = scene.resolve(face.get("fdp"))
    fps = engine.feature_points_from_fdp(scene, fdp, "FDP")
    tc = np.asarray(scene.resolve(fdp.get("textureCoord")).get("point"), dtype=np.float64).reshape(-1, 2)
    return fps, tc


def test_hand_computed_two_point_system():
    """Two points (linear kernel + constant): normalised 1 apart, the system is
    [[0, -1, 1], [-1, 0, 1], [1, 1, 0]] with eigenvalues 1, 1, -2 (by hand: (1, -1, 0) is an
    eigenvector for 1; on span{(1, 1, 0)/sqrt2, (0, 0, 1)} it acts as [[-1, sqrt2], [sqrt2, 0]],
    roots of l^2 + l - 2), so its condition number is 2; the solution is w = +-(v1 - v2)/2,
    a = (v1 + v2)/2, and the midpoint gets the mean."""
    f = rbf.fit(np.array([[0.0, 0.0], [4.0, 0.0]]), np.array([[1.0], [3.0]]), what="t")
    assert f.kernel == "linear" and f.merged == 0
    np.testing.assert_array_equal(rbf.system(f.nodes, "linear"), [[0, -1, 1], [-1, 0, 1], [1, 1, 0]])
    assert f.condition == pytest.approx(2.0, rel=1e-12)
    np.testing.assert_allclose(f.weights[:, 0], [-1.0, 1.0], atol=1e-15)
    np.testing.assert_allclose(f(np.array([[2.0, 0.0], [0.0, 0.0], [4.0, 0.0]]))[:, 0], [2.0, 1.0, 3.0], atol=1e-14)


def test_thin_plate_reproduces_affine_functions_and_interpolates():
    """A thin-plate spline with an affine part reproduces an affine function everywhere (its
    kernel weights vanish) and any data exactly at the nodes."""
    rng = np.random.default_rng(3)
    p = rng.uniform(-50, 50, (30, 3))
    M, t = np.array([[1.0, 2.0], [-0.5, 0.25], [3.0, 0.0]]), np.array([7.0, -1.0])
    f = rbf.fit(p, p @ M + t, what="t")
    assert f.kernel == "thin_plate_spline" and f.condition < rbf.CONDITION_BOUND
    q = rng.uniform(-60, 60, (100, 3))
    np.testing.assert_allclose(f(q), q @ M + t, atol=1e-9)
    v = rng.normal(size=(30, 2))
    np.testing.assert_allclose(rbf.fit(p, v, what="t")(p), v, atol=1e-9)


def test_merge_groups_are_transitive_and_use_the_tolerance():
    ext = 100.0
    tol = rbf.MERGE_TOLERANCE * ext
    p = np.array([[0, 0], [ext, ext], [0.9 * tol, 0], [1.8 * tol, 0], [50, 50], [50 + 1.5 * tol, 50]])
    assert rbf.merge_groups(p).tolist() == [0, 1, 0, 0, 2, 3]


def test_texture_ortho_old_system_is_exactly_singular_and_the_merged_one_is_well_posed():
    """fdp-texture-ortho: feature points 2.2 and 2.3 project to one texture-space point, so the
    unmerged uv system has two identical rows -- singular in exact arithmetic, whatever LAPACK
    does with it (the issue's second platform raised "Singular matrix", this one returned
    numbers). Merged, the system is far under the bound and interpolates every point."""
    scene = bifs.load_scene(suites_root() / "calibration-l1-core" / "fdp-texture-ortho.bt")
    fps, tc = _fdp(scene)
    sent = np.all(np.isfinite(fps), axis=1)
    proj = _project(fps[sent], True, fps[sent].mean(0))
    labels = np.flatnonzero(sent).tolist()
    i, j = labels.index(fp_index("2.2")), labels.index(fp_index("2.3"))
    assert len(proj) == 25 and np.array_equal(proj[i], proj[j])
    s = (proj - proj.mean(0)) / np.ptp(proj, axis=0).max()
    A = rbf.system(s, "thin_plate_spline")
    assert np.array_equal(A[i], A[j]) and np.array_equal(A[:, i], A[:, j])  # exactly singular
    assert rbf.condition(A) > 1e12  # numerically too: no bound could accept it
    f = _uv_map(proj, tc[sent]).fit
    assert f.merged == 1 and len(f.nodes) == 24
    assert f.condition < 1e4 < rbf.CONDITION_BOUND
    np.testing.assert_allclose(f(proj), tc[sent], atol=1e-10)
    model = engine.compile_scene(scene)
    assert set(model.extras["conditioning"]) == {"warp", "texture"}
    assert max(model.extras["conditioning"].values()) < rbf.CONDITION_BOUND


def _stream() -> bytes:
    return (suites_root() / "calibration-l1-core" / "fdp-few.fba").read_bytes()


def _texture_scene(tmp_path: Path, move) -> Path:
    """A calibration scene on the default head's own feature points with ortho texture
    coordinates (u, v = the normalised x, y), after ``move(points, uv)`` edits them."""
    base = engine.compile_scene(None)
    pts = base.feature_points.copy()
    lo, hi = pts.min(0), pts.max(0)
    uv = (pts[:, :2] - lo[:2]) / (hi - lo)[:2]
    move(pts, uv)
    fpc = ", ".join(" ".join(repr(float(c)) for c in p) for p in pts)
    tcc = ", ".join(" ".join(repr(float(c)) for c in p) for p in uv)
    path = tmp_path / "scene.bt"
    path.write_text(
        f"Face {{ fdp FDP {{ featurePointsCoord Coordinate {{ point [{fpc}] }} "
        f"textureCoord TextureCoordinate {{ point [{tcc}] }} useOrthoTexture TRUE }} }}\n"
    )
    return path


def test_two_coincident_texture_points_compile(tmp_path):
    """Nose tip 9.3 moved in front of the chin 2.1 (same x, y; other z) with its own (u, v): the
    two are one texture-space point whose (u, v) is the mean of theirs."""
    a, b = fp_index("2.1"), fp_index("9.3")

    def move(pts, uv):
        pts[b, :2] = pts[a, :2]
        uv[b] = uv[a] + [0.02, 0.04]

    path = _texture_scene(tmp_path, move)
    model = engine.compile_scene(bt.parse(path.read_text()))
    assert model.extras["conditioning"]["texture"] < rbf.CONDITION_BOUND
    skin = next(i for i, p in enumerate(model.parts) if p.name == "Skin")
    pi, v = model.fp_vertices[a]
    assert pi == skin
    uv = model.parts[skin].texcoords
    _, tc = _fdp(bt.parse(path.read_text()))
    np.testing.assert_allclose(uv[v], (tc[a] + tc[b]) / 2, atol=1e-9)
    assert not [d for d in analyse(_stream(), scene=path).diagnostics if d.code.startswith("FAP-SCENE")]


def _ill_conditioned(pts, uv):
    """2.1 placed on the line through the eye centres 3.5-3.6, 1e-5 off it: three nearly
    collinear texture-space points (condition number ~1e13)."""
    e1, e2, c = pts[fp_index("3.5")], pts[fp_index("3.6")], fp_index("2.1")
    pts[c, :2] = (e1[:2] + e2[:2]) / 2 + [0.0, 1e-5]
    uv[c] = [0.5, 0.3]
    keep = {fp_index("3.5"), fp_index("3.6"), c}
    for k in range(len(pts)):
        if k not in keep:
            pts[k] = 3.4e38


def test_an_ill_conditioned_scene_is_refused_reported_and_not_built(tmp_path):
    path = _texture_scene(tmp_path, _ill_conditioned)
    with pytest.raises(SceneError) as ei:
        engine.compile_scene(bt.parse(path.read_text()))
    assert ei.value.rule == "calibration-degenerate" and "condition number" in ei.value.message
    assert ei.value.node_path.endswith("FDP.textureCoord")
    # the checker reports the scene at the field
    diags = [d for d in analyse(_stream(), scene=path).diagnostics if d.code == "FAP-SCENE-004"]
    assert len(diags) == 1 and diags[0].severity == "error"
    assert diags[0].location.node_path.endswith("FDP.textureCoord")
    # the suite builder refuses a case whose reference would rest on it
    case = Case(id="bad", suite="s", claim="calibration@1", inputs={"scene": path.name}, suite_dir=tmp_path)
    with pytest.raises(SuiteError) as ei:
        reference_conditioning([case])
    assert ei.value.rule == "suite-reference"
