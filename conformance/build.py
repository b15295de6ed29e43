"""``fbaconf suites build``: generate every suite of ``data/suites.toml`` into ``suites/``.

Deterministic: the same fbaconf version writes byte-identical files (procedural content,
reference encoder, fixed seeds), so the sha256 digests in each ``suite.json`` are stable
and the goldens made from them (``fbaconf golden regenerate``) can be verified bit for bit.

Each case folder-less: a suite folder holds ``suite.json`` and the case files named
``<case>.fba``, ``<case>.fap``, ``<case>.bt``, ``<case>.bifs`` (when the BIFS codec is
available), ``scenario.toml`` (shared by the suite's image cases), ``<case>-face<i>.fba``.
"""
from __future__ import annotations

import json
import random
import shutil
import tomllib
from fractions import Fraction
from importlib import resources
from pathlib import Path

import numpy as np

from fbaconf._atomic import atomic_write_bytes, atomic_write_text

from .suite import SUITE_FORMAT, Case, Suite, SuiteError, sha256_file, suites_root


def spec(data_dir: Path | None = None) -> dict:
    """suites.toml, with the [[suite]] / [[case]] lists of data/regression.toml (promoted fuzz
    findings, written by the fuzzer) appended when that file exists."""
    data = Path(data_dir) if data_dir is not None else resources.files("fbaconf.conformance").joinpath("data")
    s = tomllib.loads(data.joinpath("suites.toml").read_text("utf-8"))
    reg = data.joinpath("regression.toml")
    if reg.is_file():
        r = tomllib.loads(reg.read_text("utf-8"))
        known = {x["name"] for x in s["suite"]}
        s["suite"] = s["suite"] + [x for x in r.get("suite", []) if x["name"] not in known]
        s["case"] = s["case"] + list(r.get("case", []))
    return s


# ------------------------------------------------------------------ content


def make_content(c: dict):
    """Procedural FapFrames for a case's ``content`` table."""
    from fbaconf.bitstreams.frames import FREE
    from fbaconf.bitstreams.synth import synthetic_sequence
    frames = synthetic_sequence(int(c.get("frames", 30)), float(c.get("rate", 25.0)),
                                visemes=bool(c.get("visemes", True)), expressions=bool(c.get("expressions", True)),
                                faps=c.get("faps"), seed=int(c.get("seed", 0)))
    scale = float(c.get("scale", 1.0))
    if scale != 1.0:
        frames.values[:] = np.round(frames.values * scale).astype(np.int32)
    if c.get("negate"):
        from fbaconf.bitstreams import tables
        qs = tables.quant_steps()
        for fap in c["negate"]:  # strictly negative: -(|v| + 40 steps), beyond any quantiser's dead zone
            j = int(fap) - 1
            frames.values[:, j] = -(np.abs(frames.values[:, j]) + 40 * int(qs[j]))
    from fbaconf.bitstreams.frames import HIGH_LEVEL_FIELDS
    for name, v in c.get("set_high", {}).items():
        col = HIGH_LEVEL_FIELDS.index(name)
        frames.high[:, col] = np.resize(np.asarray(v, dtype=np.int32), len(frames))
    for fap, v in c.get("set_values", {}).items():
        frames.values[:, int(fap) - 1] = np.resize(np.asarray(v, dtype=np.int32), len(frames))
        frames.status[:, int(fap) - 1] = 1
    start = int(c.get("start_frame", 0))
    if start:  # the content begins later in the stream's timeline (skip chain + time codes past a minute)
        frames.frame_number = frames.frame_number + start
        frames.time_ms = frames.frame_number * 1000.0 / frames.frame_rate
    k = int(c.get("sparse", 0))
    if k > 1:
        # FAP f is coded only in frames where (frame + f) % k == 0, always in frame 0
        n = len(frames)
        rows = np.arange(n)[:, None]
        cols = np.arange(frames.values.shape[1])[None, :]
        drop = ((rows + cols) % k != 0) & (rows > 0)
        frames.status[:, 2:][drop[:, 2:]] = FREE
    for fap, (a, b) in c.get("free_after", {}).items():  # FAP coded only in frames [a, b)
        j = int(fap) - 1
        keep = np.zeros(len(frames), bool)
        keep[int(a):int(b)] = True
        frames.status[~keep, j] = FREE
    ext = [int(f) for f in c.get("extremes", [])]
    if ext:  # values at the ends of the widest range (+-1860 steps): 0, +M, 0, -M ... (alternating phase)
        from fbaconf.bitstreams import tables
        qs = tables.quant_steps()
        pat = np.array([1, 0, -1, 0])
        for i, f in enumerate(ext):
            m = 1860 * int(qs[f - 1])
            frames.values[:, f - 1] = m * np.resize(np.roll(pat, i), len(frames))
            frames.status[:, f - 1] = 1
    drops = c.get("drop", [])  # [[first, count], ...]: frames left out -> skip_frames
    if drops:
        keep = np.ones(len(frames), bool)
        for a, n in drops:
            keep[int(a):int(a) + int(n)] = False
        frames = frames.select(np.nonzero(keep)[0])
    return frames


