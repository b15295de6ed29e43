"""Binary BIFS: tables, round trips, typed errors, robustness, CLI and checker."""

from __future__ import annotations

import random
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from fbaconf.bitstreams.tables import fap_table
from fbaconf.cli import main
from fbaconf.errors import BitstreamError, FbaconfInputError
from fbaconf.generators import models
from fbaconf.profiles.checker import check_stream
from fbaconf.profiles.sample_streams import make_stream
from fbaconf.profiles.scenecheck import load_scene
from fbaconf.scenes import bifs, bt
from fbaconf.scenes.bifs import BifsEncodeError, BifsError, BifsWriter

REPO = Path(__file__).resolve().parents[2]
PROVENANCE = {"spec-notes", "iso-via-implementation", "provisional"}


# ---------------------------------------------------------------------------------- tables
def test_tables_cover_the_scene_model_with_provenance():
    t = bifs.tables()
    for name, n in t.raw["node"].items():
        assert n["provenance"] in PROVENANCE, name
    for name, n in t.raw["ndt"].items():
        assert n["provenance"] in PROVENANCE, name
    for sec in ("format", "config", "command", "ndt_world_codes"):
        assert t.raw[sec]["provenance"] in PROVENANCE
    # every BT node type and field is in the BIFS tables with the same type (tables() checks it too)
    for ntype, specs in bt.node_specs().items():
        assert set(specs) <= set(t.nodes[ntype].by_name), ntype
    # spec notes section 6: Face is index 13 (code 14, 1-based) of 52 in SF3DNode (6 bits); the
    # face-specific NDTs have a single member coded with 1 bit
    sf3d = t.ndts["SF3DNode"]
    assert (len(sf3d.nodes), sf3d.bits, sf3d.code("Face")) == (52, 6, 14)
    for ndt in (
        "SFFAPNode",
        "SFFDPNode",
        "SFFITNode",
        "SFVisemeNode",
        "SFExpressionNode",
        "SFFaceDefTablesNode",
        "SFFaceDefMeshNode",
        "SFFaceDefTransformNode",
    ):
        assert t.ndts[ndt].bits == 1 and len(t.ndts[ndt].nodes) == 1
    assert t.ndts["SFTopNode"].nodes == ("Group", "Layer2D", "Layer3D", "OrderedGroup")
    assert t.ndts["SFGeometryNode"].code("IndexedFaceSet") == 9 and t.ndts["SFGeometryNode"].bits == 5
    # the FAP node: viseme, expression, then the 66 low-level FAPs in FAP order (7-bit field index)
    fap = t.nodes["FAP"]
    assert [f.name for f in fap.defs] == ["viseme", "expression"] + [f.bifs_name for f in fap_table()[2:]]
    assert fap.def_bits == 7
    # the QT13 ranges of spec notes section 6
    vis = {f["name"]: f for f in t.raw["node"]["Viseme"]["fields"]}
    assert (vis["viseme_blend"]["qbits"], vis["viseme_blend"]["max"]) == (6, 63)
    fit = {f["name"]: f for f in t.raw["node"]["FIT"]["fields"]}
    assert (fit["FAPs"]["qbits"], fit["FAPs"]["min"], fit["FAPs"]["max"]) == (7, -1, 68)
    # defIDs skip eventIns: Transform's center is defID 0, IndexedFaceSet's color is defID 0
    assert t.nodes["Transform"].by_name["center"].def_id == 0
    assert t.nodes["IndexedFaceSet"].by_name["color"].def_id == 0 and t.nodes["IndexedFaceSet"].def_bits == 4


# ---------------------------------------------------------------------------------- round trips
def _scene_files():
    return sorted((REPO / "animation" / "data").glob("*.bt"))


@pytest.mark.parametrize("name", ["default_head.bt", "logo.bt", "level_limit_head.bt"])
def test_bundled_scenes_round_trip(name):
    scene = models.bundled_scenes()[name]
    data = bifs.encode(scene)
    back = bifs.decode(data)
    assert bifs.same_scene(scene, back)
    # structure, names, integers and booleans exactly; the BT text of the result reads back identical
    assert [n for n, _ in back.walk()] and [p for _, p in back.walk()][1:] == [p for _, p in scene.walk()][1:]
    if name == "logo.bt":  # (the big heads: the BT reader's speed is not under test here)
        assert bt.parse(bt.write(back)) == back
    assert bifs.encode(back) == data  # BIFS -> model -> BIFS is bit-identical
    assert len(data) < len(bt.write(scene).encode()) * 0.6


