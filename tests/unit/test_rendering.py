"""Tests of the reference software rasteriser (fbaconf.rendering).

Meshes are built here; expected values are computed independently of the renderer
(pinhole camera maths, Lambert's cosine law, the IEC 61966-2-1 sRGB formula)."""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest
from hypothesis import HealthCheck, assume, given, settings, strategies as st

from fbaconf.animation import engine
from fbaconf.animation.engine import animate, load_scene
from fbaconf.animation.facestate import FaceState, MeshPart
from fbaconf.bitstreams import faptext
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.cli import main
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError, TextFormatError
from fbaconf.reference.pipeline import load_stream
from fbaconf.rendering import images, raster
from fbaconf.rendering.errors import GeometryError, ImageIOError, ScenarioError, TextureError
from fbaconf.rendering.images import encode_srgb8, read_image, srgb_to_linear, write_exr, write_png
from fbaconf.rendering.render import Renderer, render_frame, render_frames
from fbaconf.rendering.scenario import CameraSpec, DirectionalLight, FrameRange, Scenario

FOV = 60.0
D = 4.0  # camera distance for the test scenes


# ----------------------------------------------------------------------------- helpers
def cam_scenario(
    w=64,
    h=64,
    *,
    ss=1,
    pos=(0.0, 0.0, D),
    look=(0.0, 0.0, 0.0),
    ambient=1.0,
    lights=(),
    shading="flat",
    bg=(0.0, 0.0, 0.0),
    **kw,
) -> Scenario:
    return Scenario(
        width=w,
        height=h,
        supersample=ss,
        background=bg,
        shading=shading,
        camera=CameraSpec(fit=False, position=pos, look_at=look, fov_deg=FOV, near=0.1, far=100.0),
        ambient_intensity=ambient,
        lights=tuple(lights),
        **kw,
    )


def focal(h):
    return (h / 2) / math.tan(math.radians(FOV) / 2)


def to_px(x, y, z, w=64, h=64, cam=(0.0, 0.0, D)):
    """Independent pinhole projection for a camera looking down -z."""
    d = cam[2] - z
    f = focal(h)
    return w / 2 + f * (x - cam[0]) / d, h / 2 - f * (y - cam[1]) / d


def state_of(*parts_spec, frames=None):
    """parts_spec: (name, vertices[n,3], tris, kwargs)."""
    parts, verts, off = [], [], 0
    for name, v, t, kw in parts_spec:
        v = np.asarray(v, dtype=np.float64)
        parts.append(MeshPart(name, off, len(v), np.asarray(t), **kw))
        verts.append(v)
        off += len(v)
    allv = np.concatenate(verts)[None]
    if frames is not None:
        allv = frames
    return FaceState(parts, allv, np.zeros(allv.shape[0]))


def quad(x0, y0, x1, y1, z=0.0):
    v = [(x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)]
    return v, [[0, 1, 2], [0, 2, 3]]  # CCW seen from +z


def uv_sphere(nlat=16, nlon=24, r=1.0):
    th = np.linspace(0, np.pi, nlat + 1)[1:-1]
    ph = np.linspace(0, 2 * np.pi, nlon, endpoint=False)
    T, P = np.meshgrid(th, ph, indexing="ij")
    pts = np.stack([np.sin(T) * np.cos(P), np.cos(T), -np.sin(T) * np.sin(P)], -1).reshape(-1, 3)
    pts = np.vstack([[0, 1, 0], pts, [0, -1, 0]]) * r

    def idx(i, j):
        return 1 + i * nlon + (j % nlon)

    tris = [[0, idx(0, j), idx(0, j + 1)] for j in range(nlon)]
    for i in range(nlat - 2):
        for j in range(nlon):
            a, b, c, d = idx(i, j), idx(i, j + 1), idx(i + 1, j), idx(i + 1, j + 1)
            tris += [[a, c, d], [a, d, b]]
    last = len(pts) - 1
    tris += [[last, idx(nlat - 2, j + 1), idx(nlat - 2, j)] for j in range(nlon)]
    return pts, np.array(tris)


def sphere_state(**kw):
    v, t = uv_sphere()
    return state_of(("ball", v, t, kw))


def write_rgb_png(path, rgb8):
    spec = oiio.ImageSpec(rgb8.shape[1], rgb8.shape[0], 3, "uint8")
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    assert out.write_image(np.ascontiguousarray(rgb8, dtype=np.uint8))
    out.close()


def read_u8(path):
    return oiio.ImageBuf(str(path)).get_pixels(oiio.UINT8)


# ----------------------------------------------------------------------------- visibility
@pytest.mark.parametrize("near_first", [True, False])
def test_zbuffer_picks_nearer_triangle(near_first):
    red = ("near", [(-1, -1, 0.5), (1, -1, 0.5), (0, 1, 0.5)], [[0, 1, 2]], {"color": (1.0, 0.0, 0.0)})
    blue = ("far", [(-1.5, -1.5, -0.5), (1.5, -1.5, -0.5), (0, 1.5, -0.5)], [[0, 1, 2]], {"color": (0.0, 0.0, 1.0)})
    parts = (red, blue) if near_first else (blue, red)
    img = render_frame(state_of(*parts), 0, cam_scenario())
    np.testing.assert_allclose(img[32, 32], [1.0, 0.0, 0.0], atol=1e-12)
    # The far, larger triangle shows where the near one does not cover: its lower corners.
    x, y = to_px(-1.3, -1.35, -0.5)
    np.testing.assert_allclose(img[int(y), int(x)], [0.0, 0.0, 1.0], atol=1e-12)


