import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.animation.facedef import MeshTable, TransformTable, interval_weights, transform_fields
from fbaconf.animation.faceparams import FEATURE_POINTS, fapu_from_feature_points, fp_index
from fbaconf.errors import SceneError

BORDERS = [-1000, 0, 500, 1000]
D50 = [[1, 0, 0], [0.9, 0, 0], [1.5, 0, 4]]
D51 = [[0.8, 0, 0], [0.7, 0, 0], [2, 0, 0]]


def seed_table():
    return MeshTable.build(6, "Face", BORDERS, [50, 51], np.array(D50 + D51), n_vertices=60)


def test_seed_worked_example():
    t = seed_table()
    d = t.displacement([600], 1.0)
    np.testing.assert_allclose(d[0, 0], [600, 0, 400])
    pos = np.zeros((1, 60, 3))
    t.apply(pos, [600], 1.0)
    np.testing.assert_allclose(pos[0, 50], [600, 0, 400])
    np.testing.assert_allclose(pos[0, 51], [500 * 0.7 + 100 * 2, 0, 0])
    assert not pos[0, :50].any()


@pytest.mark.parametrize(
    "fap, expected",
    [
        (0, [0, 0, 0]),  # zero
        (250, [250 * 0.9, 0, 0]),  # inside first positive interval
        (500, [450, 0, 0]),  # exactly on a border
        (1000, [450 + 750, 0, 2000]),  # on the last border
        (1500, [450 + 1000 * 1.5, 0, 4000]),  # above the last border (step 3)
        (-400, [400, 0, 0]),  # inside the negative interval (step 4, literal)
        (-1000, [1000, 0, 0]),  # on the first border
        (-1500, [1500, 0, 0]),  # below the first border (step 5)
    ],
)
def test_interval_cases(fap, expected):
    np.testing.assert_allclose(seed_table().displacement([fap], 1.0)[0, 0], expected)


def test_border_continuity_and_fapu():
    t = seed_table()
    eps = 1e-9
    for b in BORDERS:
        lo, hi = t.displacement([b - eps, b + eps], 2.0)[:, 0]
        np.testing.assert_allclose(lo, hi, atol=1e-6)
    np.testing.assert_allclose(t.displacement([600], 0.5)[0, 0], [300, 0, 200])


def test_single_interval_linear():
    t = MeshTable.build(3, "m", [0, 1000], [0], [[0, -1, 0]], n_vertices=1)
    np.testing.assert_allclose(t.displacement([-300, 0, 2000], 1.0)[:, 0, 1], [300, 0, -2000])


def test_zero_on_outer_border_extends():
    w = interval_weights([0, 100, 200], [-50, 50, 150, 300])
    np.testing.assert_allclose(w, [[-50, 0], [50, 0], [100, 50], [100, 200]])
    w = interval_weights([-200, -100, 0], [50, -50, -150, -300])
    np.testing.assert_allclose(w, [[0, -50], [0, 50], [50, 100], [200, 100]])


def test_vectorised_over_frames():
    t = seed_table()
    faps = np.array([-1500, -1000, -400, 0, 250, 500, 600, 1500])
    d = t.displacement(faps, 1.0)
    for k, f in enumerate(faps):
        np.testing.assert_allclose(d[k], t.displacement([f], 1.0)[0])


@pytest.mark.parametrize(
    "kw, rule",
    [
        (dict(borders=[0, 500, 100], idx=[0], disp=[[1, 0, 0]] * 2), "facedef-borders-unsorted"),
        (dict(borders=[-10, 10, 500], idx=[0], disp=[[1, 0, 0]] * 2), "facedef-borders-zero"),
        (dict(borders=[0], idx=[0], disp=[[1, 0, 0]]), "facedef-interval-count"),
        (dict(borders=[-1, 0, 1], idx=[0, 1], disp=[[1, 0, 0]] * 3), "facedef-displacement-count"),
        (dict(borders=[-1, 0, 1], idx=[0, 7], disp=[[1, 0, 0]] * 4), "facedef-missing-vertex"),
        (dict(borders=[-1, 0, 1], idx=[-1], disp=[[1, 0, 0]] * 2), "facedef-missing-vertex"),
        (dict(borders=[-1, 0, 1], idx=[0], disp=[[np.nan, 0, 0]] * 2), "facedef-displacement-finite"),
    ],
)
def test_bad_tables(kw, rule):
    with pytest.raises(SceneError) as e:
        MeshTable.build(
            3,
            "m",
            kw["borders"],
            kw["idx"],
            np.array(kw["disp"], float),
            n_vertices=5,
            node_path="Face.fdp.FDP.faceDefTables[0].faceDefMesh[0]",
        )
    assert e.value.rule == rule
    assert "faceDefTables[0].faceDefMesh[0]" in str(e.value)