def test_scene_files_under_animation_data_round_trip():
    for p in _scene_files():
        scene = bt.read(p)
        assert bifs.same_scene(scene, bifs.decode(bifs.encode(scene))), p


def test_floats_are_float32_and_decode_to_the_shortest_decimal():
    scene = bt.parse("Transform { translation 0.1 -2.5 1e-3 scale 1.2345678901 1 1 children [] }")
    back = bifs.decode(bifs.encode(scene))
    n = back.nodes[0]
    assert n.fields["translation"] == (0.1, -2.5, 0.001)  # <= 7 significant digits: exact
    assert n.fields["scale"][0] != 1.2345678901 and np.float32(n.fields["scale"][0]) == np.float32(1.2345678901)
    assert bifs.same_scene(scene, back) and not scene == back


def test_field_order_and_presence_survive_masked_and_list_descriptions():
    text = (
        "DEF F Face { fdp FDP { faceSceneGraph [ DEF G Group { children [] } ] "
        "featurePointsCoord Coordinate { point [] } } fap NULL }\n"
        "Shape { geometry IndexedFaceSet { solid FALSE coordIndex [0 1 2 -1] "
        "coord Coordinate { point [0 0 0] } } }"
    )
    scene = bt.parse(text)
    back = bifs.decode(bifs.encode(scene))
    assert back == scene  # no floats but 0: exact
    assert list(back.nodes[0].fields) == ["fdp", "fap"] and back.nodes[0].fields["fap"] is None


def test_no_quantisation_decision():
    """fbaconf never sends a QuantizationParameter node: coordinates are 32-bit floats on the
    wire, and a stream with a QuantizationParameter node is refused as outside the subset."""
    pts = np.array([[1.5, -2.25, 3.0]] * 10)  # (vector form: the floats are contiguous)
    scene = bt.Scene(
        [bt.Node("Shape", {"geometry": bt.Node("IndexedFaceSet", {"coord": bt.Node("Coordinate", {"point": pts})})})]
    )
    data = bifs.encode(scene)
    assert pts.astype(">f4").tobytes() in _realign(data)
    w = _prefix()
    _node_header(w, "SF3DNode", "QuantizationParameter")
    with pytest.raises(BifsError) as e:
        bifs.decode(_finish(w))
    assert e.value.rule == "bifs-unsupported-node"


def _realign(data: bytes) -> bytes:
    """All eight bit alignments of ``data`` concatenated (to find unaligned byte strings)."""
    bits = np.unpackbits(np.frombuffer(data, np.uint8))
    return b"".join(np.packbits(bits[k:]).tobytes() for k in range(8))


# ---------------------------------------------------------------------------------- hypothesis
_SIMPLE_TYPES = ["Group", "Transform", "Shape", "Face"]


