"""Renderers-under-test built from the reference rasteriser: faithful ones with other samplers,
and wrong ones, each a realistic player bug (the wrong-renderer matrix).

Faithful renderers differ from the goldens (8 x 8 ordered samples) only in how they sample a
pixel: ordered grids of 2 x 2 to 4 x 4 samples, a rotated grid of 4 (RGSS, the usual 4x MSAA
pattern) and an 8-sample pattern (D3D's standard 8x MSAA positions), each averaged in linear
light. Sample patterns are rendered as one image per sample with the projection offset by the
sample's position, then averaged — exactly what a multisampling renderer computes for a pixel
fully covered by one triangle, and coverage-weighted at edges. ``float32`` (FLOAT_PIPELINE) is
faithful too, a GPU's float pipeline: the 2 x 2 image in float32, encoded to sRGB in float32 (a
background component on a rounding tie, e.g. 0.30 x 255 = 76.5, comes out one code below the
reference's).

Wrong renderers change one thing a player could get wrong: the lights (mirrored, one missing,
specular dropped), the camera (field of view, a 1 px shift), the geometry on screen (one region
displaced), textures (t not flipped, clamp instead of repeat), the encoding (pure 2.2 gamma,
sRGB applied twice), culling, the shading mode.

``python tests/suites/image_variants.py`` prints the matrix of verdicts and metrics over every image
case of the built suites (the measurement behind harness/data/tolerances.toml [images]).

Dropped FAPs: ``drop-fap-N`` renders geometry animated without FAP N — its effective
value held at 0 after FIT, left/right fill and visemes/expressions (FAP 1/2: the visemes or
expressions ignored) — so the vertices a player reports may be right while its picture is not.
``python tests/suites/image_variants.py --drop`` lists, per image case, the FAPs that move its
geometry and whether dropping each fails the case.
"""

from __future__ import annotations

import contextlib
import dataclasses
import re
import sys
import tempfile
from pathlib import Path

import numpy as np

from fbaconf.animation import engine
from fbaconf.animation.engine import animate_model, compile_scene, load_scene
from fbaconf.bitstreams.frames import FREE
from fbaconf.conformance.suite import load_suites
from fbaconf.harness.compare import ImageTolerances, compare_images
from fbaconf.reference.pipeline import load_stream
from fbaconf.rendering import raster
from fbaconf.rendering.images import encode_srgb8, openimageio
from fbaconf.rendering.render import Renderer
from fbaconf.rendering.scenario import Scenario

# 4x rotated grid (RGSS) and D3D's standard 8x sample positions, in pixel units from the corner
RGSS4 = [(0.375, 0.125), (0.875, 0.375), (0.125, 0.625), (0.625, 0.875)]
D3D8 = [
    (0.5625, 0.3125),
    (0.4375, 0.6875),
    (0.8125, 0.5625),
    (0.3125, 0.1875),
    (0.1875, 0.8125),
    (0.0625, 0.4375),
    (0.6875, 0.9375),
    (0.9375, 0.0625),
]

FAITHFUL = ("ss2", "ss3", "ss4", "rgss4", "msaa8")
FLOAT_PIPELINE = "float32"  # faithful too: the ss2 image with its linear light and encoding in float32
WRONG = (
    "lights-mirrored",
    "light-missing",
    "specular-off",
    "fov-wrong",
    "camera-shift",
    "region-displaced",
    "texture-flipped",
    "texture-clamp",
    "gamma22",
    "gamma-twice",
    "cull-backfaces",
    "wrong-shading",
    "ss1",
)


@contextlib.contextmanager
def _screen_offset(dx: float, dy: float):
    """Every projected point moved by (dx, dy) pixels of the supersampled grid."""
    orig = raster.project

    def project(vertices, camera, width, height):
        p = orig(vertices, camera, width, height)
        return dataclasses.replace(p, sx=p.sx + dx, sy=p.sy + dy)

    raster.project = project
    try:
        yield
    finally:
        raster.project = orig


