"""Scenes of the suites: the bundled models, calibration subsets, FIT graphs and FaceDefTable interval
grids (written at a fixed precision)."""

from __future__ import annotations

import struct
import zlib

import numpy as np

from fbaconf.animation.bundled import default_head_scene
from fbaconf.animation.faceparams import FEATURE_POINTS, UNSENT, fapu_from_feature_points
from fbaconf.bitstreams.synth import _amplitude
from fbaconf.conformance.suite import SuiteError
from fbaconf.generators import models
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.scenes import bt


def make_scene(name: str):
    """A scene model for a case's ``scene`` key; returns (scene, extra files {name: bytes},
    text substitutions applied to the BT text)."""
    if name == "default_head":
        return default_head_scene(), {}  # the committed data, as the animation stage loads it
    if name.startswith("head:"):
        # a coarser build of the default head (lean suites): head:<n_lon>:<density>
        _, n_lon, density = name.split(":")
        return models.head_scene(models.build_head(n_lon=int(n_lon), density=float(density))), {}
    if name == "logo":
        return models.logo_scene(), {}
    if name.startswith("calibration:"):
        return _calibration_scene(name.split(":", 1)[1])
    if name.startswith("fit:"):
        return _fit_scene(name.split(":", 1)[1]), {}
    if name.startswith("grid:"):
        return _grid_scene(name.split(":", 1)[1])
    raise SuiteError(f"unknown scene {name!r}", rule="suite-spec")


# Feature point subsets for calibration (labels, 14496-2 Annex C groups)
CALIBRATION_SUBSETS = {
    # mouth, eyes, brows, nose, head outline: what a face tracker typically sends
    "subset": [
        "2.1",
        "2.2",
        "2.3",
        "2.10",
        "3.5",
        "3.6",
        "3.9",
        "3.10",
        "3.11",
        "3.12",
        "4.1",
        "4.2",
        "4.3",
        "4.4",
        "4.5",
        "4.6",
        "8.1",
        "8.2",
        "8.3",
        "8.4",
        "9.3",
        "9.15",
        "10.9",
        "10.10",
        "11.1",
    ],
    "few": ["3.5", "3.6", "2.1"],
}


CALIBRATION_TEXTURE = "calibration-texture64.png"


def _calibration_scene(subset: str):
    texture = subset.endswith("+texture")
    subset = subset.removesuffix("+texture")
    head = models.default_head()
    fps = np.asarray(head.fp_positions(), np.float64)
    # a differently proportioned face: wider, a little taller, shallower, and (not affine, so that
    # every feature point matters) a jaw wider than the forehead and a fuller mid-face
    target = fps * np.array([1.12, 1.05, 0.9]) + np.array([0.0, 2.0, 0.0])
    yr = (fps[:, 1] - fps[:, 1].min()) / np.ptp(fps[:, 1])
    target[:, 0] *= 1.0 + 0.12 * (1.0 - yr)
    target[:, 2] += 4.0 * np.exp(-(((fps[:, 1] - fps[:, 1].mean()) / 25.0) ** 2))
    if subset != "all":
        if subset not in CALIBRATION_SUBSETS:
            raise SuiteError(f"unknown calibration subset {subset!r}", rule="suite-spec")
        keep = np.array([lab in CALIBRATION_SUBSETS[subset] for lab in FEATURE_POINTS])
        target = np.round(target, 4)
        target[~keep] = UNSENT
    fdp = {"featurePointsCoord": bt.Node("Coordinate", {"point": np.round(target, 4) if subset == "all" else target})}
    nodes, files = [], {}
    if texture:
        lo, hi = fps.min(0), fps.max(0)
        uv = np.round((fps[:, :2] - lo[:2]) / (hi[:2] - lo[:2]), 4)
        fdp["textureCoord"] = bt.Node("TextureCoordinate", {"point": uv})
        fdp["useOrthoTexture"] = True
        # the texture image the calibrated texture coordinates map (the first ImageTexture of the
        # scene, docs/animation.md), in a Shape without geometry that draws nothing; 64 x 64 texels
        # over a face about 100 px high: magnified, never minified
        files[CALIBRATION_TEXTURE] = _pattern_png(64, 64)
        nodes.append(
            bt.Node(
                "Shape",
                {
                    "appearance": bt.Node(
                        "Appearance", {"texture": bt.Node("ImageTexture", {"url": [CALIBRATION_TEXTURE]})}
                    )
                },
            )
        )
    return bt.Scene([bt.Node("Face", {"fdp": bt.Node("FDP", fdp)}, "FACE")] + nodes), files