@st.composite
def scenes(draw, max_depth=4):
    specs = bt.node_specs()
    t = bifs.tables()
    done: dict[str, str] = {}  # completed DEF name -> type
    used: set[str] = set()

    def value(ftype):
        f32 = st.floats(-1e6, 1e6, allow_nan=False, width=32)
        if ftype == "SFInt32":
            return draw(st.integers(-(2**31), 2**31 - 1))
        if ftype == "SFBool":
            return draw(st.booleans())
        if ftype in ("SFFloat",):
            return float(draw(f32))
        if ftype in bifs.SF_VEC:
            return tuple(float(draw(f32)) for _ in range(bifs.SF_VEC[ftype]))
        if ftype == "SFString":
            return draw(st.text(max_size=6))
        n = draw(st.sampled_from([0, 1, 2, 3, 5, 17]))
        if ftype == "MFInt32":
            return np.array(draw(st.lists(st.integers(-(2**31), 2**31 - 1), min_size=n, max_size=n)), np.int64)
        if ftype == "MFFloat":
            return np.array(draw(st.lists(f32, min_size=n, max_size=n)), np.float64)
        if ftype in bifs.MF_VEC:
            k = bifs.MF_VEC[ftype]
            return np.array(draw(st.lists(f32, min_size=n * k, max_size=n * k)), np.float64).reshape(n, k)
        if ftype == "MFString":
            return draw(st.lists(st.text(max_size=4), max_size=3))
        raise AssertionError(ftype)

    def ref_or_node(allowed, ndt, depth, null_ok):
        inline = [x for x in allowed if t.ndts[ndt].code(x) is not None] if depth < max_depth else []
        uses = [nm for nm, ty in done.items() if ty in allowed]
        choices = (["node"] if inline else []) + (["use"] if uses else []) + (["null"] if null_ok else [])
        if not choices:
            return None
        c = draw(st.sampled_from(choices))
        if c == "node":
            return node(draw(st.sampled_from(inline)), depth + 1)
        if c == "use":
            return bt.Use(draw(st.sampled_from(uses)))
        return None

    def node(ntype, depth):
        name = None
        if draw(st.integers(0, 3)) == 0:
            name = f"N{len(used)}_{draw(st.sampled_from(['a', 'B', 'x-1', 'y.2']))}"
            used.add(name)
        fields = {}
        names = list(specs[ntype])
        chosen = draw(st.permutations(names))[: draw(st.integers(0, min(len(names), 6)))]
        for fname in chosen:
            spec = specs[ntype][fname]
            bf = t.nodes[ntype].by_name[fname]
            if spec.type == "SFNode":
                if spec.allowed == ():
                    fields[fname] = None
                    continue
                fields[fname] = ref_or_node(spec.allowed, bf.ndt, depth, True)
            elif spec.type == "MFNode":
                items = []
                for _ in range(draw(st.integers(0, 2))):
                    v = ref_or_node(spec.allowed, bf.ndt, depth, False)
                    if v is not None:
                        items.append(v)
                fields[fname] = items
            else:
                fields[fname] = value(spec.type)
        n = bt.Node(ntype, fields, name)
        if name:
            done[name] = ntype
        return n

    tops = [node(draw(st.sampled_from(_SIMPLE_TYPES)), 1) for _ in range(draw(st.integers(1, 3)))]
    return bt.Scene(tops)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(scenes())
def test_random_scenes_round_trip(scene):
    data = bifs.encode(scene)
    back = bifs.decode(data)
    assert bifs.same_scene(scene, back)
    assert bifs.decode(bifs.encode(back)) == back and bifs.encode(back) == data
    assert bt.parse(bt.write(back)) == back


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(allow_nan=False, allow_infinity=False, min_value=-3e38, max_value=3e38), min_size=1, max_size=9)
)
def test_any_float64_round_trips_within_float32(xs):
    scene = bt.Scene(
        [
            bt.Node(
                "Group",
                {
                    "children": [
                        bt.Node(
                            "Face",
                            {
                                "fdp": bt.Node(
                                    "FDP",
                                    {
                                        "featurePointsCoord": bt.Node(
                                            "Coordinate", {"point": np.array(xs * 3).reshape(-1, 3)}
                                        )
                                    },
                                )
                            },
                        )
                    ]
                },
            )
        ]
    )
    back = bifs.decode(bifs.encode(scene))
    assert bifs.same_scene(scene, back)
    assert bifs.decode(bifs.encode(back)) == back


# ---------------------------------------------------------------------------------- hand-made streams
def _prefix(id_bits: int = 3) -> BifsWriter:
    """Config + ReplaceScene + top OrderedGroup with a list-coded children field: the caller
    writes the children (each preceded by endFlag 0) and calls _finish."""
    t = bifs.tables()
    w = BifsWriter()
    w.write(id_bits, 5), w.write(0, 5), w.bit(1), w.bit(0), w.bit(0), w.align()
    w.write(3, 2), w.write(0, 6), w.bit(1), w.bit(0)  # ReplaceScene: reserved, useNames, protoList (D10)
    w.bit(0), w.write(t.ndts["SFTopNode"].code("OrderedGroup"), 3), w.bit(0)
    w.bit(1), w.bit(1)  # masked; children present (order's mask bit: in _finish)
    w.bit(0), w.bit(1)  # MF reserved 0, list description
    w._id_bits = id_bits
    return w


