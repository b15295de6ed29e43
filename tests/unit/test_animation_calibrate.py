import numpy as np
import pytest

from fbaconf import cli
from fbaconf.animation import engine, rbf
from fbaconf.animation.calibrate import calibrate
from fbaconf.animation.faceparams import fapu_from_feature_points, fp_index
from fbaconf.animation.stateio import load_npz
from fbaconf.bitstreams.faptext import write_fap_file
from fbaconf.bitstreams.frames import SET, FapFrames
from fbaconf.errors import SceneError
from fbaconf.scenes import bt


@pytest.fixture(scope="module")
def base():
    return engine.compile_scene(None)


def target_points(base):
    src = base.feature_points
    rng = np.random.default_rng(5)
    c = src.mean(0)
    tgt = c + (src - c) * np.array([1.1, 0.95, 1.05]) + np.array([3.0, -2.0, 1.0])
    return tgt + rng.normal(0, 1.0, tgt.shape)


@pytest.mark.parametrize("subset", [None, ["3.5"], ["2.1", "9.3", "3.5"], "half"])
def test_feature_points_coincide(base, subset):
    tgt = target_points(base)
    recv = np.full((84, 3), np.nan)
    if subset is None:
        recv[:] = tgt
    elif subset == "half":
        recv[::2] = tgt[::2]
    else:
        for lab in subset:
            recv[fp_index(lab)] = tgt[fp_index(lab)]
    cal = calibrate(base, recv)
    st = engine.animate_model(FapFrames.empty(1), cal)
    got = st.extras["feature_points"][0]
    sent = np.all(np.isfinite(recv), axis=1)
    scale = float(np.ptp(tgt, axis=0).max())
    err = np.abs(got[sent] - recv[sent]).max()
    assert err <= 1e-6 * scale, err
    assert np.all(np.isfinite(st.vertices))
    # FAPU recomputed from the calibrated feature points
    assert cal.fapu == fapu_from_feature_points(cal.feature_points)
    np.testing.assert_allclose(cal.feature_points[sent], recv[sent])
    # smooth warp: no vertex moves much more than the feature points do
    moved = np.linalg.norm(st.vertices[0] - engine.animate_model(FapFrames.empty(1), base).vertices[0], axis=1)
    assert moved.max() < 5 * max(np.linalg.norm(tgt - base.feature_points, axis=1).max(), 1.0)


def test_calibrated_head_animates(base):
    cal = calibrate(base, target_points(base))
    fr = FapFrames.empty(2)
    fr.values[1, 2], fr.status[1, 2] = 512, SET
    st = engine.animate_model(fr, cal)
    d = st.extras["feature_points"][1, fp_index("2.1")] - st.extras["feature_points"][0, fp_index("2.1")]
    assert d[1] == pytest.approx(-512 * cal.fapu.MNS, rel=0.01)


@pytest.mark.parametrize("ortho", [True, False])
def test_texture_coordinates(base, ortho):
    tgt = target_points(base)
    lo, hi = tgt.min(0), tgt.max(0)
    tc = (tgt[:, :2] - lo[:2]) / (hi - lo)[:2]
    cal = calibrate(base, tgt, texture_coords=tc, ortho=ortho, texture="face.png")
    skin_i = next(i for i, p in enumerate(cal.parts) if p.name == "Skin")
    uv = cal.parts[skin_i].texcoords
    assert uv.shape == (len(cal.points[cal.parts[skin_i].ifs]), 2) and np.all((uv >= 0) & (uv <= 1))
    assert cal.parts[skin_i].texture == "face.png"
    for k, (pi, v) in enumerate(cal.fp_vertices):
        if pi == skin_i:
            np.testing.assert_allclose(uv[v], np.clip(tc[k], 0, 1), atol=1e-6)


def test_calibration_through_scene_and_errors(base):
    tgt = target_points(base)
    pts = tgt.copy()
    pts[10] = 3.4e38  # not sent
    fpc = ", ".join(" ".join(repr(float(c)) for c in p) for p in pts)
    s = bt.parse(f"Face {{ fdp FDP {{ featurePointsCoord Coordinate {{ point [{fpc}] }} }} }}")
    st = engine.animate(FapFrames.empty(1), s)
    got = st.extras["feature_points"][0]
    sent = np.arange(84) != 10
    assert np.abs(got[sent] - tgt[sent]).max() < 1e-6 * np.ptp(tgt, axis=0).max()
    with pytest.raises(SceneError):
        engine.compile_scene(bt.parse("Face { fdp FDP { featurePointsCoord Coordinate { point [1 2 3] } } }"))
    with pytest.raises(SceneError):
        calibrate(base, np.full((84, 3), np.nan))


def test_cli_animate(tmp_path, capsys):
    fr = FapFrames.empty(3)
    fr.values[1, 2], fr.status[1, 2] = 300, SET
    fr.save_npz(tmp_path / "f.npz")
    out = tmp_path / "out.npz"
    assert cli.main(["animate", "--faps", str(tmp_path / "f.npz"), "-o", str(out), "--json"]) == 0
    st = load_npz(out)
    assert st.vertices.shape[0] == 3 and "fap_values" in st.extras
    ref = engine.animate(fr)
    assert np.array_equal(st.vertices, ref.vertices)
    write_fap_file(tmp_path / "f.fap", fr)
    assert cli.main(["animate", "--faps", str(tmp_path / "f.fap"), "-o", str(tmp_path / "o3.npz")]) == 0
    np.testing.assert_allclose(load_npz(tmp_path / "o3.npz").vertices[1], ref.vertices[1])
    bad = tmp_path / "bad.bt"
    bad.write_text("Face { fdp FDP { faceDefTables [ FaceDefTables { fapID x } ] } }")
    capsys.readouterr()
    argv = ["animate", "--scene", str(bad), "--faps", str(tmp_path / "f.npz"), "-o", str(tmp_path / "o2.npz")]
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert "1:" in err and "fapID" in err
    assert not (tmp_path / "o2.npz").exists()


def test_an_ill_conditioned_warp_is_a_typed_error(monkeypatch):
    """A warp whose system is above the conditioning bound is one clear SceneError (never a
    LinAlgError, never a solution that depends on LAPACK)."""
    monkeypatch.setattr(rbf, "CONDITION_BOUND", 1.0)
    base = engine.compile_scene(None)
    recv = base.feature_points.copy() + 1.0
    with pytest.raises(SceneError) as ei:
        calibrate(base, recv, node_path="Face.fdp.FDP")
    assert ei.value.rule == "calibration-degenerate"
    assert ei.value.node_path == "Face.fdp.FDP.featurePointsCoord" and "condition number" in ei.value.message