@pytest.mark.parametrize("shading", ["flat", "gouraud"])
def test_exact_depth_ties_go_to_the_first_drawn_triangle(shading):
    v, t = quad(-1, -1, 1, 1)
    a = ("a", v, t, {"color": (1.0, 0.0, 0.0)})
    b = ("b", v, t, {"color": (0.0, 1.0, 0.0)})
    sc = cam_scenario(shading=shading)
    np.testing.assert_allclose(render_frame(state_of(a, b), 0, sc)[32, 32], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(render_frame(state_of(b, a), 0, sc)[32, 32], [0, 1, 0], atol=1e-12)
    img = render_frame(state_of(a, b), 0, sc)
    assert (img[:, :, 1] == 0).all()  # not a single sample of the second copy shows


def test_background_where_nothing_is_drawn(tmp_path):
    bg = (0.2, 0.4, 0.6)
    sc = cam_scenario(bg=bg)
    v, t = quad(-0.5, -0.5, 0.5, 0.5)
    img = render_frame(state_of(("q", v, t, {"color": (1, 1, 1)})), 0, sc)
    expect = [((c + 0.055) / 1.055) ** 2.4 for c in bg]  # sRGB EOTF, independent
    for y, x in [(0, 0), (63, 63), (0, 63), (5, 30)]:
        np.testing.assert_allclose(img[y, x], expect, rtol=1e-9)
    np.testing.assert_allclose(img[32, 32], [1, 1, 1], atol=1e-12)
    (p,) = render_frames(state_of(("q", v, t, {"color": (1, 1, 1)})), sc, tmp_path)
    assert p.name == "frame_00000.png"
    np.testing.assert_array_equal(read_u8(p)[0, 0], [51, 102, 153])


def test_backface_culling_follows_ccw_front():
    v, t = quad(-1, -1, 1, 1)
    ccw = state_of(("q", v, t, {"color": (1, 1, 1)}))
    cw = state_of(("q", v, np.asarray(t)[:, ::-1], {"color": (1, 1, 1)}))
    sc = cam_scenario(cull_backfaces=True)
    assert render_frame(ccw, 0, sc)[32, 32, 0] == 1.0
    assert render_frame(cw, 0, sc)[32, 32, 0] == 0.0
    # two-sided by default: the back face is drawn and lit with the flipped normal
    lit = cam_scenario(ambient=0.0, lights=[DirectionalLight((0, 0, -1))])
    np.testing.assert_allclose(render_frame(cw, 0, lit)[32, 32], [1, 1, 1], atol=1e-12)


# ----------------------------------------------------------------------------- coverage rules
def _raster_px(pts_px, tris, w=32, h=32):
    pts = np.asarray(pts_px, dtype=np.float64)
    proj = raster.Projected(pts[:, 0], pts[:, 1], np.ones(len(pts)))
    return raster.rasterize(proj, np.asarray(tris), w, h, 0.5, 10.0)


def test_square_covers_exactly_its_pixel_centres_once():
    # square [10, 20) x [5, 17) in pixel units: its sample centres 10.5..19.5 x 5.5..16.5
    pts = [(10, 5), (20, 5), (20, 17), (10, 17)]
    cov = _raster_px(pts, [[0, 1, 2], [0, 2, 3]])
    assert cov.pix.size == 10 * 12 == np.unique(cov.pix).size
    xs, ys = cov.pix % 32, cov.pix // 32
    assert xs.min() == 10 and xs.max() == 19 and ys.min() == 5 and ys.max() == 16


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(
    st.integers(2, 29),
    st.integers(2, 29),
    st.lists(st.tuples(st.integers(0, 31), st.integers(0, 31)), min_size=3, max_size=8, unique=True),
)
def test_fan_is_watertight_no_sample_twice(cx, cy, rim):
    """Triangles sharing edges through sample centres: each sample goes to exactly one."""
    pts = [(cx + 0.5, cy + 0.5)] + [(x + 0.5, y + 0.5) for x, y in rim]
    ang = {i: math.atan2(pts[i][1] - pts[0][1], pts[i][0] - pts[0][0]) for i in range(1, len(pts))}
    order = sorted(ang, key=ang.get)
    a = [ang[i] for i in order]
    gaps = [b - c for b, c in zip(a[1:], a[:-1])] + [a[0] + 2 * math.pi - a[-1]]
    assume(min(gaps) > 1e-9 and max(gaps) < math.pi - 1e-9)  # a proper fan around the centre
    tris = [[0, order[i], order[(i + 1) % len(order)]] for i in range(len(order))]
    per_tri = sum(_raster_px(pts, [t]).pix.size for t in tris)
    whole = _raster_px(pts, tris)
    assert np.unique(whole.pix).size == whole.pix.size
    # every triangle's own samples, summed, equal the union when no sample is shared
    singles = [set(_raster_px(pts, [t]).pix.tolist()) for t in tris]
    union = set().union(*singles)
    assert per_tri == len(union) == whole.pix.size


# ----------------------------------------------------------------------------- shading
def test_lambert_cosine_60_degrees():
    c = math.cos(math.radians(60))
    s = math.sin(math.radians(60))
    head_on = state_of(("a", *quad(-1, -1, 1, 1), {"color": (0.9, 0.9, 0.9)}))
    # the same quad turned 60 degrees about the y axis (normal (sin60, 0, cos60))
    turned_v = [(-c, -1, s), (c, -1, -s), (c, 1, -s), (-c, 1, s)]
    turned = state_of(("b", turned_v, [[0, 1, 2], [0, 2, 3]], {"color": (0.9, 0.9, 0.9)}))
    for shading in ("flat", "gouraud"):
        sc = cam_scenario(ambient=0.0, lights=[DirectionalLight((0, 0, -1), (1, 1, 1), 0.8)], shading=shading)
        a = render_frame(head_on, 0, sc)[32, 32]
        b = render_frame(turned, 0, sc)[32, 32]
        np.testing.assert_allclose(a, 0.9 * 0.8, rtol=1e-12)
        np.testing.assert_allclose(b / a, math.cos(math.radians(60)), rtol=1e-9)


def test_flat_and_gouraud_differ_on_a_sphere():
    st_ = sphere_state(color=(0.8, 0.8, 0.8))
    lights = [DirectionalLight((0.3, -0.4, -1.0))]
    flat = render_frame(st_, 0, cam_scenario(128, 128, ambient=0.1, lights=lights, shading="flat"))
    gour = render_frame(st_, 0, cam_scenario(128, 128, ambient=0.1, lights=lights, shading="gouraud"))
    inside = flat[:, :, 0] != 0.0
    assert (inside == (gour[:, :, 0] != 0.0)).all()
    assert np.abs(flat - gour)[inside].mean() > 1e-3
    # Flat: one value per visible triangle (at most the triangle count); Gouraud: a
    # smooth gradient with a distinct value at almost every pixel.
    n_flat = np.unique(flat[inside][:, 0]).size
    n_gour = np.unique(gour[inside][:, 0]).size
    assert n_flat <= st_.parts[0].triangles.shape[0] and n_gour > 3 * n_flat


def test_specular_highlight_brightens_towards_mirror_direction():
    st_ = sphere_state(color=(0.5, 0.5, 0.5), specular=1.0, shininess=0.3)
    sc = cam_scenario(ambient=0.0, lights=[DirectionalLight((0, 0, -1))], shading="gouraud")
    on = render_frame(st_, 0, sc)
    off = render_frame(st_, 0, sc.with_(specular=False))
    assert on[32, 32, 0] > off[32, 32, 0] + 0.5  # highlight at the centre (H = n)
    np.testing.assert_allclose(on[0, 0], off[0, 0])


def test_vertex_colours_are_interpolated():
    v, t = quad(-1, -1, 1, 1)
    vc = np.array([[1, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 1]], dtype=np.float32)  # bottom red, top blue
    img = render_frame(state_of(("q", v, t, {"vertex_colors": vc})), 0, cam_scenario(shading="gouraud"))
    _, ytop = to_px(0, 0.9, 0)
    _, ybot = to_px(0, -0.9, 0)
    assert img[int(ytop), 32, 2] > 0.9 and img[int(ybot), 32, 0] > 0.9


# ----------------------------------------------------------------------------- textures
def _checker(tmp_path):
    # 2 x 2 blocks of 2 x 2 texels: top (v = 1) red, green; bottom blue, white
    blocks = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], dtype=np.uint8)
    tex = np.repeat(np.repeat(blocks, 2, axis=0), 2, axis=1)
    path = tmp_path / "checker.png"
    write_rgb_png(path, tex)
    return path