def _node_header(w, ndt, ntype, *, def_id=None, name=b"", masked_none=True, item=True):
    t = bifs.tables()
    if item:
        w.bit(0)  # endFlag of the children list
    w.bit(0)
    w.write(t.ndts[ndt].code(ntype), t.ndts[ndt].bits)
    if def_id is None:
        w.bit(0)
    else:
        w.bit(1), w.write(def_id, w._id_bits), w.write_bytes(name + b"\0")


def _finish(w) -> bytes:
    w.bit(1)  # end of children
    w.bit(0)  # OrderedGroup.order absent
    w.bit(0), w.bit(0)  # hasROUTEs, continue
    w._unpadded = w.position
    w.align()
    return w.getvalue()


def _empty_node(w, ndt, ntype, **kw):
    _node_header(w, ndt, ntype, **kw)
    w.bit(0), w.bit(1)  # list description, endFlag


def _rule(data) -> BifsError:
    with pytest.raises(BifsError) as e:
        bifs.decode(data)
    assert isinstance(e.value, BitstreamError) and e.value.bit_offset >= 0
    return e.value


def test_hand_made_minimal_stream_decodes():
    w = _prefix()
    _empty_node(w, "SF3DNode", "Group", def_id=0, name=b"G")
    w.bit(0), w.bit(1), w.write(0, 3)  # USE G (nodeID 0)
    assert bifs.decode(_finish(w)) == bt.Scene([bt.Node("Group", {}, "G"), bt.Use("G")])


def test_unknown_and_reserved_node_codes():
    for code in (0, 53, 63):
        w = _prefix()
        w.bit(0), w.bit(0), w.write(code, 6)
        e = _rule(_finish(w))
        assert e.rule == "bifs-node-code" and e.bit_offset == 16 + 9 + 1 + 5 + 2 + 2 + 1 + 1  # 1: protoList
    w = _prefix()
    _empty_node(w, "SF3DNode", "Anchor")
    assert _rule(_finish(w)).rule == "bifs-unsupported-node"


def test_wrong_node_types():
    # an inline Face where FaceDefTransform.faceSceneGraphNode (SF3DNode) wants a Transform
    t = bifs.tables()
    w = _prefix()
    _node_header(w, "SF3DNode", "Face")
    w.bit(0)  # Face: list description
    w.bit(0), w.write(t.nodes["Face"].by_name["fdp"].def_id, 3)
    _node_header(w, "SFFDPNode", "FDP", item=False)
    w.bit(0)
    w.bit(0), w.write(t.nodes["FDP"].by_name["faceDefTables"].def_id, 3)
    w.bit(0), w.bit(1), w.bit(0)  # MF list, one item
    _node_header(w, "SFFaceDefTablesNode", "FaceDefTables", item=False)
    w.bit(0), w.bit(0), w.write(t.nodes["FaceDefTables"].by_name["faceDefTransform"].def_id, 2)
    w.bit(0), w.bit(1), w.bit(0)
    _node_header(w, "SFFaceDefTransformNode", "FaceDefTransform", item=False)
    w.bit(0), w.bit(0), w.write(0, 3)  # faceSceneGraphNode
    _empty_node(w, "SF3DNode", "Face", item=False)
    e = _rule(_finish(w))
    assert e.rule == "bifs-node-type" and e.node_path.endswith("faceDefTransform[0].faceSceneGraphNode")
    assert "(allowed: Transform)" in str(e) and "bit offset" in str(e)
    # a USE of a Coordinate among Group children
    w = _prefix()
    _node_header(w, "SF3DNode", "Group")
    w.bit(1), w.bit(1)  # masked: children present
    w.bit(0), w.bit(1), w.bit(0)  # MF list, one item
    _node_header(w, "SF3DNode", "Shape", item=False)
    w.bit(0), w.bit(0), w.write(1, 1)  # list: geometry
    _node_header(w, "SFGeometryNode", "IndexedFaceSet", item=False)
    w.bit(0), w.bit(0), w.write(1, 4)  # coord
    _empty_node(w, "SFCoordinateNode", "Coordinate", item=False, def_id=0, name=b"C")
    w.bit(1), w.bit(1)  # end IFS fields, end Shape fields
    w.bit(0), w.bit(1), w.write(0, 3)  # second child: USE C
    e = _rule(_finish(w))
    assert e.rule == "bifs-node-type"