def _fit_scene(which: str):
    if which == "chain":
        # FAP 4 (lower_t_midlip) drives FAP 51 (lower_t_midlip_o) as 2*x, and FAP 19 drives
        # FAP 21 through (x + x^2/200) / 1 — a link with a quadratic numerator.
        return bt.parse("""Face { fit FIT {
            FAPs [4 -1 51 -1 19 -1 21]
            Graph [0 1 2 3]
            numeratorTerms [1 2] denominatorTerms [0 1]
            numeratorExp [1 1 2] denominatorExp [0]
            numeratorImpulse []
            numeratorCoefs [2.0 1.0 0.005] denominatorCoefs [1.0] } }""")
    if which == "shapes":
        # nodes: 0 = {3} (sent), 1 = {5, 6} (two FAPs, derived), 2 = {12} (sent only in the first half),
        # 3 = {53} (two parents: 1 first, then 2), 4 = {1} (viseme blend, a high-level parent), 5 = {59}
        # (child of 4), 6 = {55} (grandchild of 0 through 1: a chain)
        # links in order: (0,1) (1,3) (2,3) (4,5) (1,6)
        # (0,1): FAP5 = 0.5*x3 / (1 + x3/4000) [non-constant denominator], FAP6 = -0.25*x3 + 40*imp(x3==0)
        # (1,3): FAP53 = 0.3*x5 + 0.1*x6      (2,3): FAP53 = 2*x12     (4,5): FAP59 = 3*blend
        # (1,6): FAP55 = x5*x6/500 (a product of two parents' FAPs)
        return bt.parse("""Face { fit FIT {
            FAPs [3 -1 5 6 -1 12 -1 53 -1 1 -1 59 -1 55]
            Graph [0 1 1 3 2 3 4 5 1 6]
            numeratorTerms [1 2 2 1 1 1] denominatorTerms [2 1 1 1 1 1]
            numeratorExp [1 1 0 1 0 0 1 1 1 1 1]
            numeratorImpulse [0 0 1 0 0 0 0 0]
            numeratorCoefs [0.5 -0.25 40 0.3 0.1 2 3 0.002]
            denominatorExp [0 1 0 0 0 0 0 0 0]
            denominatorCoefs [1 0.00025 1 1 1 1 1] } }""")
    if which.startswith("limit:"):
        level = int(which.split(":")[1])
        ps = load_profiles()
        lim = {x.id: int(x.value(level)) for x in ps.limits_for(Claim.parse(f"calibration@{level}", ps))}
        n, links, terms = lim["fit_nodes"], lim["fit_links"], lim["fit_terms"]
        faps = list(range(3, 3 + n))
        pairs = []
        for gap in range(1, n):  # a DAG: i -> i+gap, nearest first, until the link limit
            for i in range(n - gap):
                if len(pairs) < links:
                    pairs.append((i, i + gap))
        fap_list = []
        for k, f in enumerate(faps):
            fap_list += ([-1] if k else []) + [f]
        # every function: `terms` numerator terms summing to 0.9 x parent (+ a tiny square), denominator 1
        nt, nc, ne, dt, dc, de = [], [], [], [], [], []
        for _ in pairs:
            nt.append(terms)
            dt.append(1)
            for t in range(terms):
                ne.append(2 if t == terms - 1 else 1)
                nc.append(1e-6 if t == terms - 1 else round(0.9 / (terms - 1), 6))
            dc.append(1.0)
            de.append(0)

        def arr(xs):
            return " ".join(bt.fmt_float(x) if isinstance(x, float) else str(x) for x in xs)

        return bt.parse(f"""Face {{ fit FIT {{
            FAPs [{arr(fap_list)}]
            Graph [{arr([x for p in pairs for x in p])}]
            numeratorTerms [{arr(nt)}] denominatorTerms [{arr(dt)}]
            numeratorExp [{arr(ne)}] denominatorExp [{arr(de)}]
            numeratorCoefs [{arr(nc)}] denominatorCoefs [{arr(dc)}] }} }}""")
    if which == "order":
        # node numbers against the graph's order: node 0 = {35} is the child of node 2 = {34, 36},
        # itself the child of node 1 = {3}; FAP 36 is sent, FAP 34 is not
        # (1,2): FAP34 = 0.5*x3, FAP36 = 0.8*x3 (never written: it is sent)   (2,0): FAP35 = x34
        return bt.parse("""Face { fit FIT {
            FAPs [35 -1 3 -1 34 36]
            Graph [1 2 2 0]
            numeratorTerms [1 1 1] denominatorTerms [1 1 1]
            numeratorExp [1 1 1 0] denominatorExp [0 0 0 0]
            numeratorImpulse []
            numeratorCoefs [0.5 0.8 1.0] denominatorCoefs [1 1 1] } }""")
    raise SuiteError(f"unknown FIT scene {which!r}", rule="suite-spec")