@pytest.mark.parametrize("shading", ["flat", "gouraud"])
def test_texture_checker_lands_in_the_right_quadrants(tmp_path, shading):
    path = _checker(tmp_path)
    v, t = quad(-1, -1, 1, 1)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    state = state_of(("q", v, t, {"texcoords": uv, "texture": path.name}))
    img = render_frame(state, 0, cam_scenario(shading=shading), scene_dir=tmp_path)
    # lit head-on at 0.5 + ambient 0.25: the texture colour times 0.75
    lit = render_frame(
        state,
        0,
        cam_scenario(shading=shading, ambient=0.25, lights=[DirectionalLight((0, 0, -1), intensity=0.5)]),
        scene_dir=tmp_path,
    )
    expect = {(-0.5, 0.5): (1, 0, 0), (0.5, 0.5): (0, 1, 0), (-0.5, -0.5): (0, 0, 1), (0.5, -0.5): (1, 1, 1)}
    for (x, y), col in expect.items():
        px, py = to_px(x, y, 0)
        np.testing.assert_allclose(img[int(py), int(px)], col, atol=1e-9)
        np.testing.assert_allclose(lit[int(py), int(px)], np.multiply(col, 0.75), atol=1e-9)


def test_texture_mapping_is_perspective_correct(tmp_path):
    tex = np.array([[[255, 0, 0], [0, 255, 0]]], dtype=np.uint8)  # u < 0.5 red, u > 0.5 green
    path = tmp_path / "lr.png"
    write_rgb_png(path, tex)
    # left edge at z = 0, right edge at z = -4: u = 0.5 lies at x = 0, z = -2
    v = [(-1, -1, 0), (1, -1, -4), (1, 1, -4), (-1, 1, 0)]
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    state = state_of(("q", v, [[0, 1, 2], [0, 2, 3]], {"texcoords": uv, "texture": str(path)}))
    w = 256
    img = render_frame(state, 0, cam_scenario(w, w))
    row = img[w // 2]
    red_wins = row[:, 0] > row[:, 1]
    xl, _ = to_px(-1, 0, 0, w, w)
    xr, _ = to_px(1, 0, -4, w, w)
    cols = np.arange(w)
    on = (cols + 0.5 > xl) & (cols + 0.5 < xr)
    crossing = cols[on & ~red_wins].min()
    assert abs(crossing - w / 2) <= 1  # projected 3D midpoint
    assert abs(crossing - (xl + xr) / 2) > 5  # not the screen-space (affine) midpoint


def test_missing_texture_is_a_typed_error(tmp_path):
    v, t = quad(-1, -1, 1, 1)
    uv = np.zeros((4, 2))
    state = state_of(("skin", v, t, {"texcoords": uv, "texture": "nope.png"}))
    with pytest.raises(TextureError, match="skin"):
        render_frame(state, 0, cam_scenario(), scene_dir=tmp_path)
    with pytest.raises(GeometryError, match="no texcoords"):
        render_frame(state_of(("skin", v, t, {"texture": "nope.png"})), 0, cam_scenario())


# ----------------------------------------------------------------------------- files
def test_render_twice_is_bit_identical_and_one_pixel_camera_change_is_not(tmp_path):
    v, t = uv_sphere()
    state = state_of(("ball", v, t, {"color": (0.7, 0.5, 0.4), "specular": 0.4}))
    sc = cam_scenario(64, 64, ss=2, ambient=0.2, lights=[DirectionalLight((0.4, -0.5, -1))], shading="gouraud")
    a = render_frames(state, sc, tmp_path / "a")
    b = render_frames(state, sc, tmp_path / "b")
    assert a[0].read_bytes() == b[0].read_bytes()
    dx = D / focal(64)  # one pixel at the depth of z = 0
    moved = cam_scenario(
        64,
        64,
        ss=2,
        pos=(dx, 0.0, D),
        look=(dx, 0.0, 0.0),
        ambient=0.2,
        lights=[DirectionalLight((0.4, -0.5, -1))],
        shading="gouraud",
    )
    c = render_frames(state, moved, tmp_path / "c")
    assert c[0].read_bytes() != a[0].read_bytes()
    # and the image content moved by one pixel to the left (exact for the z = 0 plane)
    q = state_of(("q", *quad(-1, -1, 1, 1), {"color": (1, 1, 1)}))
    i1 = render_frame(q, 0, cam_scenario(64, 64, ss=2))
    i2 = render_frame(q, 0, cam_scenario(64, 64, ss=2, pos=(dx, 0.0, D), look=(dx, 0.0, 0.0)))
    assert not np.array_equal(i1, i2)
    np.testing.assert_allclose(i2[:, :-1], i1[:, 1:], atol=1e-12)


@pytest.mark.spawns("the claim is about a second process: it renders the same bits")
def test_bit_identical_across_processes(tmp_path):
    script = textwrap.dedent(f"""
        import sys, numpy as np
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_rendering import sphere_state, cam_scenario
        from fbaconf.rendering.scenario import DirectionalLight
        from fbaconf.rendering.render import render_frames
        sc = cam_scenario(48, 48, ss=3, ambient=0.2, lights=[DirectionalLight((0.4, -0.5, -1))],
                          shading="gouraud", format="exr")
        render_frames(sphere_state(color=(0.7, 0.5, 0.4), specular=0.5), sc, sys.argv[1])
    """)
    (tmp_path / "s.py").write_text(script)
    here = render_frames(
        sphere_state(color=(0.7, 0.5, 0.4), specular=0.5),
        cam_scenario(
            48, 48, ss=3, ambient=0.2, lights=[DirectionalLight((0.4, -0.5, -1))], shading="gouraud", format="exr"
        ),
        tmp_path / "a",
    )
    subprocess.run(
        [sys.executable, str(tmp_path / "s.py"), str(tmp_path / "b")],
        check=True,
        env={**os.environ, "PYTHONHASHSEED": "123"},
    )
    assert here[0].name == "frame_00000.exr"
    assert (tmp_path / "b" / "frame_00000.exr").read_bytes() == here[0].read_bytes()


def test_exr_and_png_round_trip_through_oiio(tmp_path):
    rng = np.random.default_rng(7)
    lin = rng.uniform(0.0, 1.5, size=(9, 11, 3))
    write_exr(tmp_path / "x.exr", lin)
    back, fmt = read_image(tmp_path / "x.exr")
    assert fmt == "float"
    np.testing.assert_array_equal(back, lin.astype(np.float32))
    write_png(tmp_path / "x.png", lin)
    back8 = read_u8(tmp_path / "x.png")
    np.testing.assert_array_equal(back8, encode_srgb8(lin))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.exr", "x.png"]  # no temp files left


def test_srgb_encoding_matches_colour_science_and_the_formula():
    import colour  # noqa: PLC0415 (colour-science loads in ~1 s)

    vals = np.array([0.0, 0.001, 0.0031308, 0.01, 0.18, 0.5, 0.9, 1.0, 1.7, -0.2])
    clipped = np.clip(vals, 0, 1)
    formula = np.where(clipped <= 0.0031308, 12.92 * clipped, 1.055 * clipped ** (1 / 2.4) - 0.055)
    np.testing.assert_allclose(colour.cctf_encoding(clipped, function="sRGB"), formula, atol=1e-12)
    np.testing.assert_array_equal(encode_srgb8(vals), np.floor(formula * 255 + 0.5).astype(np.uint8))
    assert encode_srgb8(np.array([0.18]))[0] == 118
    np.testing.assert_allclose(srgb_to_linear(formula), clipped, atol=1e-12)


def test_frames_selection_and_names(tmp_path):
    v, t = quad(-1, -1, 1, 1)
    frames = np.stack([np.asarray(v, float) + [0.1 * k, 0, 0] for k in range(5)])
    state = state_of(("q", v, t, {}), frames=frames)
    paths = render_frames(state, cam_scenario(16, 16, frames=FrameRange(1, None, 2)), tmp_path)
    assert [p.name for p in paths] == ["frame_00001.png", "frame_00003.png"]
    with pytest.raises(ScenarioError, match="out of range"):
        render_frames(state, cam_scenario(16, 16, frames=(0, 7)), tmp_path / "x")
    assert not (tmp_path / "x").exists()


# ----------------------------------------------------------------------------- degenerate geometry
def test_nan_vertex_is_an_error_naming_part_vertex_and_frame():
    v, t = quad(-1, -1, 1, 1)
    frames = np.stack([np.asarray(v, float)] * 3)
    frames[2, 3, 1] = np.nan
    state = state_of(
        ("a", [(0, 0, 0)], np.zeros((0, 3)), {}),
        ("lips", v, t, {}),
        frames=np.concatenate([np.zeros((3, 1, 3)), frames], axis=1),
    )
    r = Renderer(state, cam_scenario())
    r.render(1)
    with pytest.raises(GeometryError) as ei:
        r.render(2)
    e = ei.value
    assert (e.part, e.vertex, e.frame) == ("lips", 3, 2) and isinstance(e, FbaconfInputError)
    assert "lips" in str(e) and "vertex 3" in str(e)
    state.vertices[0, 1, 0] = np.inf  # frame 0 places the fitted camera
    with pytest.raises(GeometryError):
        Renderer(state, Scenario())


def test_bad_triangle_index_or_material_is_an_error():
    tri = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    with pytest.raises(GeometryError, match="outside"):
        render_frame(state_of(("q", tri, [[0, 1, 3]], {})), 0, cam_scenario())
    with pytest.raises(GeometryError, match="finite"):
        render_frame(state_of(("q", tri, [[0, 1, 2]], {"color": (1, np.nan, 0)})), 0, cam_scenario())
    with pytest.raises(GeometryError, match="shininess"):
        render_frame(state_of(("q", tri, [[0, 1, 2]], {"shininess": np.inf})), 0, cam_scenario())
    with pytest.raises(GeometryError, match="vertex_colors"):
        render_frame(state_of(("q", tri, [[0, 1, 2]], {"vertex_colors": np.ones((2, 3))})), 0, cam_scenario())


def test_near_plane_and_zero_area_are_defined():
    tri_behind = [(-1, -1, 0), (1, -1, 0), (0, 1, D + 1)]  # one vertex behind the camera
    tri_zero = [(-1, -1, 0), (0, 0, 0), (1, 1, 0)]  # collinear
    ok = [(-0.2, -0.2, 0), (0.2, -0.2, 0), (0, 0.2, 0)]
    state = state_of(
        ("a", tri_behind, [[0, 1, 2]], {}),
        ("b", tri_zero, [[0, 1, 2]], {}),
        ("c", ok, [[0, 1, 2]], {"color": (0, 1, 0)}),
    )
    r = Renderer(state, cam_scenario(shading="gouraud"))
    img = r.render(0)
    assert np.isfinite(img).all()
    assert r.skipped_near[0] == 1
    assert np.count_nonzero(img.sum(axis=2)) == np.count_nonzero(img[:, :, 1])  # only the green one


# ----------------------------------------------------------------------------- properties
finite = st.floats(-1.2, 1.2, allow_nan=False)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.tuples(finite, finite, st.floats(-2, 1.5)), min_size=3, max_size=12),
    st.sampled_from(["flat", "gouraud"]),
    st.integers(1, 3),
    st.tuples(st.floats(0, 1), st.floats(0, 1), st.floats(0, 1)),
)
def test_random_triangles_give_finite_pixels_in_unit_range(pts, shading, ss, col):
    n = len(pts) - len(pts) % 3
    tris = np.arange(n).reshape(-1, 3)
    state = state_of(("r", pts[:n], tris, {"color": col, "specular": 0.0}))
    sc = cam_scenario(
        24,
        24,
        ss=ss,
        ambient=0.3,
        shading=shading,
        lights=[DirectionalLight((0.2, -0.3, -1.0), intensity=0.4), DirectionalLight((-1.0, 0.0, 0.2), intensity=0.3)],
    )
    img = render_frame(state, 0, sc)
    assert img.shape == (24, 24, 3)
    assert np.isfinite(img).all() and img.min() >= 0.0 and img.max() <= 1.0 + 1e-12