def encoder_options(o: dict, n_frames: int):
    from fbaconf.bitstreams.encoder import EncoderOptions
    o = dict(o)
    cpf = o.pop("coding_per_frame", None)
    if isinstance(cpf, str) and cpf.startswith("alternate:"):
        run = int(cpf.split(":")[1])
        o["coding_per_frame"] = ["arithmetic" if (k // run) % 2 == 0 else "dct" for k in range(n_frames)]
    if isinstance(o.get("frame_rate"), str) and "/" in o["frame_rate"]:
        o["frame_rate"] = Fraction(o["frame_rate"])
    qpf = o.get("fap_quant_per_frame")
    if isinstance(qpf, str):  # "1:10,2:10" = ten frames at 1, ten at 2
        q = []
        for part in qpf.split(","):
            v, n = part.split(":")
            q += [int(v)] * int(n)
        o["fap_quant_per_frame"] = np.array((q * n_frames)[:n_frames])
    b = o.get("bounds")
    if isinstance(b, str):  # "wide": every list value 31 (+-1860), "wide:<fap>,<fap>": only those FAPs
        from fbaconf.bitstreams import tables
        arr = tables.default_bounds().copy()
        faps = range(3, 69) if b == "wide" else [int(x) for x in b.split(":", 1)[1].split(",")]
        for f in faps:
            arr[f - 1] = (1860, -1860, 1860, -1860)
        o["bounds"] = arr
    return EncoderOptions(**o)


# ------------------------------------------------------------------ scenes


def make_scene(name: str):
    """A scene model for a case's ``scene`` key; returns (scene, extra files {name: bytes},
    text substitutions applied to the BT text)."""
    from fbaconf.animation import models
    if name == "default_head":
        return models.default_head_scene(), {}
    if name.startswith("head:"):
        # a coarser build of the default head (lean suites): head:<n_lon>:<density>
        _, n_lon, density = name.split(":")
        return models._head_scene(models.build_head(n_lon=int(n_lon), density=float(density))), {}
    if name == "logo":
        return models.logo_scene(), {}
    if name.startswith("calibration:"):
        return _calibration_scene(name.split(":", 1)[1]), {}
    if name.startswith("fit:"):
        return _fit_scene(name.split(":", 1)[1]), {}
    if name.startswith("grid:"):
        return _grid_scene(name.split(":", 1)[1])
    raise SuiteError(f"unknown scene {name!r}", rule="suite-spec")


# Feature point subsets for calibration (labels, 14496-2 Annex C groups)
CALIBRATION_SUBSETS = {
    # mouth, eyes, brows, nose, head outline: what a face tracker typically sends
    "subset": ["2.1", "2.2", "2.3", "2.10", "3.5", "3.6", "3.9", "3.10", "3.11", "3.12", "4.1", "4.2", "4.3",
               "4.4", "4.5", "4.6", "8.1", "8.2", "8.3", "8.4", "9.3", "9.15", "10.9", "10.10", "11.1"],
    "few": ["3.5", "3.6", "2.1"],
}


def _calibration_scene(subset: str):
    from fbaconf.scenes import bt
    from fbaconf.animation import models
    from fbaconf.animation.faceparams import FEATURE_POINTS, UNSENT
    texture = subset.endswith("+texture")
    subset = subset.removesuffix("+texture")
    head = models.default_head()
    fps = np.asarray(head.fp_positions(), np.float64)
    # a differently proportioned face: wider, a little taller, shallower, and (not affine, so that
    # every feature point matters) a jaw wider than the forehead and a fuller mid-face
    target = fps * np.array([1.12, 1.05, 0.9]) + np.array([0.0, 2.0, 0.0])
    yr = (fps[:, 1] - fps[:, 1].min()) / np.ptp(fps[:, 1])
    target[:, 0] *= 1.0 + 0.12 * (1.0 - yr)
    target[:, 2] += 4.0 * np.exp(-((fps[:, 1] - fps[:, 1].mean()) / 25.0) ** 2)
    if subset != "all":
        if subset not in CALIBRATION_SUBSETS:
            raise SuiteError(f"unknown calibration subset {subset!r}", rule="suite-spec")
        keep = np.array([lab in CALIBRATION_SUBSETS[subset] for lab in FEATURE_POINTS])
        target = np.round(target, 4)
        target[~keep] = UNSENT
    fdp = {"featurePointsCoord": bt.Node("Coordinate", {"point": np.round(target, 4) if subset == "all" else target})}
    if texture:
        lo, hi = fps.min(0), fps.max(0)
        uv = np.round((fps[:, :2] - lo[:2]) / (hi[:2] - lo[:2]), 4)
        fdp["textureCoord"] = bt.Node("TextureCoordinate", {"point": uv})
        fdp["useOrthoTexture"] = True
    return bt.Scene([bt.Node("Face", {"fdp": bt.Node("FDP", fdp)}, "FACE")])


def _fit_scene(which: str):
    from fbaconf.scenes import bt
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
        from fbaconf.profiles.model import Claim, load_profiles
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
    raise SuiteError(f"unknown FIT scene {which!r}", rule="suite-spec")


def _png(width: int, height: int, rgb=(200, 160, 140)) -> bytes:
    """A uniform RGB PNG (zlib level 9: deterministic for a given zlib)."""
    import struct
    import zlib
    row = b"\x00" + bytes(rgb) * width
    raw = row * height

    def chunk(t, d):
        return struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d) & 0xFFFFFFFF)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))