def _pattern_png(width: int, height: int) -> bytes:
    """An asymmetric, low-frequency RGB texture (deterministic PNG, zlib level 9): red rises and
    falls once across s, green once across t (triangle waves, equal at both borders: no seam where
    the texture repeats, so texture coordinates a multisampling player extrapolates past a
    silhouette wrap to the same colour), blue is a smooth bump in the top-left quadrant only (t up,
    as the texture is seen). A player that flips t or mirrors s moves the bump; one that clamps
    where the scene says repeat (the grid's s runs over [0, 2]) loses the second red wave. Nothing
    in it is sharper than a few texels, so minified, mipmapped or multisampled reads of it (one
    texture sample per pixel) agree with the golden's supersampled one. Rows use PNG filter 1 (Sub)."""
    u = (np.arange(width) + 0.5) / width
    red = np.round(60 + 160 * (1.0 - np.abs(2.0 * u - 1.0))).astype(np.int64)
    raw = bytearray()
    for j in range(height):
        v = 1.0 - (j + 0.5) / height  # t of this row (row 0 is the top, t = 1)
        green = int(round(60 + 160 * (1.0 - abs(2.0 * v - 1.0))))
        d2 = ((u - 0.25) / 0.2) ** 2 + ((v - 0.75) / 0.2) ** 2
        blue = np.round(70 + 110 * np.where(d2 < 1.0, 0.5 + 0.5 * np.cos(np.pi * np.sqrt(d2)), 0.0))
        px = np.stack([red, np.full(width, green), blue.astype(np.int64)], 1).reshape(-1)
        sub = px.copy()
        sub[3:] = (px[3:] - px[:-3]) % 256
        raw += b"\x01" + bytes(sub.astype(np.uint8))

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)

    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(bytes(raw), 9))
        + chunk(b"IEND", b"")
    )