@settings(max_examples=30, deadline=None)
@given(st.floats(-1.0, 0.9), st.floats(-1.0, 0.9), st.floats(0.05, 1.0), st.floats(0.05, 1.0), st.integers(1, 4))
def test_rectangle_coverage_matches_analytic_area(x0, y0, w, h, ss):
    x1, y1 = min(x0 + w, 1.1), min(y0 + h, 1.1)
    state = state_of(("rect", *quad(x0, y0, x1, y1), {"color": (1, 1, 1)}))
    img = render_frame(state, 0, cam_scenario(32, 32, ss=ss))
    covered = img[:, :, 0].sum()
    (px0, py1), (px1, py0) = to_px(x0, y0, 0, 32, 32), to_px(x1, y1, 0, 32, 32)
    wn, hn = (px1 - px0) * ss, (py1 - py0) * ss  # extent in samples
    lo = max(wn - 1, 0) * max(hn - 1, 0) / ss**2
    hi = (wn + 1) * (hn + 1) / ss**2
    assert lo - 1e-9 <= covered <= hi + 1e-9


# ----------------------------------------------------------------------------- scenario files
def test_default_scenario_and_toml_round_trip(tmp_path):
    sc = Scenario.default()
    assert (sc.width, sc.height, sc.supersample, sc.shading, sc.format) == (256, 256, 3, "gouraud", "png")
    assert sc.camera.fit and len(sc.lights) >= 2 and sc.ambient_intensity > 0
    assert Scenario.from_toml(sc.to_toml()) == sc
    odd = cam_scenario(frames=FrameRange(2, 9, 3), cull_backfaces=True, format="exr")
    sc.save(tmp_path / "s.toml")
    assert Scenario.load(tmp_path / "s.toml") == sc
    assert Scenario.from_toml(odd.to_toml()) == odd
    assert Scenario.from_toml(cam_scenario(frames=(4, 1)).to_toml()).frames == (4, 1)


