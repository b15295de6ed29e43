import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from fbaconf.animation import engine
from fbaconf.animation.bundled import default_head_feature_vertices, default_head_scene
from fbaconf.animation.faceparams import fapu_from_feature_points, fp_index
from fbaconf.animation.highlevel import default_tables
from fbaconf.bitstreams.frames import DERIVED, FREE, SET, FapFrames
from fbaconf.bitstreams.tables import fap_by_name
from fbaconf.errors import FbaconfInputError, SceneError
from fbaconf.generators import head, models
from fbaconf.generators.models import MODEL_DATA, model_data_files
from fbaconf.scenes import bt


def frames(n):
    return FapFrames.empty(n)


def setf(fr, k, fap, value):
    n = fap_by_name(fap).number if isinstance(fap, str) else fap
    fr.values[k, n - 1] = value
    fr.status[k, n - 1] = SET


@pytest.fixture(scope="module")
def neutral():
    return engine.animate(frames(1))


def fp(state, label, k=0):
    return state.extras["feature_points"][k, fp_index(label)]


def test_default_head_geometry(neutral):
    m = models.default_head()
    n_tri = sum(len(p.triangles) for p in m.parts.values())
    assert 2000 <= n_tri <= 8000 and m.vertex_count() < 5000
    names = {p.name for p in neutral.parts}
    for part in (
        "Skin",
        "LeftEyeball",
        "RightEyeball",
        "LeftIris",
        "LeftPupilDisc",
        "LeftBrow",
        "UpperTeeth",
        "LowerTeeth",
        "Tongue",
        "LeftEar",
        "RightEar",
    ):
        assert part in names
    assert np.all(np.isfinite(neutral.vertices))
    # all 84 feature points on real vertices, equal to the FDP's featurePointsCoord
    fps = neutral.extras["feature_points"][0]
    assert fps.shape == (84, 3)
    np.testing.assert_allclose(fps, m.fp_positions(), atol=1e-5)
    # distinct vertices for distinct points (except the designed contacts)
    assert len({tuple(np.round(p, 6)) for p in fps}) >= 80


def test_default_fapu_from_feature_points(neutral):
    m = models.default_head()
    f = fapu_from_feature_points(m.fp_positions())
    model = engine.compile_scene(None)
    assert model.fapu == fapu_from_feature_points(model.feature_points)
    iris = next(p for p in neutral.parts if p.name == "LeftIris")
    assert np.ptp(neutral.part_vertices(iris, 0)[:, 1]) == pytest.approx(f.IRISD * 1024, rel=1e-3)  # lids tangent
    assert f.IRISD * 1024 == pytest.approx(2 * head.IRIS_R, rel=0.01)
    assert f.MNS * 1024 == pytest.approx(25.0, rel=0.02)
    assert 40 < f.ES * 1024 < 80 and 40 < f.MW * 1024 < 60 and 30 < f.ENS * 1024 < 60
    # neutral face: lips in contact, lip line horizontal, corners at the same height
    for a, b in (("2.2", "2.3"), ("2.6", "2.8"), ("2.7", "2.9")):
        np.testing.assert_allclose(fp(neutral, a), fp(neutral, b), atol=1e-9)
    assert fp(neutral, "2.4")[1] == pytest.approx(fp(neutral, "2.2")[1])
    assert fp(neutral, "8.3")[1] == pytest.approx(fp(neutral, "8.4")[1])
    assert fp(neutral, "9.10")[1] == pytest.approx(fp(neutral, "9.11")[1])  # teeth touch
    # pupil diameter = IRISD0 / 3
    pv = next(p for p in neutral.parts if p.name == "LeftPupilDisc")
    P = neutral.part_vertices(pv, 0)
    assert np.ptp(P[:, 0]) == pytest.approx(f.IRISD * 1024 / 3, rel=0.02)