def _grid_scene(kind: str):
    """A downloaded non-human model: a 20 x 10 grid under two nested Transforms, FaceDefTables chosen
    for the coverage model. ``intervals``: every interval layout and every FaceDefTransform field,
    viseme/expression tables; ``limit:<level>``: the Predictable level limits exactly (mesh vertices,
    FaceDefTables entries, intervals per FaceDefMesh, texture size) with DEF/USE to stay small."""
    from fbaconf.scenes import bt
    from fbaconf.animation import models
    from fbaconf.animation.faceparams import fapu_from_feature_points
    from fbaconf.bitstreams.synth import _amplitude
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
        from fbaconf.profiles.model import Claim, load_profiles
        ps = load_profiles()
        lim = {x.id: int(x.value(level)) for x in ps.limits_for(Claim.parse(f"predictable@{level}", ps))}
        tex = f"texture{lim['texture_width']}.png"
        files[tex] = _png(lim["texture_width"], lim["texture_height"])
        app["texture"] = bt.Node("ImageTexture", {"url": [tex]})
    gf = {"coord": bt.Node("Coordinate", {"point": V}), "coordIndex": np.array(ci, np.int64), "solid": False}
    if level is not None:  # per-vertex texture coordinates for the texture
        gf["texCoord"] = bt.Node("TextureCoordinate", {"point": np.round(np.stack(
            [(V[:, 0] - V[:, 0].min()) / np.ptp(V[:, 0]), (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])], 1), 4)})
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
            kids.append(bt.Node("Shape", {"geometry": bt.Node("IndexedFaceSet", {
                "coord": fill if k == 0 else bt.Use("FILL"), "coordIndex": np.array([0, 1, 2, -1], np.int64)})}))
    inner = bt.Node("Transform", {"center": (0.0, -20.0, 0.0), "children": kids}, "Inner")
    outer = bt.Node("Transform", {"children": [inner]}, "Outer")

    def mesh(idx, borders, disp):
        idx = np.asarray(idx, np.int64)
        n = len(borders) - 1
        d = np.asarray(disp, np.float64).reshape(-1, 3)
        if len(d) == 1:
            d = np.tile(d, (len(idx) * n, 1))
        return bt.Node("FaceDefMesh", {"faceSceneGraphNode": bt.Use("Grid"),
                                       "intervalBorders": np.round(np.asarray(borders, np.float64)).astype(np.int64),
                                       "coordIndex": idx, "displacements": np.round(d, 6)})

    def xform(target, field_id, value):
        key = {1: "rotationDef", 2: "scaleDef", 3: "translationDef"}[field_id]
        return bt.Node("FaceDefTransform", {"faceSceneGraphNode": bt.Use(target), "fieldId": field_id,
                                            key: value})

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
        tables.append(table(4, [mesh(g[:, 6], [-a(4) / 8, 0, a(4) / 3, 2 * a(4) / 3],
                                     [(1.0, 0, 0), (0, 0.02, 0), (0, 0.01, 0.01)] * len(g[:, 6]))]))
        tables.append(table(5, [mesh(g[:, 9], [-2 * a(5) / 3, -a(5) / 3, 0], [(0, 0.02, 0), (0.01, 0.01, 0)]
                                     * len(g[:, 9]))]))
        tables.append(table(51, [mesh(g[:, 12], [-1, 1], [(0.0, 0.015, 0.005)])]))
        tables.append(table(6, trs=[xform("Inner", 2, (1.001, 1.0, 1.0))]))
        tables.append(table(14, trs=[xform("Inner", 3, (0.0, 0.01, 0.0))]))
        tables.append(table(48, trs=[xform("Outer", 1, (1.0, 0.0, 0.0, 1.0))]))
        tables.append(table(50, trs=[xform("Inner", 1, (0.0, 0.0, 1.0, 1.0))]))
        tables.append(table(1, [mesh(g[-1, :], [-1, 1], [(0.0, 0.05, 0.0)])], hls=3))
        tables.append(table(2, trs=[xform("Inner", 3, (0.02, 0.0, 0.0))], hls=1))
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
        for k, f in enumerate(faps):
            n_here = min(per, entries - sum(len(t.get("faceDefMesh")) for t in tables[1:]))
            if n_here <= 0:
                break
            m = shared.get(f % 7)
            if m is None:
                shared[f % 7] = m = bt.Node("FaceDefMesh", mesh([g[f % ny, f % nx]], [-1, 1],
                                                                [(0.0, 0.0, 0.001)]).fields, f"M{f % 7}")
                first = [m] + [bt.Use(f"M{f % 7}")] * (n_here - 1)
            else:
                first = [bt.Use(f"M{f % 7}")] * n_here
            tables.append(table(f, first))
    else:
        raise SuiteError(f"unknown grid scene {kind!r}", rule="suite-spec")
    fdp = bt.Node("FDP", {"featurePointsCoord": bt.Node("Coordinate", {"point": fps_g}),
                          "faceSceneGraph": [outer], "faceDefTables": tables})
    del u
    return bt.Scene([bt.Node("Face", {"fdp": fdp}, "FACE")]), files


