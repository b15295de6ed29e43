import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from fbaconf.errors import TextFormatError
from fbaconf.scenes import bt

NODE_TYPES = sorted(bt.node_specs())
finite = st.floats(allow_nan=False, allow_infinity=False)


def value_strategy(spec, depth):
    t = spec.type
    if t == "SFInt32":
        return st.integers(-(2**31), 2**31 - 1)
    if t in ("SFFloat", "SFTime"):
        return finite
    if t == "SFBool":
        return st.booleans()
    if t == "SFString":
        return st.text(max_size=8)
    if t in bt._VEC_SIZES:
        return st.tuples(*[finite] * bt._VEC_SIZES[t])
    types = NODE_TYPES if spec.allowed is None else list(spec.allowed)
    if t == "SFNode":
        return st.none() if depth <= 0 or not types else st.one_of(st.none(), node_strategy(depth - 1, types))
    if t == "MFNode":
        return st.just([]) if depth <= 0 or not types else st.lists(node_strategy(depth - 1, types), max_size=2)
    if t == "MFString":
        return st.lists(st.text(max_size=5), max_size=3)
    if t == "MFInt32":
        return st.lists(st.integers(-(2**31), 2**31 - 1), max_size=20).map(lambda x: np.array(x, np.int64))
    if t == "MFFloat":
        return st.lists(finite, max_size=12).map(lambda x: np.array(x, np.float64))
    k = bt._MF_VEC[t]
    return st.lists(st.tuples(*[finite] * k), max_size=6).map(lambda x: np.array(x, np.float64).reshape(-1, k))


@st.composite
def node_strategy(draw, depth=2, types=None):
    ntype = draw(st.sampled_from(types or NODE_TYPES))
    specs = bt.node_specs()[ntype]
    names = draw(st.lists(st.sampled_from(sorted(specs)), unique=True, max_size=5)) if specs else []
    fields = {n: draw(value_strategy(specs[n], depth)) for n in names}
    def_name = draw(
        st.one_of(
            st.none(),
            st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{2,8}", fullmatch=True).filter(
                lambda s: s not in ("USE", "DEF", "NULL", "TRUE", "FALSE")
            ),
        )
    )
    return bt.Node(ntype, fields, def_name)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(node_strategy(), min_size=1, max_size=3))
def test_roundtrip_random_trees(nodes):
    scene = bt.Scene(nodes)
    names = [n.def_name for n, _ in scene.walk() if n.def_name]
    assume(len(names) == len(set(names)))  # DEF names are unique in a file
    group_ok = bt.node_specs()["Group"]["children"].allowed
    defs = sorted(n.def_name for n, _ in scene.walk() if n.def_name and n.type in group_ok)
    if defs:
        scene.nodes.append(bt.Node("Group", {"children": [bt.Use(d) for d in defs]}))
    text = bt.write(scene)
    s2 = bt.parse(text)
    assert s2 == scene
    assert bt.write(s2) == text
    assert bt.parse(bt.write(s2)) == s2


SAMPLE = """# a face
DEF FACE Face {
  fap FAP { open_jaw 300 viseme Viseme { viseme_select1 3 viseme_blend 40 } }
  fdp FDP {
    useOrthoTexture TRUE
    featurePointsCoord Coordinate { point [0 0 0, 1 2 3] }
    faceSceneGraph [ DEF T Transform { children [ Shape { geometry DEF M IndexedFaceSet {
        coord Coordinate { point [0 0 0 1 0 0 0 1 0] } coordIndex [0 1 2 -1] } } ] } ]
    faceDefTables [
      FaceDefTables { fapID 6 faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M
          intervalBorders [-1000 0 500 1000] coordIndex [1]
          displacements [1 0 0, 0.9 0 0, 1.5 0 4] } ] }
      FaceDefTables { fapID 23 faceDefTransform [ FaceDefTransform { faceSceneGraphNode USE T
          rotationDef 0 -1 0 1 } ] }
    ]
  }
  fit FIT { FAPs [2 -1 4 5] Graph [0 1] numeratorCoefs [1.5] }
}
"""


def test_sample_and_defaults():
    s = bt.parse(SAMPLE)
    face = s.nodes[0]
    assert face.def_name == "FACE" and face.type == "Face"
    fdp = face.fields["fdp"]
    assert fdp.get("useOrthoTexture") is True
    tabs = fdp.fields["faceDefTables"]
    mesh = tabs[0].fields["faceDefMesh"][0]
    assert mesh.fields["faceSceneGraphNode"] == bt.Use("M")
    assert s.resolve(mesh.fields["faceSceneGraphNode"]).type == "IndexedFaceSet"
    np.testing.assert_array_equal(mesh.fields["displacements"], [[1, 0, 0], [0.9, 0, 0], [1.5, 0, 4]])
    assert tabs[1].get("highLevelSelect") == 1 and tabs[1].fields["faceDefTransform"][0].get("scaleDef") == (1, 1, 1)
    assert face.fields["fap"].get("lower_t_midlip") == bt.FAP_NOT_SET
    assert face.fields["fap"].get("stretch_l_corner") == bt.FAP_NOT_SET
    paths = dict((p, n.type) for n, p in s.walk())
    assert "Face.fdp.FDP.faceDefTables[0].faceDefMesh[0]" in paths
    assert bt.parse(bt.write(s)) == s