def _grid_scene(kind: str):
    """A downloaded non-human model: a 20 x 10 grid under two nested Transforms, FaceDefTables chosen
    for the coverage model. ``intervals``: every interval layout and every FaceDefTransform field,
    viseme/expression tables; ``limit:<level>``: the Predictable level limits exactly (mesh vertices,
    FaceDefTables entries, intervals per FaceDefMesh, texture size) with DEF/USE to stay small."""
    nx, ny = 20, 10
    xs, ys = np.meshgrid(np.arange(nx, dtype=np.float64) * 4.0 - 38.0, np.arange(ny, dtype=np.float64) * 8.0 - 36.0)
    V = np.stack([xs.ravel(), ys.ravel(), np.zeros(nx * ny)], 1)
    g = np.arange(nx * ny).reshape(ny, nx)
    ci = []
    for j in range(ny - 1):
        for i in range(nx - 1):
            a, b, c, d = g[j, i], g[j, i + 1], g[j + 1, i + 1], g[j + 1, i]
            ci += [a, b, c, -1, a, c, d, -1]
    head = models.default_head()
    fps = head.fp_positions()
    lo, hi = fps.min(0), fps.max(0)
    fps_g = np.round((fps - (lo + hi) / 2) * (np.array([80.0, 80.0, 20.0]) / (hi - lo)), 4)
    u = fapu_from_feature_points(fps_g).per_fap()
    files: dict[str, bytes] = {}
    app = {"material": bt.Node("Material", {"diffuseColor": (0.8, 0.6, 0.5)})}
    level = int(kind.split(":")[1]) if kind.startswith("limit:") else None
    lim = {}
    if level is not None:
        ps = load_profiles()
        lim = {x.id: int(x.value(level)) for x in ps.limits_for(Claim.parse(f"predictable@{level}", ps))}
        tex = f"texture{lim['texture_width']}.png"
        files[tex] = _pattern_png(lim["texture_width"], lim["texture_height"])
        app["texture"] = bt.Node("ImageTexture", {"url": [tex]})
    gf = {"coord": bt.Node("Coordinate", {"point": V}), "coordIndex": np.array(ci, np.int64), "solid": False}
    if level is not None:  # per-vertex texture coordinates for the texture
        gf["texCoord"] = bt.Node(
            "TextureCoordinate",
            {
                "point": np.round(
                    np.stack(
                        [
                            2.0 * (V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0]),
                            (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1]),
                        ],
                        1,
                    ),
                    4,
                )
            },
        )
    grid = bt.Node("IndexedFaceSet", gf, "Grid")
    kids = [bt.Node("Shape", {"appearance": bt.Node("Appearance", app), "geometry": grid})]
    if level is not None:
        # filler parts sharing one Coordinate (DEF/USE): vertices up to the level's mesh limit
        extra = lim["mesh_vertices"] - nx * ny
        parts = 50 if extra > 10000 else 10
        per = extra // parts
        assert per * parts == extra, (extra, parts)
        fill = bt.Node("Coordinate", {"point": np.zeros((per, 3))}, "FILL")
        for k in range(parts):
            kids.append(
                bt.Node(
                    "Shape",
                    {
                        "geometry": bt.Node(
                            "IndexedFaceSet",
                            {
                                "coord": fill if k == 0 else bt.Use("FILL"),
                                "coordIndex": np.array([0, 1, 2, -1], np.int64),
                            },
                        )
                    },
                )
            )
    inner_fields = {"center": (0.0, -20.0, 0.0), "children": kids}
    if kind == "transforms":  # a neutral scale other than 1 (a FAP's scale multiplies it)
        inner_fields["scale"] = (1.2, 0.9, 1.0)
    inner = bt.Node("Transform", inner_fields, "Inner")
    outer = bt.Node("Transform", {"children": [inner]}, "Outer")

    def mesh(idx, borders, disp):
        idx = np.asarray(idx, np.int64)
        n = len(borders) - 1
        d = np.asarray(disp, np.float64).reshape(-1, 3)
        if len(d) == 1:
            d = np.tile(d, (len(idx) * n, 1))
        return bt.Node(
            "FaceDefMesh",
            {
                "faceSceneGraphNode": bt.Use("Grid"),
                "intervalBorders": np.round(np.asarray(borders, np.float64)).astype(np.int64),
                "coordIndex": idx,
                "displacements": np.round(d, 6),
            },
        )

    def xform(target, field_id, value):
        key = {1: "rotationDef", 2: "scaleDef", 3: "translationDef"}[field_id]
        return bt.Node("FaceDefTransform", {"faceSceneGraphNode": bt.Use(target), "fieldId": field_id, key: value})

    def table(fap, meshes=(), trs=(), hls=None):
        f = {"fapID": fap}
        if hls is not None:
            f["highLevelSelect"] = hls
        if meshes:
            f["faceDefMesh"] = list(meshes)
        if trs:
            f["faceDefTransform"] = list(trs)
        return bt.Node("FaceDefTables", f)

    def a(fap):
        return float(round(_amplitude(fap)))

    tables = []
    if kind == "intervals":
        col = g[:, 3]
        # interval layouts (borders in FAP units, relative to the content's amplitude)
        tables.append(table(3, [mesh(col, [0, a(3) / 3, 2 * a(3) / 3], [(0, -0.02, 0.01), (0, -0.03, 0)] * len(col))]))
        tables.append(
            table(
                4,
                [
                    mesh(
                        g[:, 6],
                        [-a(4) / 8, 0, a(4) / 3, 2 * a(4) / 3],
                        [(1.0, 0, 0), (0, 0.02, 0), (0, 0.01, 0.01)] * len(g[:, 6]),
                    )
                ],
            )
        )
        tables.append(
            table(5, [mesh(g[:, 9], [-2 * a(5) / 3, -a(5) / 3, 0], [(0, 0.02, 0), (0.01, 0.01, 0)] * len(g[:, 9]))])
        )
        tables.append(table(51, [mesh(g[:, 12], [-1, 1], [(0.0, 0.015, 0.005)])]))
        tables.append(table(6, trs=[xform("Inner", 2, (1.001, 1.0, 1.0))]))
        tables.append(table(14, trs=[xform("Inner", 3, (0.0, 0.01, 0.0))]))
        tables.append(table(48, trs=[xform("Outer", 1, (1.0, 0.0, 0.0, 1.0))]))
        tables.append(table(50, trs=[xform("Inner", 1, (0.0, 0.0, 1.0, 1.0))]))
        tables.append(table(1, [mesh(g[-1, :], [-1, 1], [(0.0, 0.05, 0.0)])], hls=3))
        tables.append(table(2, trs=[xform("Inner", 3, (0.02, 0.0, 0.0))], hls=1))
    elif kind == "equal-borders":  # invalid: intervalBorders must increase strictly
        tables.append(table(3, [mesh(g[:, 3], [-100, 0, 0, 100], [(0.0, 0.02, 0.0)])]))
    elif kind == "transforms":
        # tables of one Transform listed against ascending fapID (they apply in fapID order): two
        # rotations of one node about different axes (50 about z before 48 about x), which do not commute
        tables.append(table(50, trs=[xform("Inner", 1, (0.0, 0.0, 1.0, 1.0))]))
        tables.append(table(48, trs=[xform("Inner", 1, (1.0, 0.0, 0.0, 1.0))]))
        tables.append(table(14, trs=[xform("Inner", 3, (0.0, 0.01, 0.0))]))
        tables.append(table(6, trs=[xform("Inner", 2, (1.002, 1.0, 1.0))]))
        tables.append(table(3, [mesh(g[:, 3], [-1, 1], [(0.0, 0.02, 0.0)])]))
    elif level is not None:
        nint = lim["intervals_per_facedefmesh"]
        am = a(4)
        borders = np.round(np.linspace(-am, am, nint + 1))
        borders[nint // 2] = 0.0
        big = mesh(g[:, 6], borders, [(0.0, 0.01, 0.0)])
        tables.append(table(4, [big]))
        entries = lim["facedeftables_entries"] - 1
        faps = [f for f in range(3, 69) if f != 4]
        shared = {}
        per = -(-entries // len(faps))
        for _k, f in enumerate(faps):
            n_here = min(per, entries - sum(len(t.get("faceDefMesh")) for t in tables[1:]))
            if n_here <= 0:
                break
            m = shared.get(f % 7)
            if m is None:
                shared[f % 7] = m = bt.Node(
                    "FaceDefMesh", mesh([g[f % ny, f % nx]], [-1, 1], [(0.0, 0.0, 0.001)]).fields, f"M{f % 7}"
                )
                first = [m] + [bt.Use(f"M{f % 7}")] * (n_here - 1)
            else:
                first = [bt.Use(f"M{f % 7}")] * n_here
            tables.append(table(f, first))
    else:
        raise SuiteError(f"unknown grid scene {kind!r}", rule="suite-spec")
    fdp = bt.Node(
        "FDP",
        {
            "featurePointsCoord": bt.Node("Coordinate", {"point": fps_g}),
            "faceSceneGraph": [outer],
            "faceDefTables": tables,
        },
    )
    del u
    return bt.Scene([bt.Node("Face", {"fdp": fdp}, "FACE")]), files