@contextlib.contextmanager
def _texture_sampler(kind: str):
    orig = raster.sample_bilinear_repeat

    def flipped(tex, uv):
        return orig(tex, np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1))

    def clamped(tex, uv):
        return orig(
            tex,
            np.clip(
                uv, 0.5 / np.array([tex.shape[1], tex.shape[0]]), 1.0 - 0.5 / np.array([tex.shape[1], tex.shape[0]])
            ),
        )

    raster.sample_bilinear_repeat = flipped if kind == "flipped" else clamped
    try:
        yield
    finally:
        raster.sample_bilinear_repeat = orig


_RENDERERS: dict = {}


def _render(state, sc, k, scene_dir):
    """Frame k of ``state`` under ``sc``; one Renderer per (state, scenario, folder), so a
    sampling pattern's images share the scene's loaded textures (the state is kept with it, so
    its id is never reused while cached)."""
    key = (id(state), repr(sc), str(scene_dir))
    if key not in _RENDERERS:
        _RENDERERS[key] = (state, Renderer(state, sc, scene_dir=scene_dir))
    return _RENDERERS[key][1].render(k)


def _pattern(state, sc, k, scene_dir, samples):
    one = sc.with_(supersample=1)
    acc = None
    for ox, oy in samples:
        with _screen_offset(ox - 0.5, oy - 0.5):
            img = _render(state, one, k, scene_dir)
        acc = img if acc is None else acc + img
    return acc / len(samples)


def _displaced(state, sc, k, scene_dir):
    """The lowest tenth of the face's vertices (chin, jaw, lower lip on a head) moved sideways by
    1.5 px on screen in frame k."""
    cam = Renderer(state, sc, scene_dir=scene_dir).camera
    V = state.vertices.copy()
    y = V[k, :, 1]
    sel = y <= np.quantile(y, 0.1)
    right, eye = np.asarray(cam.basis()[0]), np.asarray(cam.position)
    depth = float(np.linalg.norm(V[k, sel].mean(axis=0) - eye))
    per_px = 2.0 * depth * np.tan(np.radians(sc.camera.fov_deg) / 2.0) / sc.height
    V[k, sel] += 1.5 * per_px * right
    return dataclasses.replace(state, vertices=V)


@contextlib.contextmanager
def _fap_dropped(fap: int):
    """Animation that ignores FAP ``fap``: its effective value 0 (FAP 1/2: visemes/expressions off)."""
    orig_eff, orig_w = engine.effective_faps, engine.high_level_weights

    def effective_faps(frames, model):
        if fap <= 2:
            frames = frames.copy()
            st = frames.status.copy()
            st[:, fap - 1] = FREE
            frames.status = st
        values, status = orig_eff(frames, model)
        if fap >= 3:
            values = values.copy()
            values[:, fap - 1] = 0.0
        return values, status

    def high_level_weights(high, status):
        wv, we = orig_w(high, status)
        return (np.zeros_like(wv) if fap == 1 else wv), (np.zeros_like(we) if fap == 2 else we)

    engine.effective_faps, engine.high_level_weights = effective_faps, high_level_weights
    try:
        yield
    finally:
        engine.effective_faps, engine.high_level_weights = orig_eff, orig_w


def _key(case) -> tuple:
    return case.suite, str(case.input_path("scene")), str(case.input_path("fba"))


def case_state(case, cache: dict, drop: int | None = None):
    """The animated state of ``case`` (FAP ``drop`` ignored), sharing its stream and compiled scene."""
    key = _key(case)
    if (key, "model") not in cache:
        scene = compile_scene(load_scene(case.input_path("scene")))
        cache[(key, "model")] = (load_stream(case.input_path("fba")), scene)
    if (key, drop) not in cache:
        frames, model = cache[(key, "model")]
        with _fap_dropped(drop) if drop is not None else contextlib.nullcontext():
            cache[(key, drop)] = animate_model(frames, model)
    return cache[(key, drop)]


def animated_faps(case, cache: dict, eps: float = 1e-9, only=None) -> list[int]:
    """The FAPs (of ``only``, default all) whose dropping moves the case's geometry in some frame."""
    base = case_state(case, cache).vertices
    out = []
    for fap in only or range(1, 69):
        v = case_state(case, cache, fap).vertices
        if v.shape != base.shape or np.abs(v - base).max() > eps:
            out.append(fap)
        cache.pop((_key(case), fap))
    return out