@pytest.mark.parametrize(
    "text, where, rule",
    [
        (
            "Face { fdp FDP { faceDefTables [ FaceDefTables { } FaceDefTables { faceDefMesh [ FaceDefMesh { coordIndex [1 2.5] } ] } ] } }",  # noqa: E501
            "Face.fdp.FDP.faceDefTables[1].faceDefMesh[0].coordIndex",
            "bt-number",
        ),
        ("Face {\n  fap FAP { open_jawx 3 } }", "Face.fap.FAP", "bt-unknown-field"),
        ("Group { children [ Foo { } ] }", "Group.children[0]", "bt-unknown-node"),
        ("Group { children [ USE X ] }", "Group.children[0]", "bt-use-undefined"),
        ("Face { fdp FAP { } }", "Face.fdp", "bt-node-type"),
        ("DEF A Group { } DEF A Group { }", None, "bt-def-duplicate"),
        ("DEF C Coordinate { } Group { children [ USE C ] }", "Group.children[0]", "bt-node-type"),
        ("FDP { useOrthoTexture yes }", "FDP.useOrthoTexture", "bt-bool"),
        ("Transform { rotation 0 1 0 }", "Transform.rotation", "bt-number"),
        ("Group { children [ ", "Group.children", "bt-eof"),
        ('ImageTexture { url ["abc] }', None, "bt-token"),
        ("Transform { translation 1 2 3 translation 1 2 3 }", "Transform", "bt-duplicate-field"),
        ("Transform { scale 1e999 1 1 }", "Transform.scale", "bt-number"),
        ("FAP { open_jaw 99999999999 }", "FAP.open_jaw", "bt-number"),
    ],
)
def test_errors_name_line_column_and_path(text, where, rule):
    with pytest.raises(TextFormatError) as e:
        bt.parse(text, "x.bt")
    err = e.value
    assert err.rule == rule
    assert err.line >= 1 and err.column >= 1
    if where:
        assert err.node_path == where
    assert "x.bt: " in str(err)


def test_error_position():
    with pytest.raises(TextFormatError) as e:
        bt.parse("Group {\n  children [\n    Shape { bogus 1 }\n  ]\n}")
    assert (e.value.line, e.value.column) == (3, 13)


def test_depth_limit():
    text = "Group { children [ " * 150 + "]}" * 150
    with pytest.raises(TextFormatError) as e:
        bt.parse(text)
    assert e.value.rule == "bt-depth"


@settings(max_examples=200, deadline=None)
@given(st.integers(0, len(SAMPLE) - 1), st.integers(0, len(SAMPLE)), st.text(max_size=4))
def test_mutated_text_only_typed_errors(i, j, insert):
    text = SAMPLE[:i] + insert + SAMPLE[max(i, j) :]
    try:
        s = bt.parse(text)
    except TextFormatError:
        return
    assert bt.parse(bt.write(s)) == s


def test_reads_booleans_as_mp4box_writes_them():
    """GPAC's MP4Box dumps SFBool as lowercase true/false; both spellings read the same."""
    upper = bt.parse("Face { fap FAP { viseme Viseme { viseme_def TRUE } } }")
    lower = bt.parse("Face { fap FAP { viseme Viseme { viseme_def true } } }")
    assert upper == lower
    assert bt.parse("Face { fap FAP { viseme Viseme { viseme_def false } } }") != upper


def _urls(text):
    return [n.fields["url"] for n, _ in bt.parse(text).find("ImageTexture")]


def test_reads_object_descriptor_urls_as_mp4box_writes_them():
    """MP4Box dumps an MFURL's object-descriptor items unquoted (od:5) and the empty URL as od:0
    (GPAC's scene_dump.c); the quoted forms read the same, and the writer keeps them quoted."""
    assert _urls('ImageTexture { url ["face.jpg" od:5 od:0] }') == [["face.jpg", "od:5", ""]]
    assert _urls("ImageTexture { url od:1023 }") == _urls('ImageTexture { url "od:1023" }') == [["od:1023"]]
    assert 'url ["face.jpg" "od:5" ""]' in bt.write(bt.parse('ImageTexture { url ["face.jpg" od:5 od:0] }'))


@pytest.mark.parametrize(
    "text,bad",
    [
        ("ImageTexture { url [face.jpg] }", "'face.jpg'"),
        ("ImageTexture { url [od:] }", "'od:'"),
        ("ImageTexture { url [od:x5] }", "'od:x5'"),
        ("ImageTexture { url [od:12345678901] }", "'od:12345678901'"),
    ],
)
def test_other_unquoted_urls_are_typed_errors(text, bad):
    with pytest.raises(TextFormatError) as e:
        bt.parse(text)
    assert e.value.rule == "bt-string" and bad in str(e.value) and e.value.column == text.index(bad[1:-1]) + 1