def test_use_of_undefined_and_cyclic_ids():
    w = _prefix()
    w.bit(0), w.bit(1), w.write(5, 3)
    assert _rule(_finish(w)).rule == "bifs-use-undefined"
    w = _prefix()  # a Group that USEs itself
    _node_header(w, "SF3DNode", "Group", def_id=0, name=b"G")
    w.bit(1), w.bit(1), w.bit(0), w.bit(1), w.bit(0), w.bit(1), w.write(0, 3), w.bit(1)
    assert _rule(_finish(w)).rule == "bifs-use-undefined"
    w = _prefix()
    _empty_node(w, "SF3DNode", "Group", def_id=7, name=b"G")  # all ones: reserved for NULL
    assert _rule(_finish(w)).rule == "bifs-node-id"
    w = _prefix()
    _empty_node(w, "SF3DNode", "Group", def_id=0, name=b"G")
    _empty_node(w, "SF3DNode", "Group", def_id=1, name=b"G")
    assert _rule(_finish(w)).rule == "bifs-def-name"


def test_absurd_counts_are_refused_before_allocation():
    t = bifs.tables()
    w = _prefix()
    _node_header(w, "SF3DNode", "Shape")
    w.bit(0), w.bit(0), w.write(1, 1)
    _node_header(w, "SFGeometryNode", "IndexedFaceSet", item=False)
    w.bit(0), w.bit(0), w.write(t.nodes["IndexedFaceSet"].by_name["coordIndex"].def_id, 4)
    w.bit(0), w.bit(0), w.write(31, 5), w.write(2**31 - 1, 31)
    tracemalloc.start()
    try:
        e = _rule(_finish(w))
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert e.rule == "bifs-mf-count" and peak < 5_000_000  # 2^31 - 1 indices would be 8 GiB
    assert e.node_path.endswith("geometry.IndexedFaceSet.coordIndex")
    # a string declaring 2^31 - 1 bytes
    w = _prefix()
    _node_header(w, "SF3DNode", "Shape")
    w.bit(0), w.bit(0), w.write(0, 1)
    _node_header(w, "SFAppearanceNode", "Appearance", item=False)
    w.bit(0), w.bit(0), w.write(1, 2)
    _node_header(w, "SFTextureNode", "ImageTexture", item=False)
    w.bit(1), w.bit(1), w.bit(0), w.bit(1)  # masked: url, MF list
    w.bit(0), w.bit(0), w.write(31, 5), w.write(2**31 - 1, 31)  # endFlag, isOD 0 (MFURL, D10), string
    assert _rule(_finish(w)).rule == "bifs-truncated"