def test_tables_cover_all_low_level_faps():
    scene = models.default_head_scene()
    fdp = scene.nodes[0].fields["fdp"]
    ids = sorted(t.fields["fapID"] for t in fdp.fields["faceDefTables"])
    assert ids == list(range(3, 69))
    n_int = [
        len(m.fields["intervalBorders"]) - 1
        for t in fdp.fields["faceDefTables"]
        for m in t.fields.get("faceDefMesh", [])
    ]
    assert min(n_int) >= 4 and len(n_int) > 60
    transforms = {t.fields["fapID"] for t in fdp.fields["faceDefTables"] if "faceDefTransform" in t.fields}
    assert {23, 24, 25, 26, 27, 28, 29, 30, 48, 49, 50} <= transforms


def test_every_fap_moves_the_model(neutral):
    fr = frames(66)
    for k, fap in enumerate(range(3, 69)):
        setf(fr, k, fap, 30000 if fap in (23, 24, 25, 26, 47, 48, 49, 50) else 300)
    st = engine.animate(fr)
    moved = np.abs(st.vertices - neutral.vertices).max(axis=(1, 2))
    assert np.all(moved > 0.5), [3 + int(i) for i in np.nonzero(moved <= 0.5)[0]]
    assert np.all(np.isfinite(st.vertices))


def test_fap_semantics(neutral):
    m = engine.compile_scene(None)
    fr = frames(6)
    setf(fr, 5, "lower_t_midlip", 200)
    setf(fr, 0, "open_jaw", 512)
    setf(fr, 1, "close_t_l_eyelid", 1024)
    setf(fr, 2, "yaw_l_eyeball", 20000)
    setf(fr, 3, "head_yaw", 20000)
    setf(fr, 4, "raise_l_i_eyebrow", 200)
    st = engine.animate(fr)
    d = fp(st, "2.1", 0) - fp(neutral, "2.1")
    assert d[1] == pytest.approx(-512 * m.fapu.MNS, rel=0.15)  # chin down by FAP x MNS
    gap = fp(st, "3.1", 1)[1] - fp(st, "3.3", 1)[1]
    assert abs(gap) < 0.6  # eye closed
    assert st.extras["fap_status"][1, 19] == DERIVED and fp(st, "3.2", 1)[1] < fp(neutral, "3.2")[1] - 5  # L/R fill
    assert fp(st, "3.5", 2)[0] > fp(neutral, "3.5")[0] + 1.0  # left eye looks left (+x)
    assert fp(st, "9.3", 3)[0] > fp(neutral, "9.3")[0] + 5.0  # head turns left
    assert fp(st, "4.1", 4)[1] == pytest.approx(fp(neutral, "4.1")[1] + 200 * m.fapu.ENS, rel=0.1)
    # 2.2 is the upper lip's vertex, 2.3 the lower lip's (they coincide in the neutral face)
    assert fp(st, "2.2", 5)[1] == pytest.approx(fp(neutral, "2.2")[1] - 200 * m.fapu.MNS, rel=0.1)
    assert fp(st, "2.3", 5)[1] == pytest.approx(fp(neutral, "2.3")[1], abs=1e-9)


def test_neutral_and_deterministic(neutral):
    m = models.default_head()
    skin = next(p for p in neutral.parts if p.name == "Skin")
    np.testing.assert_array_equal(neutral.part_vertices(skin, 0), m.parts["Skin"].vertices.round(6))
    fr = frames(3)
    setf(fr, 1, "open_jaw", 400)
    fr.status[2, 1] = SET
    fr.high[2, 4:8] = (1, 63, 0, 0)
    a, b = engine.animate(fr), engine.animate(fr)
    assert np.array_equal(a.vertices, b.vertices)
    scene2 = bt.parse(bt.write(default_head_scene()))
    c = engine.animate(fr, scene2)
    assert np.array_equal(a.vertices, c.vertices)