def render_variant(state, sc, k: int, variant: str, scene_dir=None) -> np.ndarray:
    """Frame k as the renderer ``variant`` makes it: linear float[H, W, 3], except the encoding
    variants, which return sRGB-encoded values (see :func:`encoded`)."""
    n = sc.supersample
    if variant.startswith("ss"):
        return _render(state, sc.with_(supersample=int(variant[2:])), k, scene_dir)
    if variant.startswith("drop-fap-"):  # the state passed is already the one without the FAP
        return _render(state, sc, k, scene_dir)
    if variant == "rgss4":
        return _pattern(state, sc, k, scene_dir, RGSS4)
    if variant == "msaa8":
        return _pattern(state, sc, k, scene_dir, D3D8)
    if variant == "lights-mirrored":
        lights = tuple(
            dataclasses.replace(li, direction=(-li.direction[0], li.direction[1], li.direction[2])) for li in sc.lights
        )
        return _render(state, sc.with_(lights=lights), k, scene_dir)
    if variant == "light-missing":
        return _render(state, sc.with_(lights=sc.lights[:-1] if len(sc.lights) > 1 else ()), k, scene_dir)
    if variant == "specular-off":
        return _render(state, sc.with_(specular=False), k, scene_dir)
    if variant == "fov-wrong":
        return _render(
            state, sc.with_(camera=dataclasses.replace(sc.camera, fov_deg=sc.camera.fov_deg * 1.1)), k, scene_dir
        )
    if variant == "camera-shift":
        with _screen_offset(float(n), 0.0):
            return _render(state, sc, k, scene_dir)
    if variant == "region-displaced":
        return _render(_displaced(state, sc, k, scene_dir), sc, k, scene_dir)
    if variant in ("texture-flipped", "texture-clamp"):
        with _texture_sampler(variant.split("-")[1]):
            return _render(state, sc, k, scene_dir)
    if variant == "cull-backfaces":
        return _render(state, sc.with_(cull_backfaces=not sc.cull_backfaces), k, scene_dir)
    if variant == "wrong-shading":
        return _render(state, sc.with_(shading="flat" if sc.shading == "gouraud" else "gouraud"), k, scene_dir)
    if variant in ("gamma22", "gamma-twice"):
        return _render(state, sc, k, scene_dir)
    if variant == "float32":  # a GPU's float pipeline: linear light and its encoding in float32
        return _render(state, sc, k, scene_dir).astype(np.float32)
    raise ValueError(f"unknown variant {variant}")


def encoded(linear: np.ndarray, variant: str) -> np.ndarray:
    """8-bit encoded pixels as the variant writes them."""
    x = np.clip(linear, 0.0, 1.0)
    if variant == "float32":  # the exact sRGB encode (IEC 61966-2-1), every step in float32
        x = x.astype(np.float32)
        e = np.where(
            x <= np.float32(0.0031308),
            np.float32(12.92) * x,
            np.float32(1.055) * x ** np.float32(1.0 / 2.4) - np.float32(0.055),
        ).astype(np.float32)
        return np.floor(e * np.float32(255.0) + np.float32(0.5)).astype(np.uint8)
    if variant == "gamma22":
        return np.floor(x ** (1.0 / 2.2) * 255.0 + 0.5).astype(np.uint8)
    if variant == "gamma-twice":
        once = encode_srgb8(x).astype(np.float64) / 255.0
        return encode_srgb8(once)
    return encode_srgb8(x)


def image_cases():
    return [c for s in load_suites() for c in s.cases if "images" in c.stages]