@pytest.mark.parametrize(
    "text, key",
    [
        ("width = 0", "width"),
        ("widht = 5", "widht"),
        ("width = 2.5", "width"),
        ("supersample = 9", "supersample"),
        ("shading = 'phong'", "shading"),
        ("format = 'jpg'", "format"),
        ("background = [0.1, 2.0, 0.1]", "background[1]"),
        ("background = [0.1, 0.1]", "background"),
        ("frames = [1, -2]", "frames[1]"),
        ("frames = 'all'", "frames"),
        ("[camera]\nfit = true\nposition = [0, 0, 1]", "camera.position"),
        ("[camera]\nfit = false\nlook_at = [0, 0, 0]", "camera.position"),
        ("[camera]\nposition = [0, 0, 1]\nlook_at = [0, 0, 1]", "camera.look_at"),
        ("[camera]\nposition = [0, 5, 0]\nlook_at = [0, 0, 0]", "camera.up"),
        ("[camera]\nfov_deg = 0", "camera.fov_deg"),
        ("[camera]\nposition = [0, 0, 5]\nlook_at = [0, 0, 0]\nnear = 2\nfar = 1", "camera.far"),
        ("[[lights]]\ncolor = [1, 1, 1]", "lights[0].direction"),
        ("[[lights]]\ndirection = [0, 0, 0]", "lights[0].direction"),
        ("[[lights]]\ndirection = [0, 0, -1]\nintensity = -1", "lights[0].intensity"),
        ("[ambient]\nbrightness = 1", "ambient.brightness"),
    ],
)
def test_scenario_errors_are_typed_and_name_the_key(text, key):
    with pytest.raises(ScenarioError) as ei:
        Scenario.from_toml(text, file="sc.toml")
    assert ei.value.key == key and ei.value.file == "sc.toml"
    assert isinstance(ei.value, FbaconfInputError) and isinstance(ei.value, ValueError)
    assert key in str(ei.value) and "sc.toml" in str(ei.value)