def test_expressions_only_free_faps(neutral):
    fr = frames(3)
    for k in range(3):
        fr.status[k, 1] = SET
        fr.high[k, 4:8] = (1, 63, 0, 0)  # joy
    setf(fr, 1, "raise_l_cornerlip", -200)  # SET: the expression must not override it
    fr.high[2, 4:8] = (1, 63, 2, 63)  # joy + sadness
    st = engine.animate(fr)
    vals, status = st.extras["fap_values"], st.extras["fap_status"]
    n = fap_by_name("raise_l_cornerlip").number - 1
    assert status[0, n] == DERIVED and vals[0, n] > 0
    assert status[1, n] == SET and vals[1, n] == -200
    assert fp(st, "2.4", 0)[1] > fp(neutral, "2.4")[1] + 2  # smile: corner up
    assert fp(st, "2.4", 1)[1] < fp(st, "2.4", 0)[1] - 2  # the SET value wins over the expression
    _, exp = default_tables()
    np.testing.assert_allclose(vals[2, n], exp[1, n] + exp[2, n])


def small_scene(table_text, extra_fps=None):
    pts = models.default_head().fp_positions()
    fpc = " ".join(f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in pts)
    return f"""Face {{ fdp FDP {{
  featurePointsCoord Coordinate {{ point [{fpc}] }}
  faceSceneGraph [ DEF T Transform {{ children [ Shape {{ geometry DEF M IndexedFaceSet {{
     coord Coordinate {{ point [0 0 0, 10 0 0, 0 10 0, 10 10 0] }} coordIndex [0 1 3 2 -1] }} }} ] }} ]
  faceDefTables [ {table_text} ]
}} }}"""


def test_downloaded_model_exact_tables():
    s = bt.parse(
        small_scene("""FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M
          intervalBorders [-1000 0 500 1000] coordIndex [3] displacements [1 0 0, 0.9 0 0, 1.5 0 4] } ] }
        FaceDefTables { fapID 2 highLevelSelect 1 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M
          intervalBorders [0 63] coordIndex [0] displacements [0 0.1 0] } ] }
        FaceDefTables { fapID 48 faceDefTransform [ FaceDefTransform { faceSceneGraphNode USE T
          rotationDef 1 0 0 1 } ] }""")
    )
    model = engine.compile_scene(s)
    mw = model.fapu.MW
    fr = frames(3)
    setf(fr, 0, 6, 600)
    fr.status[1, 1] = SET
    fr.high[1, 4:8] = (1, 42, 0, 0)
    setf(fr, 2, 48, 100000)  # 1 rad
    st = engine.animate(fr, s)
    V = st.vertices
    np.testing.assert_allclose(V[0, 3], np.array([10, 10, 0]) + mw * np.array([600, 0, 400]), atol=1e-9)
    np.testing.assert_allclose(V[0, :3], [[0, 0, 0], [10, 0, 0], [0, 10, 0]])
    np.testing.assert_allclose(V[1, 0], [0, 42 * 0.1, 0], atol=1e-12)
    np.testing.assert_allclose(V[2, 2], [0, 10 * np.cos(1), 10 * np.sin(1)], atol=1e-9)
    # FAP 7 (pair of 6) left/right fill does not create motion: no table for 7
    assert st.vertices.shape == (3, 4, 3)


@pytest.mark.parametrize(
    "table, rule, where",
    [
        (
            "FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M intervalBorders [0 1] "
            "coordIndex [9] displacements [1 0 0] } ] }",
            "facedef-missing-vertex",
            "faceDefMesh[0].coordIndex",
        ),
        (
            "FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode IndexedFaceSet { } "
            "intervalBorders [0 1] coordIndex [0] displacements [1 0 0] } ] }",
            "facedef-missing-node",
            "faceSceneGraphNode",
        ),
        (
            "FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M intervalBorders [0 5 1] "
            "coordIndex [0] displacements [1 0 0 1 0 0] } ] }",
            "facedef-borders-unsorted",
            "intervalBorders",
        ),
        ("FaceDefTables { fapID 99 }", "facedef-fap-id", "fapID"),
        (
            "FaceDefTables { fapID 23 faceDefTransform [ FaceDefTransform { faceSceneGraphNode USE T fieldId 9 } ] }",
            "facedef-field-id",
            "fieldId",
        ),
    ],
)
def test_bad_scene_tables(table, rule, where):
    s = bt.parse(small_scene(table))
    with pytest.raises(SceneError) as e:
        engine.compile_scene(s)
    assert e.value.rule == rule
    assert e.value.node_path.startswith("Face.fdp.FDP.faceDefTables[0]") and where in e.value.node_path