def test_truncation_trailing_padding_depth():
    data = bifs.encode(models.logo_scene())
    for cut in (1, 2, 5, 20, len(data) // 3, len(data) - 1):
        e = _rule(data[:cut])
        assert e.rule in ("bifs-truncated", "bifs-mf-count", "bifs-padding"), (cut, e)
    assert _rule(data + b"\0").rule == "bifs-trailing"
    w = _prefix()
    _empty_node(w, "SF3DNode", "Group")
    good = _finish(w)
    assert bifs.decode(good) == bt.Scene([bt.Node("Group")])
    assert w._unpadded % 8  # the access unit ends with padding bits: set one
    bad = bytearray(good)
    bad[-1] |= 1
    assert _rule(bytes(bad)).rule == "bifs-padding"
    w = _prefix()
    for _ in range(bifs.MAX_DEPTH + 5):
        _node_header(w, "SF3DNode", "Group")
        w.bit(1), w.bit(1), w.bit(0), w.bit(1)
    assert _rule(w.getvalue()).rule == "bifs-depth"


def test_encoder_refuses_models_bifs_cannot_carry():
    bad = [
        bt.Scene([bt.Node("FaceDefMesh", {"faceSceneGraphNode": bt.Node("IndexedFaceSet")})]),  # not SF3DNode
        bt.Scene([bt.Node("Group", {"children": [bt.Use("nope")]})]),
        bt.Scene([bt.Node("Transform", {"translation": (1e39, 0.0, 0.0)})]),
        bt.Scene([bt.Node("IndexedFaceSet", {"coordIndex": np.array([2**33])})]),
    ]
    for s in bad:
        with pytest.raises(BifsEncodeError) as e:
            bifs.encode(s)
        assert isinstance(e.value, FbaconfInputError) and e.value.rule.startswith("bifs-")


# ---------------------------------------------------------------------------------- robustness
def _seed_scene() -> bt.Scene:
    return bt.parse("""
DEF FACE Face {
  fap FAP { viseme Viseme { viseme_select1 3 viseme_blend 40 viseme_def TRUE }
            expression Expression { expression_select1 2 expression_intensity1 63 init_face TRUE }
            open_jaw 120 head_yaw -300 }
  fdp FDP {
    featurePointsCoord Coordinate { point [0 1 2, 3 4 5, 6 7 8] }
    faceSceneGraph [ DEF T Transform { translation 0 1 0 children [
      Shape { appearance Appearance { material Material { diffuseColor 1 0.5 0 }
                                      texture ImageTexture { url ["skin.png" "b"] repeatS FALSE } }
              geometry DEF M IndexedFaceSet { coord Coordinate { point [0 0 0, 1 0 0, 0 1 0] }
                                             texCoord TextureCoordinate { point [0 0, 1 0, 0 1] }
                                             coordIndex [0 1 2 -1] solid FALSE } } ] } ]
    faceDefTables [ FaceDefTables { fapID 3 highLevelSelect 2
      faceDefMesh [ FaceDefMesh { faceSceneGraphNode USE M intervalBorders [-100 0 100]
                                  coordIndex [1] displacements [0 -1 0, 0 -2 0] } ]
      faceDefTransform [ FaceDefTransform { faceSceneGraphNode USE T fieldId 1 rotationDef 1 0 0 0.5 } ] } ]
  }
  fit FIT { FAPs [3 -1 4] Graph [0 1] numeratorCoefs [0.5 1] }
}
""")


def _mutants(seeds: list[bytes], n: int, rng: random.Random):
    for i in range(n):
        d = bytearray(seeds[i % len(seeds)])
        k = rng.randrange(7)
        if k <= 2:  # flip 1..3 bits
            for _ in range(k + 1):
                p = rng.randrange(len(d) * 8)
                d[p >> 3] ^= 0x80 >> (p & 7)
        elif k == 3:  # truncate
            d = d[: rng.randrange(len(d))]
        elif k == 4:  # overwrite a byte
            d[rng.randrange(len(d))] = rng.randrange(256)
        elif k == 5:  # insert or delete bytes
            p = rng.randrange(len(d))
            if rng.random() < 0.5:
                d[p:p] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
            else:
                del d[p : p + rng.randint(1, 4)]
        else:  # 0xFF run (huge counts / lengths)
            p = rng.randrange(len(d))
            d[p : p + 4] = b"\xff\xff\xff\xff"
        yield bytes(d)


def test_ten_thousand_mutants_give_only_typed_errors():
    small = bt.parse(
        "Group { children [ DEF T Transform { rotation 0 1 0 0.5 children [ Shape { geometry "
        "IndexedFaceSet { coord Coordinate { point [0 0 0, 1 0 0, 0 1 0] } coordIndex [0 1 2 -1] } } ] } "
        "Face { fit FIT { FAPs [3 4] numeratorCoefs [1] } } ] } USE T"
    )
    seeds = [
        bifs.encode(_seed_scene()),
        bifs.encode(_seed_scene(), use_names=False),
        bifs.encode(small),
        bifs.encode(small, use_names=False),
    ]
    rng = random.Random(9)
    n_ok = n_err = 0
    rules = set()
    for data in _mutants(seeds, 10_000, rng):
        try:
            scene = bifs.decode(data)
        except BifsError as e:
            assert 0 <= e.bit_offset <= len(data) * 8 + 8 and e.rule.startswith("bifs-")
            rules.add(e.rule)
            n_err += 1
            continue
        n_ok += 1  # whatever is accepted is a valid model that re-encodes and round-trips (checked on a sample)
        if n_ok % 10 == 1:
            assert bifs.decode(bifs.encode(scene)) == scene
    assert n_ok + n_err == 10_000 and n_err > 5_000
    assert {"bifs-truncated", "bifs-node-code", "bifs-trailing"} <= rules


def test_names_off_gives_generated_names():
    scene = _seed_scene()
    back = bifs.decode(bifs.encode(scene, use_names=False))
    assert back.nodes[0].def_name == "N0" and bt.parse(bt.write(back)) == back


# ---------------------------------------------------------------------------------- CLI and checker
def test_cli_encode_decode_trace(tmp_path, capsys):
    scene = _seed_scene()
    src = tmp_path / "s.bt"
    src.write_text(bt.write(scene))
    assert main(["encode", str(src), "-o", str(tmp_path / "s.bifs")]) == 0
    assert "bytes of BIFS" in capsys.readouterr().out
    assert main(["decode", str(tmp_path / "s.bifs"), "-o", str(tmp_path / "back.bt")]) == 0
    assert bt.read(tmp_path / "back.bt") == scene
    capsys.readouterr()
    assert main(["decode", str(tmp_path / "s.bifs"), "--trace"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["bit", "width", "element"]
    rows = [ln.split(None, 2) for ln in out[1:]]
    assert rows[0][0] == "0" and rows[0][2].startswith("BIFSConfig")
    jaw = [r for r in rows if r[2].strip().startswith("[0]Face.fap.FAP.open_jaw")]
    assert jaw and jaw[0][1] == "32" and "= 120" in jaw[0][2]
    assert any("DEF M (nodeID" in r[2] and "IndexedFaceSet (code 9/SFGeometryNode)" in r[2] for r in rows)
    offs = [int(r[0]) for r in rows]
    assert offs == sorted(offs)
    # bad input: exit 2, one line naming the bit offset and the rule; the trace so far is printed
    data = (tmp_path / "s.bifs").read_bytes()
    (tmp_path / "bad.bifs").write_bytes(data[:40])
    assert main(["decode", str(tmp_path / "bad.bifs"), "-o", str(tmp_path / "x.bt"), "--trace"]) == 2
    cap = capsys.readouterr()
    assert "bit offset" in cap.err and "[rule bifs-" in cap.err and "BIFSConfig" in cap.out
    assert not (tmp_path / "x.bt").exists()
    assert main(["decode", str(tmp_path / "s.bifs")]) == 2
    assert main(["encode", str(src), "-o", str(tmp_path / "s.fba")]) == 2


def test_check_reads_bifs_scenes_like_bt(tmp_path):
    scene = models.logo_scene()
    (tmp_path / "s.bt").write_text(bt.write(scene))
    (tmp_path / "s.bifs").write_bytes(bifs.encode(scene))
    a, b = [], []
    sa, sb = load_scene(str(tmp_path / "s.bt"), a), load_scene(str(tmp_path / "s.bifs"), b)
    # the only diagnostic of either form: the D10 interop note on FaceDefMesh -> IndexedFaceSet
    assert [d.code for d in a] == [d.code for d in b] == ["FAP-SCENE-003"]
    assert sa.measures == sb.measures and sa.tools == sb.tools
    data = make_stream(6, faps=range(3, 10))
    ra = [(d.code, d.message) for d in check_stream(data, scene=str(tmp_path / "s.bt"), claim="predictable@1")]
    rb = [(d.code, d.message) for d in check_stream(data, scene=str(tmp_path / "s.bifs"), claim="predictable@1")]
    assert ra == rb
    # a damaged BIFS scene is a FAP-SCENE-002 diagnostic with the bit offset and node path
    (tmp_path / "bad.bifs").write_bytes(bifs.encode(scene)[:300])
    diags = [d for d in check_stream(data, scene=str(tmp_path / "bad.bifs")) if d.code.startswith("FAP-SCENE")]
    assert [d.code for d in diags] == ["FAP-SCENE-002"]
    assert "BIFS bit offset" in diags[0].message and diags[0].location.node_path


def test_animate_and_render_read_bifs_scenes_like_bt(tmp_path, capsys):
    """`fbaconf animate/render --scene` take a binary scene (.bifs or .bif) as the reference
    decoder and the checker do; before, both verbs parsed it as BT text and refused it."""
    suite = Path(__file__).resolve().parents[2] / "conformance" / "suites" / "predictable-l1-core"
    (tmp_path / "s.bt").write_bytes((suite / "logo.bt").read_bytes())
    for name in ("s.bifs", "s.bif"):
        (tmp_path / name).write_bytes((suite / "logo.bifs").read_bytes())
    faps = suite / "logo.fap"
    header = next(ln for ln in faps.read_text().splitlines() if ln.strip() and not ln.startswith("#"))
    n_frames = int(header.split()[3])  # .fap header: version, name, rate, frame count
    verts = {}
    for name in ("s.bt", "s.bifs", "s.bif"):
        out = tmp_path / f"{name}.npz"
        assert main(["animate", "--scene", str(tmp_path / name), "--faps", str(faps), "-o", str(out)]) == 0
        with np.load(out) as z:
            verts[name] = z["vertices"]
        img = tmp_path / f"img-{name}"
        assert main(["render", "--scene", str(tmp_path / name), "--faps", str(faps), "-o", str(img)]) == 0
        assert len(list(img.iterdir())) == len(verts[name]) == n_frames
    # the BIFS scene carries its floats as float32: the same motion within float32 rounding
    assert verts["s.bt"].shape == verts["s.bifs"].shape
    assert np.abs(verts["s.bt"][1:] - verts["s.bt"][0]).max() > 0  # the FAPs move the face
    np.testing.assert_allclose(verts["s.bifs"], verts["s.bt"], rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(verts["s.bif"], verts["s.bifs"])
    capsys.readouterr()


def test_d10_proto_list_bit_and_mfurl():
    """D10: a ReplaceScene carries the proto-list bit after useNames (PROTOs refused), and url is
    MFURL: per URL isOD(1), then a 10-bit object descriptor ID ("od:N") or a string."""
    scene = bt.Scene(
        [
            bt.Node(
                "Shape",
                {
                    "appearance": bt.Node(
                        "Appearance", {"texture": bt.Node("ImageTexture", {"url": ["face.png", "od:12"]})}
                    )
                },
            )
        ]
    )
    data = bifs.encode(scene)
    assert bifs.decode(data) == scene
    w = _prefix()
    raw = bytearray(_finish(w))
    # the protoList bit is the 1st bit after reserved(6) + useNames(1) of the command byte(s)
    bit = 16 + 9  # config (13 bits, aligned to 16), command code 2 + reserved 6 + useNames 1
    raw[bit // 8] |= 0x80 >> (bit % 8)
    assert _rule(bytes(raw)).rule == "bifs-proto"


def test_float_decoding_ignores_numpy_print_mode():
    """colour-science switches numpy to its 1.13 print mode on import, which formats float32 with
    6 digits; BIFS float fields must still decode to the shortest decimal of the float32
    (105.6582, not 105.658) whatever the process imported before (found by the GPAC test)."""
    pts = ", ".join(["0 -8.5 105.6582"] * 40)  # enough points for the vector form of an MF field
    scene = bt.parse(f"Face {{ fdp FDP {{ featurePointsCoord Coordinate {{ point [{pts}] }} }} }}")
    blob = bifs.encode(scene)
    with np.printoptions(legacy="1.13"):
        back = bifs.decode(blob)
    pt = back.nodes[0].fields["fdp"].fields["featurePointsCoord"].fields["point"]
    assert set(np.asarray(pt).reshape(-1, 3)[:, 2].tolist()) == {105.6582}