# ------------------------------------------------------------------ error streams


def _hl_stream(n: int, fap: int, fields: dict[int, list[int]]) -> bytes:
    from fbaconf.bitstreams.encoder import EncoderOptions, encode
    from fbaconf.bitstreams.frames import SET, FapFrames
    f = FapFrames.empty(n, 30.0)
    f.status[:, fap - 1] = SET
    for col, vals in fields.items():
        f.high[:, col] = vals
    return encode(f, EncoderOptions(plane_start_codes="none")).data


def _intra_then_p(a: bytes, b: bytes) -> bytes:
    """A's intra plane followed by B's first predicted plane (same masks and quantiser)."""
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams.bitedit import end_stream, splice
    pa, pb = decode(a).planes, decode(b).planes
    joined = splice((a, 0, pa[0].end_offset), (b, pb[1].bit_offset, pb[1].end_offset))
    return end_stream(joined, pa[0].end_offset + pb[1].end_offset - pb[1].bit_offset)


def mutate(data: bytes, mutation: str, seed: int) -> bytes:
    """An invalid stream from a valid one (``data``), or built from scratch, for an error case."""
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.errors import BitstreamError
    from fbaconf.bitstreams import bitedit
    from fbaconf.profiles.teststreams import stuffing_positions, zero_heavy_plane
    planes = decode(data).planes
    hdr = planes[0].header_offset
    if mutation == "truncate:plane1-middle":
        p1, p2 = planes[1], planes[2]
        return bitedit.truncate_bits(data, (p1.header_offset + p2.bit_offset) // 2)
    if mutation == "frame-rate-zero":
        return bitedit.set_bits(data, hdr + 4, 12, 0)
    if mutation == "garbage:plane0":
        rng = random.Random(seed)
        cut = (planes[0].header_offset + 40) // 8
        return data[:cut] + bytes(rng.randrange(256) for _ in range(64))
    if mutation == "too-short":
        return data[:3]
    if mutation == "not-face":
        return b"\x00\x00\x01\xb6" + data[4:]
    if mutation == "object-mask":
        return bitedit.set_bits(data, hdr + 1, 2, 0b11)
    if mutation == "first-predicted":
        return bitedit.flip_bit(data, hdr)
    if mutation == "marker":
        return bitedit.flip_bit(data, planes[0].marker_offsets[0][0])
    if mutation == "unexpected-start-code":
        assert data[-4:] == b"\x00\x00\x01\xb1"
        return data[:-1] + b"\xb6"
    if mutation == "time-code-hours":
        assert planes[0].time_code is not None
        return bitedit.set_bits(data, hdr + 18, 5, 24)
    if mutation == "stuffing":
        w = zero_heavy_plane()
        _, start, length = decode(w).planes[0].blocks[-1]
        return bitedit.flip_bit(w, stuffing_positions(w, start, length)[0])
    if mutation == "dct-vlc":
        p = planes[0]
        for name, start, length in p.blocks:
            for b in range(start, start + length):
                bad = bitedit.flip_bit(data, b)
                try:
                    decode(bad)
                except BitstreamError as e:
                    if e.rule in ("invalid-vlc", "run-overflow", "segment-length", "coefficient-overflow"):
                        return bad
        raise SuiteError("no single-bit corruption of the DCT data found", rule="suite-spec")
    if mutation == "viseme-select":
        return _intra_then_p(_hl_stream(1, 1, {0: [14]}), _hl_stream(2, 1, {0: [0, 5]}))
    if mutation == "expression-select":
        return _intra_then_p(_hl_stream(1, 2, {4: [6]}), _hl_stream(2, 2, {4: [0, 4]}))
    if mutation == "intensity":
        return _intra_then_p(_hl_stream(1, 1, {2: [63]}), _hl_stream(2, 1, {2: [0, 30]}))
    if mutation == "value-overflow":
        return _value_overflow()
    raise SuiteError(f"unknown mutation {mutation!r}", rule="suite-spec")


def _value_overflow() -> bytes:
    """FAP 47 at the top of 0..1860 steps, then predicted planes each adding +1860 steps (written
    with the codec's arithmetic coder: the encoder refuses such values) until 2^31 - 1 is passed."""
    from fbaconf.bitstreams.arith import ArithEncoder, make_model
    from fbaconf.bitstreams.bitio import BitWriter
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams.encoder import EncoderOptions, encode
    from fbaconf.bitstreams.frames import SET, FapFrames
    from fbaconf.bitstreams.bitedit import end_stream, splice
    fap = 47
    bnd = np.zeros((68, 4), dtype=np.int64)
    bnd[fap - 1] = (1860, 0, 1860, 0)
    f = FapFrames.empty(1, 30.0)
    f.status[:, fap - 1] = SET
    f.values[0, fap - 1] = 1860 * 512
    e = encode(f, EncoderOptions(bounds=bnd, plane_start_codes="none")).data
    end = decode(e).planes[0].end_offset
    w = BitWriter()
    model = make_model(1861)
    for _ in range(2260):
        w.bit(0)
        w.write(1, 2)
        w.bit(0)
        enc = ArithEncoder(w)
        enc.encode(model, 1860)
        enc.flush()
    n = w.position
    return end_stream(splice((e, 0, end), (w.getvalue(), 0, n)), end + n)


def edit_valid(data: bytes, edit: str) -> bytes:
    """Bit edits that keep a stream decodable (warnings only): ``no-frame-rate``, ``trailing``,
    ``time-backwards``, ``quant-no-lists``."""
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams import bitedit
    planes = decode(data).planes
    if edit == "no-frame-rate":
        intra = [p for p in planes if p.is_intra and p.frame_rate is not None]
        out = data
        removed = 0
        for p in intra:  # drop the 13 frame-rate bits of every intra plane (is_frame_rate = 0)
            h = p.header_offset - removed
            out = bitedit.set_bits(bitedit.remove_bits(out, h + 4, 13), h + 3, 1, 0)
            removed += 13
        return bitedit.end_stream(out, planes[-1].end_offset - removed)
    if edit == "trailing":
        return data + b"\x00\x17"
    if edit == "time-backwards":
        p = [p for p in planes if p.is_intra and p.time_code is not None and p.time_code[3] >= 2][0]
        return bitedit.set_bits(data, p.header_offset + 18 + 12, 6, 0)
    if edit == "quant-no-lists":
        p = next(p for p in planes if p.is_intra and p.index > 0 and len(p.new_lists) == 4)
        first_list = p.marker_offsets[10][0]
        p_min_start = p.marker_offsets[10 + 3 * 18][0]
        block_start = p.blocks[0][1]
        removed = block_start - p_min_start
        out = bitedit.remove_bits(data, p_min_start, removed)
        out = bitedit.set_bits(out, first_list - 1, 1, 0)  # is_p_new_min = 0
        return bitedit.end_stream(out, planes[-1].end_offset - removed)
    raise SuiteError(f"unknown edit {edit!r}", rule="suite-spec")


def special_stream(name: str) -> bytes:
    """Streams that need hand-made frames: ``lookahead`` (a stuffing position in the 14-bit look-ahead
    after the viseme block, FAP-DECISION-005), ``splice-rates`` (the frame rate changes at an intra
    plane: 25 Hz then 12.5 Hz)."""
    from fbaconf.bitstreams.decoder import decode
    from fbaconf.bitstreams.encoder import EncoderOptions, encode
    from fbaconf.bitstreams.frames import SET, FapFrames
    from fbaconf.bitstreams.bitedit import end_stream, splice
    if name == "lookahead":
        b = np.zeros((68, 4), dtype=np.int64)
        b[:] = (1860, -1860, 1860, -1860)
        f = FapFrames.empty(1, 30.0)
        f.status[0, 0] = f.status[0, 2] = f.status[0, 3] = SET
        f.high[0, :3] = (0, 3, 32)
        f.values[0, 2], f.values[0, 3] = 1860 * 4, 1860 * 2
        return encode(f, EncoderOptions(fap_quant=1, bounds=b, plane_start_codes="none")).data
    if name == "splice-rates":
        a = encode(make_content({"frames": 12, "rate": 25, "seed": 31, "visemes": False, "expressions": False,
                                 "faps": list(range(3, 20))}), EncoderOptions(fap_quant=2, plane_start_codes="none"))
        b = encode(make_content({"frames": 8, "rate": 12.5, "seed": 32, "visemes": False, "expressions": False,
                                 "faps": list(range(3, 20))}), EncoderOptions(fap_quant=2, plane_start_codes="none"))
        pa, pb = decode(a.data).planes, decode(b.data).planes
        joined = splice((a.data, 0, pa[-1].end_offset), (b.data, pb[0].bit_offset, pb[-1].end_offset))
        return end_stream(joined, pa[-1].end_offset + pb[-1].end_offset - pb[0].bit_offset)
    raise SuiteError(f"unknown special stream {name!r}", rule="suite-spec")


# ------------------------------------------------------------------ build


def _scenario_toml(sc_spec: dict, n_frames: int) -> str:
    from fbaconf.rendering.scenario import Scenario
    sc = Scenario.default()
    frames = sorted({0, n_frames // 2, n_frames - 1}) if sc_spec.get("frames") == "ends" else None
    text = sc.to_toml()
    d = tomllib.loads(text)
    d["width"], d["height"], d["supersample"] = sc_spec["width"], sc_spec["height"], sc_spec["supersample"]
    if frames is not None:
        d["frames"] = frames
    return _dump_toml(d)


def _dump_toml(d: dict, prefix: str = "") -> str:
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(val(x) for x in v) + "]"
        if isinstance(v, float):
            return repr(v)
        return str(v)
    lines, tables, arrays = [], [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            arrays.append((k, v))
        else:
            lines.append(f"{k} = {val(v)}")
    out = "\n".join(lines) + "\n"
    for k, v in tables:
        out += f"\n[{prefix}{k}]\n" + _dump_toml(v, f"{prefix}{k}.")
    for k, items in arrays:
        for it in items:
            out += f"\n[[{prefix}{k}]]\n" + _dump_toml(it, f"{prefix}{k}.")
    return out


def _write(dirpath: Path, name: str, data: bytes | str, case: Case, key: str | None) -> str:
    p = dirpath / name
    if isinstance(data, str):
        atomic_write_text(p, data)
    else:
        atomic_write_bytes(p, data)
    case.sha256[name] = sha256_file(p)
    if key:
        case.inputs[key] = name
    return name


def _error_expect(c: dict) -> dict:
    """An error case's expectation: the checker's diagnostics, and whether a decoder may
    decode (conceal) instead of rejecting (``conceal = true`` in suites.toml)."""
    out = {"diagnostics": list(c.get("expect", []))}
    if c.get("conceal"):
        out["conceal"] = True
    return out


def build_case(c: dict, suite: dict, d: Path, sc_spec: dict) -> Case:
    from fbaconf.bitstreams.encoder import encode
    from fbaconf.bitstreams.faptext import write_fap
    from fbaconf.scenes import bt
    gen = c.get("generator", "stream")
    case = Case(id=c["id"], suite=suite["name"], claim=c.get("claim", suite["claim"]), group=suite["group"],
                kind={"stream": "decode", "multi": "multi", "error": "error", "file": "decode", "special": "decode"}[gen],
                description=c.get("description", ""), tools=list(c.get("tools", [])), covers=list(c.get("covers", [])),
                suite_dir=d)
    if gen == "file":
        # a committed input (e.g. a promoted fuzz finding, conformance/data/regression/): an error
        # case, or a valid stream decoded by the reference for the goldens
        src = Path(str(resources.files("fbaconf.conformance").joinpath("data", c["file"])))
        if not src.is_file():
            raise SuiteError(f"case {case.id}: file {c['file']} not found under conformance/data", rule="suite-spec")
        ext = src.suffix.lower().lstrip(".")
        _write(d, f"{case.id}.{ext}", src.read_bytes(), case, ext)
        if c.get("expect") is not None or c.get("valid") is False:
            case.kind = "error"
            case.expect = _error_expect(c)
        else:
            case.stages = ["faps"]
            case.goldens = {"faps": "faps.npz"}
        return case
    if gen == "error" and c.get("mutation") in ("too-short", "not-face", "stuffing", "viseme-select",
                                                 "expression-select", "intensity", "value-overflow") \
            and "content" not in c:
        c = dict(c, content={"frames": 5, "faps": [3, 4]})
    content = make_content(c.get("content", {}))
    opts = encoder_options(c.get("options", {}), len(content))
    if gen == "multi":
        faces = []
        for i in range(int(c["faces"])):
            cc = dict(c.get("content", {}))
            cc["seed"] = int(cc.get("seed", 0)) * 10 + i
            res = encode(make_content(cc), opts)
            faces.append(_write(d, f"{case.id}-face{i}.fba", res.data, case, None))
        case.inputs["faces"] = faces
        case.frames = len(content)
        case.stages = ["faps"]
        case.goldens = {"faces": [f"face{i}.npz" for i in range(len(faces))]}
        return case
    res = encode(content, opts)
    if gen == "error":
        data = mutate(res.data, c["mutation"], int(c.get("content", {}).get("seed", 0)))
        _write(d, f"{case.id}.fba", data, case, "fba")
        case.expect = _error_expect(c)
        case.frames = len(content)
        return case
    data = special_stream(c["special"]) if c.get("special") else res.data
    if c.get("edit"):
        data = edit_valid(data, c["edit"])
    from fbaconf.bitstreams.decoder import decode
    decoded = decode(data).frames
    _write(d, f"{case.id}.fba", data, case, "fba")
    if c.get("text", True):
        _write(d, f"{case.id}.fap", write_fap(decoded, name=case.id), case, "fap")
    case.frames = len(decoded)
    case.stages = list(c.get("stages", ["faps"]))
    case.goldens = {"faps": "faps.npz"}
    if "scene" in c:
        scene, files = make_scene(c["scene"])
        for name, blob in sorted(files.items()):
            if not (d / name).is_file():
                _write(d, name, blob, case, None)
            else:
                case.sha256[name] = sha256_file(d / name)
        _write(d, f"{case.id}.bt", bt.write(scene), case, "scene")
        try:
            from fbaconf.scenes import bifs
        except ImportError:
            bifs = None
        if bifs is not None:
            _write(d, f"{case.id}.bifs", bifs.encode(scene), case, "bifs")
    if "vertices" in case.stages:
        case.goldens["vertices"] = "vertices.npz"
        if c.get("vertices_key"):
            case.tolerances.setdefault("vertices", {})["key"] = c["vertices_key"]
    if "images" in case.stages:
        name = "scenario.toml"
        text = _scenario_toml(sc_spec, case.frames)
        _write(d, f"{case.id}-scenario.toml", text, case, "scenario")
        frames = tomllib.loads(text).get("frames", list(range(case.frames)))
        case.goldens["images"] = [f"frame_{k:05d}.png" for k in frames]
        del name
    return case


def build(root: Path | None = None, names: list[str] | None = None, log=print) -> list[Suite]:
    """Regenerate the suites (all, or ``names``) under ``root``; returns them."""
    s = spec()
    root = root or suites_root()
    root.mkdir(parents=True, exist_ok=True)
    suites = []
    known = {x["name"] for x in s["suite"]}
    for c in s["case"]:
        if c["suite"] not in known:
            raise SuiteError(f"case {c['id']} names unknown suite {c['suite']!r}", rule="suite-spec")
    for sd in s["suite"]:
        if names and sd["name"] not in names:
            continue
        d = root / sd["name"]
        if d.exists():
            shutil.rmtree(d)
        d.mkdir(parents=True)
        cases = [build_case(c, sd, d, s["scenario"]) for c in s["case"] if c["suite"] == sd["name"]]
        suite = Suite(sd["name"], sd.get("description", ""), sd["claim"], sd["group"], s["version"], cases, d)
        atomic_write_text(d / "suite.json", json.dumps(suite.to_json(), indent=1, sort_keys=False) + "\n")
        suites.append(suite)
        log(f"built {suite.name}: {len(cases)} case(s)")
    return suites




# ------------------------------------------------------------------ external (real .fap files)

EXTERNAL_SUITE = "simple-l2-real"
EXTERNAL_QUANTS = (1, 8, 31)
EXTERNAL_RATES = (None, 10.0)  # the file's own rate, and resampled to 10 Hz


def build_external(src: Path, out: Path | None = None, log=print) -> Suite | None:
    """The optional EXTERNAL suite: every ``.fap`` file under ``src`` (e.g. ../shared/data/fap),
    encoded at several quantisers and frame rates, with goldens, under ``out`` (default: a new
    temporary folder). Never written into the repository. Returns None when ``src`` holds no
    .fap file. Run it with ``FBACONF_SUITES=<out>/suites FBACONF_GOLDEN=<out>/golden fbaconf run``."""
    import tempfile
    from fbaconf.bitstreams.encoder import EncoderOptions, encode
    from fbaconf.errors import FbaconfInputError
    from fbaconf.bitstreams.faptext import read_fap_file, write_fap
    src = Path(src)
    files = sorted(p for p in src.rglob("*.fap") if p.is_file()) if src.is_dir() else []
    if not files:
        return None
    out = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="fbaconf-external-"))
    d = out / "suites" / EXTERNAL_SUITE
    if d.exists():
        shutil.rmtree(d)
    d.mkdir(parents=True)
    cases = []
    for f in files:
        try:
            frames = read_fap_file(f)[0]
        except (OSError, FbaconfInputError) as e:
            log(f"external: {f}: skipped ({e})")
            continue
        stem = f"{f.parent.name}-{f.stem}".replace(" ", "_")
        for q in EXTERNAL_QUANTS:
            for rate in EXTERNAL_RATES:
                cid = f"{stem}-q{q}" + (f"-{rate:g}hz" if rate else "")
                try:
                    res = encode(frames, EncoderOptions(fap_quant=q, frame_rate=rate, intra_period=25))
                except FbaconfInputError as e:
                    log(f"external: {cid}: not codable ({e.message if hasattr(e, 'message') else e})")
                    continue
                case = Case(id=cid, suite=EXTERNAL_SUITE, claim="simple@2", group="real", kind="decode",
                            description=f"real file {f.relative_to(src)} at fap_quant {q}"
                                        + (f", {rate:g} Hz" if rate else ""), tools=["arithmetic"], suite_dir=d)
                _write(d, f"{cid}.fba", res.data, case, "fba")
                _write(d, f"{cid}.fap", write_fap(res.recon, name=cid), case, "fap")
                case.frames = len(res.recon)
                case.stages = ["faps"]
                case.goldens = {"faps": "faps.npz"}
                cases.append(case)
    suite = Suite(EXTERNAL_SUITE, f"EXTERNAL: the real .fap files of {src} (not committed)", "simple@2", "real",
                  spec()["version"], cases, d)
    atomic_write_text(d / "suite.json", json.dumps(suite.to_json(), indent=1) + "\n")
    from .golden import regenerate
    regenerate([suite], out / "golden", log=lambda *_: None)
    log(f"built external suite {EXTERNAL_SUITE}: {len(cases)} case(s) from {len(files)} file(s) in {out}")
    return suite


__all__ = ["build", "build_external", "spec", "SUITE_FORMAT"]