def test_bundled_test_models(tmp_path):
    paths = models.write_bundled_scenes(tmp_path)
    assert sorted(p.name for p in paths) == ["default_head.bt", "level_limit_head.bt", "logo.bt"]
    fr = frames(2)
    setf(fr, 1, "open_jaw", 500)
    setf(fr, 1, "raise_l_i_eyebrow", 300)
    setf(fr, 1, "head_yaw", 10000)
    for p in paths:
        s = bt.read(p)
        st = engine.animate(fr, p)
        assert np.all(np.isfinite(st.vertices))
        assert np.abs(st.vertices[1] - st.vertices[0]).max() > 1.0, p.name
        if p.name == "level_limit_head.bt":
            assert st.vertices.shape[1] == models.PREDICTABLE_L1_MAX_VERTICES
            n = sum(len(n.get("coord") and s.resolve(n.get("coord")).get("point")) for n, _ in s.find("IndexedFaceSet"))
            assert n == models.PREDICTABLE_L1_MAX_VERTICES
    assert bt.read(paths[0]) == models.default_head_scene()


FUZZ_BASE = small_scene("""FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M
          intervalBorders [-1000 0 500 1000] coordIndex [3] displacements [1 0 0, 0.9 0 0, 1.5 0 4] } ] }
        FaceDefTables { fapID 2 highLevelSelect 1 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M
          intervalBorders [0 63] coordIndex [0] displacements [0 0.1 0] } ] }
        FaceDefTables { fapID 48 faceDefTransform [ FaceDefTransform { faceSceneGraphNode USE T
          rotationDef 1 0 0 1 } ] }""").replace(
    "Face {",
    "Face { fit FIT { FAPs [4 -1 51] Graph [0 1] numeratorTerms [1] denominatorTerms [1] "
    "numeratorCoefs [2.0] numeratorExp [1] denominatorCoefs [1] denominatorExp [1] }",
    1,
)


@settings(max_examples=80, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 10**6),
            st.sampled_from(
                [
                    "0",
                    "-1",
                    "1e30",
                    "99",
                    "-0",
                    "3.4e38",
                    "2147483647",
                    "0.0",
                    "7",
                    "-1000",
                    "1000",
                    "5",
                    "[",
                    "}",
                    "USE M",
                    "USE T",
                    "TRUE",
                ]
            ),
        ),
        min_size=1,
        max_size=2,
    )
)
def test_mutated_scenes_give_typed_errors_only(edits):
    words = FUZZ_BASE.split(" ")
    for pos, tok in edits:
        words[pos % len(words)] = tok
    fr = frames(2)
    fr.values[:, :] = 500
    fr.status[:, 2:] = SET
    fr.status[:, 3] = FREE
    fr.status[:, 1] = SET
    fr.high[:, 4:8] = (1, 63, 0, 0)
    try:
        st_ = engine.animate(fr, bt.parse(" ".join(words)))
    except FbaconfInputError:
        return
    assert np.all(np.isfinite(st_.vertices))


def test_committed_model_data_is_what_the_generator_makes():
    """The default head is loaded from committed data (animation/data/models); regenerating it
    on this machine gives the same bytes (fixed precision: no last-digit drift)."""
    for name, text in model_data_files().items():
        assert (MODEL_DATA / name).read_text("utf-8") == text, name


def test_the_runtime_head_is_the_generated_one_at_fixed_precision():
    assert default_head_scene() == bt.rounded(models.default_head_scene(), 6)
    head = models.default_head()
    assert default_head_feature_vertices() == {k: tuple(v) for k, v in head.feature_points.items()}