def test_scenario_syntax_error_has_line_and_column(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("width = 64\nheight = = 3\n")
    with pytest.raises(TextFormatError) as ei:
        Scenario.load(p)
    assert ei.value.line == 2 and ei.value.column > 1 and ei.value.file == str(p)
    with pytest.raises(ScenarioError, match="cannot read"):
        Scenario.load(tmp_path / "missing.toml")


def test_fit_camera_frames_the_mesh():
    v, t = uv_sphere(r=30.0)
    state = state_of(("ball", v + [100.0, -50.0, 20.0], t, {"color": (1, 1, 1)}))
    sc = Scenario(width=64, height=48, ambient_intensity=1.0)
    cam = sc.resolve_camera(state.vertices[0])
    np.testing.assert_allclose(cam.look_at, [100, -50, 20], atol=1e-9)
    img = render_frame(state, 0, sc)
    ys, xs = np.nonzero(img[:, :, 0])
    assert 0 < xs.min() and xs.max() < 63 and 0 < ys.min() and ys.max() < 47  # inside, not clipped
    assert ys.max() - ys.min() > 20  # and large
    assert abs((xs.min() + xs.max()) / 2 - 31.5) <= 1 and abs((ys.min() + ys.max()) / 2 - 23.5) <= 1


def test_fit_from_the_side_and_over_all_frames():
    v, t = uv_sphere()
    moving = np.stack([v, v + [1.5, 0.0, 0.0]])  # frame 1 moves right by 1.5 radii
    state = state_of(("ball", v, t, {"color": (1, 1, 1)}), frames=moving)
    side = Scenario(width=32, height=32, ambient_intensity=1.0, camera=CameraSpec(direction=(-1.0, 0.0, 0.0)))
    cam = Renderer(state, side).camera
    assert cam.position[0] > 1.0 and abs(cam.position[2]) < 1e-9  # on +x, looking along -x
    first = Scenario(width=32, height=32, ambient_intensity=1.0)
    allf = Scenario.from_toml("width = 32\nheight = 32\n[ambient]\nintensity = 1.0\n[camera]\nfit_to = 'all'\n")
    assert allf.camera.fit_to == "all" and Scenario.from_toml(allf.to_toml()) == allf
    img_first = Renderer(state, first).render(1)
    img_all = Renderer(state, allf).render(1)
    assert img_first[:, -1, 0].max() == 1.0  # frame 1 runs off the frame-0 framing
    ys, xs = np.nonzero(img_all[:, :, 0])
    assert xs.max() < 31 and xs.min() > 0  # framing all frames keeps it inside
    with pytest.raises(ScenarioError, match="fit_to"):
        Scenario.from_toml("[camera]\nfit = false\nposition = [0, 0, 1]\nlook_at = [0, 0, 0]\nfit_to = 'all'")


# ----------------------------------------------------------------------------- CLI
def _fake_engine(monkeypatch, state):
    mod = types.ModuleType("fbaconf.animation.engine")
    calls = []

    def animate(frames, scene=None):
        calls.append((len(frames), scene))
        return state

    mod.animate = animate
    monkeypatch.setitem(sys.modules, "fbaconf.animation.engine", mod)
    return calls


def test_cli_render_verb(tmp_path, monkeypatch, capsys):
    v, t = uv_sphere()
    state = state_of(("ball", v, t, {"color": (0.8, 0.7, 0.6)}), frames=np.stack([v, v * 1.1]))
    calls = _fake_engine(monkeypatch, state)
    faps = tmp_path / "f.npz"
    FapFrames.empty(2).save_npz(faps)
    sc = tmp_path / "sc.toml"
    sc.write_text("width = 32\nheight = 32\n[ambient]\nintensity = 0.5\n")
    assert main(["render", "--faps", str(faps), "--scenario", str(sc), "-o", str(tmp_path / "out")]) == 0
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["frame_00000.png", "frame_00001.png"]
    assert calls == [(2, None)]
    # bad scenario -> exit 2 with a one-line message
    sc.write_text("width = 'wide'\n")
    assert main(["render", "--faps", str(faps), "--scenario", str(sc), "-o", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "width" in err and "Traceback" not in err
    assert main(["render", "--faps", str(tmp_path / "none.npz"), "-o", str(tmp_path / "o3")]) == 2
    (tmp_path / "afile").write_text("x")
    sc.write_text("width = 8\nheight = 8\n")
    assert main(["render", "--faps", str(faps), "--scenario", str(sc), "-o", str(tmp_path / "afile")]) == 2
    assert "cannot write" in capsys.readouterr().err


def test_cli_reports_missing_animation_stage(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "fbaconf.animation.engine", None)  # import -> ImportError
    faps = tmp_path / "f.npz"
    FapFrames.empty(1).save_npz(faps)
    assert main(["render", "--faps", str(faps), "-o", str(tmp_path / "out")]) == 2
    assert "animation stage" in capsys.readouterr().err


def test_chunked_rasterisation_gives_the_same_coverage(monkeypatch):
    v, t = uv_sphere()
    proj = raster.project(v * 1.3, raster.Camera((0.2, 0.1, D), (0, 0, 0)), 80, 60)
    whole = raster.rasterize(proj, t, 80, 60, 0.1, 100.0)
    monkeypatch.setattr(raster, "_MAX_FRAGMENTS", 97)
    parts = raster.rasterize(proj, t, 80, 60, 0.1, 100.0)
    o1, o2 = np.argsort(whole.pix), np.argsort(parts.pix)
    for f in ("pix", "tri", "v0", "v1", "v2", "b0", "b1", "b2", "front"):
        np.testing.assert_array_equal(getattr(whole, f)[o1], getattr(parts, f)[o2])
    assert whole.pix.size > 1000


def test_cli_end_to_end_with_the_animation_stage(tmp_path):
    """The real default head (when the animation stage is present): npz and .fap inputs."""
    assert hasattr(engine, "animate")
    frames = FapFrames.empty(2)
    frames.save_npz(tmp_path / "f.npz")
    faptext.write_fap_file(tmp_path / "f.fap", frames)
    sc = tmp_path / "sc.toml"
    Scenario.default().with_(width=48, height=48, supersample=1).save(sc)
    for name in ("f.npz", "f.fap"):
        assert (
            main(
                [
                    "render",
                    "--faps",
                    str(tmp_path / name),
                    "--scenario",
                    str(sc),
                    "-o",
                    str(tmp_path / name.replace(".", "_")),
                ]
            )
            == 0
        )
    a = sorted((tmp_path / "f_npz").iterdir())
    b = sorted((tmp_path / "f_fap").iterdir())
    assert [p.name for p in a] == ["frame_00000.png", "frame_00001.png"]
    assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    img = read_u8(a[0]).astype(int)
    bg = encode_srgb8(srgb_to_linear(np.array(Scenario.default().background)))
    assert (np.abs(img - bg).sum(axis=2) > 30).mean() > 0.15  # a face covers a good part of the image


def test_failed_image_write_leaves_no_file(tmp_path, monkeypatch):

    class FailingOutput:
        def open(self, path, spec):
            Path(path).write_bytes(b"partial")
            return True

        def write_image(self, px):
            return False

        def geterror(self):
            return "disk full"

        def close(self):
            return True

    fake = types.SimpleNamespace(
        ImageOutput=types.SimpleNamespace(create=lambda p: FailingOutput()),
        ImageSpec=oiio.ImageSpec,
        geterror=lambda: "",
    )
    monkeypatch.setattr(images, "openimageio", lambda: fake)
    with pytest.raises(ImageIOError, match="disk full"):
        write_png(tmp_path / "frame_00000.png", np.zeros((4, 4, 3)))
    assert list(tmp_path.iterdir()) == []


def test_every_image_case_keeps_clear_of_the_near_plane():
    """GL clips a triangle that crosses the near plane where fbaconf's rasteriser skips it
    whole (raster.py, "Clipping"); the two agree only while no vertex of a rendered frame is
    nearer than the near plane. Every frame of every committed image case is checked (the
    scenario's fitted camera, the animated vertices), so the difference is never exercised."""
    checked = 0
    animated = {}  # the scenarios of a case share its stream and scene: animated once
    for s in load_suites():
        for c in s.cases:
            if "images" not in c.stages:
                continue
            stream, scene = c.input_path("fba").read_bytes(), c.input_path("scene").read_bytes()
            key = (hashlib.sha256(stream).hexdigest(), hashlib.sha256(scene).hexdigest(), c.input_path("scene").name)
            if key not in animated:
                animated[key] = animate(decode(stream).frames, load_scene(c.input_path("scene")))
            state = animated[key]
            sc = Scenario.load(c.input_path("scenario"))
            cam = Renderer(state, sc, scene_dir=c.input_path("scene").parent).camera
            right, up, fwd = cam.basis()
            depth = (state.vertices - np.asarray(cam.position)) @ fwd  # view depth, every frame
            assert float(depth.min()) > cam.near, (c.full_id, float(depth.min()), cam.near)
            checked += 1
    assert checked >= 39


# ----------------------------------------------------------------------------- the C fast path
needs_native = pytest.mark.skipif(raster.native() is None, reason="rendering/_fastraster.c was not built here")


def _coverage_by_pixel(cov):
    order = np.argsort(cov.pix, kind="stable")
    return {k: np.asarray(getattr(cov, k))[order] for k in ("pix", "tri", "v0", "v1", "v2", "b0", "b1", "b2", "front")}


@needs_native
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 2**31 - 1), st.integers(1, 40), st.booleans(), st.sampled_from([(8, 8), (31, 17), (64, 48)]))
def test_native_scan_conversion_equals_the_numpy_reference(seed, n_tri, cull, size):
    """Random triangle soups (shared edges, slivers, corners on sample centres, some beyond the
    far plane): the C winners and barycentrics are the numpy path's, bit for bit."""
    rng = np.random.default_rng(seed)
    w, h = size
    nv = 3 * n_tri
    sx = rng.uniform(-4, w + 4, nv)
    sy = rng.uniform(-4, h + 4, nv)
    snap = rng.random(nv) < 0.3  # some corners exactly on sample centres
    sx[snap], sy[snap] = np.floor(sx[snap]) + 0.5, np.floor(sy[snap]) + 0.5
    depth = rng.uniform(1.0, 12.0, nv)
    tris = rng.integers(0, nv, size=(n_tri, 3))
    tris[: n_tri // 2] = np.arange(3 * (n_tri // 2)).reshape(-1, 3)  # distinct corners
    proj = raster.Projected(sx, sy, depth)
    fast = raster.rasterize(proj, tris, w, h, 0.5, 10.0, cull)
    assert raster.native() is not None
    os.environ["FBACONF_PURE_PYTHON"] = "1"
    try:
        ref = raster.rasterize(proj, tris, w, h, 0.5, 10.0, cull)
    finally:
        del os.environ["FBACONF_PURE_PYTHON"]
    a, b = _coverage_by_pixel(fast), _coverage_by_pixel(ref)
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    assert fast.n_skipped_near == ref.n_skipped_near


@needs_native
@pytest.mark.parametrize("shading,texture", [("gouraud", False), ("flat", False), ("gouraud", True)])
def test_native_images_equal_the_numpy_reference(monkeypatch, shading, texture):
    """Whole frames (scan conversion, Gouraud interpolation, box filter) byte for byte: the
    goldens do not depend on whether the extension was built."""
    case = next(c for s in load_suites() for c in s.cases if c.id == ("grid-limits-l1" if texture else "default-head"))
    state = animate(load_stream(case.input_path("fba")), scene=case.input_path("scene"))
    sc = Scenario.load(case.input_path("scenario")).with_(shading=shading, supersample=3)
    scene_dir = case.input_path("scene").parent
    fast = [Renderer(state, sc, scene_dir=scene_dir).render(k) for k in (0, state.n_frames - 1)]
    monkeypatch.setenv("FBACONF_PURE_PYTHON", "1")
    ref = [Renderer(state, sc, scene_dir=scene_dir).render(k) for k in (0, state.n_frames - 1)]
    for x, y in zip(fast, ref):
        assert x.tobytes() == y.tobytes()