def run_variant(case, variant: str, out: Path, state_cache: dict | None = None, only: list[int] | None = None):
    """The image stage's result for ``variant`` rendering ``case``'s compared frames (``only``: just
    these of them)."""

    scene = case.input_path("scene")
    cache = state_cache if state_cache is not None else {}
    state = case_state(case, cache, int(variant.rsplit("-", 1)[1]) if variant.startswith("drop-fap-") else None)
    sc = Scenario.load(case.input_path("scenario"))
    names = case.goldens["images"]
    frames = [int(re.fullmatch(r"frame_(\d+)\.png", n).group(1)) for n in names]
    if only is not None:
        names, frames = [n for n, k in zip(names, frames) if k in only], [k for k in frames if k in only]
    out.mkdir(parents=True, exist_ok=True)
    oiio = openimageio()
    got = []
    for n, k in zip(names, frames):
        px = encoded(render_variant(state, sc, k, variant, scene_dir=scene.parent if scene else None), variant)
        p = out / n
        o = oiio.ImageOutput.create(str(p))
        o.open(str(p), oiio.ImageSpec(px.shape[1], px.shape[0], 3, oiio.UINT8))
        o.write_image(np.ascontiguousarray(px))
        o.close()
        got.append(p)
    gdir = case.golden_dir()
    return compare_images([gdir / n for n in names], got, ImageTolerances.defaults(), out / "art", frames=frames)


def drop_matrix(cases=None, log=print, faps=None) -> dict:
    """Per decode case (its scenario views together): FAP -> the first view whose image stage fails
    with that FAP dropped, or None when every view passes (``faps``: only these FAPs)."""
    cases = cases if cases is not None else image_cases()
    groups: dict = {}
    for c in cases:
        groups.setdefault((c.suite, str(c.input_path("fba"))), []).append(c)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for views in groups.values():
            cache: dict = {}
            row = {}
            for fap in animated_faps(views[0], cache, only=faps):
                row[fap] = None
                for c in views:
                    r = run_variant(c, f"drop-fap-{fap}", Path(tmp) / c.suite / c.id / str(fap), cache)
                    if r.outcome.value == "Fail":
                        row[fap] = c.id
                        break
                cache.pop((_key(views[0]), fap), None)
            out[f"{views[0].suite}/{views[0].id}"] = row
            log(
                f"{views[0].suite}/{views[0].id}: {len(row)} FAPs move it; survive dropped: "
                f"{sorted(f for f, v in row.items() if v is None)}"
            )
    return out


def shared_cases(variants, variant: str, cases: list) -> list:
    """The image cases ``variant`` renders in a faithful-renderer matrix: the first of
    ``variants`` (the coarsest sampling, the farthest from the goldens' 8 x 8) renders every
    case; each other one every (n-1)-th case, in turn — so every case is rendered by the
    coarsest and by one other sampling pattern, and every pattern meets every kind of case
    (the full matrix, every variant on every case, with each cell's numbers: ``python
    tests/suites/image_variants.py ss2 ss3 ss4 rgss4 msaa8``)."""
    if variant == variants[0]:
        return list(cases)
    others = list(variants[1:])
    k = others.index(variant)
    return [c for i, c in enumerate(cases) if i % len(others) == k]


def main(argv: list[str]) -> int:
    if argv[:1] == ["--drop"]:  # --drop [--faps N,N,...] [CASE_ID_PREFIX ...]
        faps = None
        if argv[1:2] == ["--faps"]:
            faps, argv = [int(x) for x in argv[2].split(",")], argv[:1] + argv[3:]
        drop_matrix([c for c in image_cases() if not argv[1:] or c.id.startswith(tuple(argv[1:]))], faps=faps)
        return 0
    variants = argv or list(FAITHFUL + (FLOAT_PIPELINE,) + WRONG)
    cases = image_cases()
    cache: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for v in variants:
            cells = []
            for c in cases:
                r = run_variant(c, v, Path(tmp) / v / c.suite / c.id, cache)
                m = r.metrics
                cells.append(
                    f"{c.id}:{r.outcome.value[0]}{int(m.get('violations_max', -1))}"
                    f"/{m.get('interior_deltae_mean_max', float('nan')):.2f}"
                )
            fails = sum(cell.split(":")[1][0] == "F" for cell in cells)
            print(f"{v:18s} fails {fails:2d}/{len(cases)}  " + " ".join(cells), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