def test_transform_rotation_seed_example():
    # FAP 23 yaw: axis (0,-1,0), factor 1; FAP in AU (1e-5 rad): 100000 AU = 1 rad
    tab = TransformTable.build(23, "LeftEyeX", 1, rotation=(0, -1, 0, 1))
    out = transform_fields({}, [tab], lambda t: np.array([0, 100000, -50000]), lambda t: 1e-5)
    R = out["R"]
    np.testing.assert_allclose(R[0], np.eye(3), atol=1e-12)
    # rotating +z about -y by 1 rad moves it towards -x
    v = R[1] @ [0, 0, 1]
    np.testing.assert_allclose(v, [-np.sin(1), 0, np.cos(1)], atol=1e-12)
    np.testing.assert_allclose(R[2] @ [0, 0, 1], [np.sin(0.5), 0, np.cos(0.5)], atol=1e-12)


def test_transform_scale_translation():
    ts = TransformTable.build(29, "pupil", 2, scale=(2, 2, 1))
    tt = TransformTable.build(27, "eye", 3, translation=(0, 0, 1))
    out = transform_fields({"translation": (1, 2, 3)}, [ts, tt], lambda t: np.array([0.0, 512.0]), lambda t: 1 / 512)
    np.testing.assert_allclose(out["scale"], [[1, 1, 1], [2, 2, 1]])
    np.testing.assert_allclose(out["translation"], [[1, 2, 3], [1, 2, 4]])
    with pytest.raises(SceneError):
        TransformTable.build(23, "x", 7)


def test_feature_points_and_fapu():
    assert len(FEATURE_POINTS) == 84 and FEATURE_POINTS[0] == "2.1" and FEATURE_POINTS[-1] == "11.6"
    assert fp_index("3.14") + 1 == fp_index("4.1")
    pts = {
        "3.1": (0, 10, 0),
        "3.3": (0, 8.976, 0),
        "3.5": (30, 9, 0),
        "3.6": (-30, 9, 0),
        "9.15": (0, -31.96, 0),
        "2.2": (0, -62.68, 0),
        "8.3": (25, -63, 0),
        "8.4": (-26.2, -63, 0),
    }
    f = fapu_from_feature_points(pts)
    assert f.IRISD == pytest.approx(1.024 / 1024) and f.ES == pytest.approx(60 / 1024)
    assert f.ENS == pytest.approx(40.96 / 1024) and f.MNS == pytest.approx(30.72 / 1024)
    assert f.MW == pytest.approx(51.2 / 1024) and f.AU == 1e-5
    assert f.per_fap()[2] == pytest.approx(f.MNS) and f.per_fap()[22] == 1e-5
    with pytest.raises(SceneError):
        fapu_from_feature_points({k: v for k, v in pts.items() if k != "9.15"})
    bad = dict(pts, **{"3.6": (40, 9, 0)})
    with pytest.raises(SceneError):
        fapu_from_feature_points(bad)


def naive_seed_formula(I, D, fap):
    """Steps 1-6 of Ostermann 1998 2.3.2 written out literally (1-based interval indices)."""
    I = list(I)
    n = len(I) - 1
    if n == 1:
        return fap * D[0]
    k = I.index(0) + 1  # I_k = 0 (1-based)
    Ib = lambda i: I[i - 1]
    Dd = lambda i: D[i - 1]
    out = np.zeros(3)
    if fap >= 0:
        if k == n + 1:  # 0 is the last border: documented extension
            return -fap * Dd(n)
        j = next((i for i in range(k, n + 1) if Ib(i) <= fap <= Ib(i + 1)), n)  # step 3: j = max - 1
        for i in range(k, j):
            out += (Ib(i + 1) - Ib(i)) * Dd(i)
        return out + (fap - Ib(j)) * Dd(j)
    if k == 1:  # 0 is the first border: documented extension
        return fap * Dd(1)
    j = next((i for i in range(1, k) if Ib(i) <= fap <= Ib(i + 1)), 1)  # step 5: j = 1
    out += (Ib(j + 1) - fap) * Dd(j)
    for i in range(j + 1, k):
        out += (Ib(i + 1) - Ib(i)) * Dd(i)
    return out


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.integers(-3000, 3000), min_size=1, max_size=7, unique=True),
    st.integers(0, 10**6),
    st.lists(st.integers(-4000, 4000), min_size=1, max_size=6),
)
def test_vectorised_equals_literal_formula(others, seed, faps):
    borders = sorted(set(others) | {0})
    if len(borders) < 2:
        borders = [0, 100]
    n = len(borders) - 1
    D = np.random.default_rng(seed).normal(size=(n, 3))
    t = MeshTable.build(3, "m", borders, [0], D, n_vertices=1)
    got = t.displacement(faps, 1.0)[:, 0]
    for k, f in enumerate(faps):
        np.testing.assert_allclose(got[k], naive_seed_formula(borders, D, f), rtol=1e-9, atol=1e-6)
