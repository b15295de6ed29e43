#!/usr/bin/env python3
"""glrender: an OpenGL renderer-under-test for fbaconf's image stage.

It is a *player's renderer*, not fbaconf's: the FAPs and the animated vertices come from
fbaconf's reference chain (bits -> FapFrames -> FaceState), so only the rendering is under
test. The rendering is OpenGL 3.3 core through moderngl (headless EGL; Mesa llvmpipe works):
its own GLSL shaders do the VRML97 / MPEG-4 lighting the way a fixed-function player does
(per-vertex Gouraud with a separate specular colour, flat shading per triangle in a geometry
shader, two-sided lighting with gl_FrontFacing, GL culling), textures are GL textures
(bilinear, repeat, no mipmaps, rows flipped on upload so t runs up), anti-aliasing is either
supersampling resolved by a box-filter pass or GL multisampling resolved by a framebuffer blit,
both in linear light (float32 targets), and a last pass encodes to 8-bit sRGB.

Nothing here calls fbaconf's rasteriser (rendering/raster.py, render.py) or its lighting:
the camera fit, the normals, the lighting, the texture decode and the sRGB encode are written
again from docs/rendering.md. Only the scenario *parser* (rendering/scenario.py: the TOML
file -> a Scenario) and the image writer library (OpenImageIO) are shared.

``--variant`` picks a faithful renderer or one with a realistic bug (see VARIANTS).

As a decoder (manifests/<variant>.toml)::

    glrender.py --variant msaa4 decode IN.fba [--scene S.bt] [--scenario SC.toml]
                --faps-out F.npz [--vertices-out V.npz] [--images-dir DIR]
    glrender.py decode-multi --out-dir DIR IN1.fba IN2.fba ...

From Python (benchmarks, tests)::

    from glrender import render_frames
    images = render_frames(state, scenario, "msaa4", scene_dir=...)   # list of uint8 sRGB [H, W, 3]

Exit codes: 0 done; 2 the stream/scene was rejected (fbaconf input error); 69 not supported
(this machine's GL cannot do the variant, e.g. msaa8 where GL_MAX_SAMPLES is 4, or no GL
context at all).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

FAITHFUL = ("ssaa2", "ssaa3", "ssaa4", "msaa4", "msaa4-centroid", "msaa8")
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
)
VARIANTS = FAITHFUL + WRONG
# The renderer the wrong variants start from (a faithful 4x MSAA player, centroid sampling).
BASE_WRONG = "msaa4-centroid"
MAX_LIGHTS = 8
EXIT_NOT_SUPPORTED = 69


class NotSupported(Exception):
    """The variant cannot run on this GL (exit 69)."""


# ----------------------------------------------------------------------------- GL context
_CTX = None


def gl_context():
    """One headless OpenGL 3.3+ context per process (EGL, e.g. Mesa llvmpipe)."""
    global _CTX
    if _CTX is None:
        import moderngl

        try:
            _CTX = moderngl.create_standalone_context(require=330, backend="egl")
        except Exception as e:  # noqa: BLE001 - any failure means no GL here
            raise NotSupported(f"no OpenGL 3.3 context (EGL): {e}") from None
    return _CTX


# ----------------------------------------------------------------------------- shaders
_LIGHTING = """
uniform vec3 eye;
uniform vec3 ambient;
uniform int n_lights;
uniform vec3 light_L[%(ML)d];     // unit vector towards the light (-direction)
uniform vec3 light_C[%(ML)d];     // colour x intensity
uniform bool spec_on;
uniform float ks;
uniform float expo;               // 128 x shininess

// VRML97 4.14: E = ambient + sum max(0, n.L) C ; S = sum [n.L > 0] ks max(0, n.H)^expo C
void vrml_light(vec3 n, vec3 p, out vec3 E, out vec3 S) {
    E = ambient;
    S = vec3(0.0);
    vec3 V = normalize(eye - p);
    for (int i = 0; i < n_lights; ++i) {
        float ndl = dot(n, light_L[i]);
        E += max(ndl, 0.0) * light_C[i];
        if (spec_on && ks > 0.0 && ndl > 0.0) {
            vec3 H = normalize(light_L[i] + V);
            float ndh = max(dot(n, H), 0.0);
            float s = expo > 0.0 ? pow(ndh, expo) : 1.0;
            S += ks * s * light_C[i];
        }
    }
}
""" % {"ML": MAX_LIGHTS}  # noqa: UP031 - GLSL has braces: % keeps them literal

# Gouraud: lit at the vertices, both sides, like fixed-function GL with
# GL_LIGHT_MODEL_TWO_SIDE and GL_SEPARATE_SPECULAR_COLOR: primary = albedo x E (E alone on
# textured parts, where the texture replaces the diffuse colour), secondary = S.
_GOURAUD_VS = """
#version 330
in vec3 in_pos;
in vec3 in_nrm;
in vec3 in_alb;
in vec2 in_uv;
uniform mat4 mvp;
uniform bool textured;
%(LIGHTING)s
INTERP out vec3 v_pf;
INTERP out vec3 v_sf;
INTERP out vec3 v_pb;
INTERP out vec3 v_sb;
INTERP out vec2 v_uv;
void main() {
    vec3 Ef, Sf, Eb, Sb;
    vrml_light(in_nrm, in_pos, Ef, Sf);
    vrml_light(-in_nrm, in_pos, Eb, Sb);
    v_pf = textured ? Ef : in_alb * Ef;
    v_pb = textured ? Eb : in_alb * Eb;
    v_sf = Sf;
    v_sb = Sb;
    v_uv = in_uv;
    gl_Position = mvp * vec4(in_pos, 1.0);
}
"""

_GOURAUD_FS = """
#version 330
INTERP in vec3 v_pf;
INTERP in vec3 v_sf;
INTERP in vec3 v_pb;
INTERP in vec3 v_sb;
INTERP in vec2 v_uv;
uniform bool textured;
uniform sampler2D tex;
out vec4 f_color;
void main() {
    vec3 p = gl_FrontFacing ? v_pf : v_pb;
    vec3 s = gl_FrontFacing ? v_sf : v_sb;
    if (textured) p *= texture(tex, v_uv).rgb;
    f_color = vec4(p + s, 1.0);
}
"""

# Flat: lit once per triangle at its centroid with its geometric normal (geometry shader);
# the albedo (vertex colour or texture) per sample.
_FLAT_VS = """
#version 330
in vec3 in_pos;
in vec3 in_alb;
in vec2 in_uv;
uniform mat4 mvp;
out vec3 g_pos;
out vec3 g_alb;
out vec2 g_uv;
void main() {
    g_pos = in_pos;
    g_alb = in_alb;
    g_uv = in_uv;
    gl_Position = mvp * vec4(in_pos, 1.0);
}
"""

_FLAT_GS = """
#version 330
layout(triangles) in;
layout(triangle_strip, max_vertices = 3) out;
in vec3 g_pos[];
in vec3 g_alb[];
in vec2 g_uv[];
%(LIGHTING)s
flat out vec3 v_Ef;
flat out vec3 v_Sf;
flat out vec3 v_Eb;
flat out vec3 v_Sb;
INTERP out vec3 v_alb;
INTERP out vec2 v_uv;
void main() {
    vec3 n = cross(g_pos[1] - g_pos[0], g_pos[2] - g_pos[0]);
    float len = length(n);
    n = len > 0.0 ? n / len : vec3(0.0);
    vec3 c = (g_pos[0] + g_pos[1] + g_pos[2]) / 3.0;
    vec3 Ef, Sf, Eb, Sb;
    vrml_light(n, c, Ef, Sf);
    vrml_light(-n, c, Eb, Sb);
    for (int i = 0; i < 3; ++i) {
        v_Ef = Ef; v_Sf = Sf; v_Eb = Eb; v_Sb = Sb;
        v_alb = g_alb[i];
        v_uv = g_uv[i];
        gl_Position = gl_in[i].gl_Position;
        EmitVertex();
    }
    EndPrimitive();
}
"""

_FLAT_FS = """
#version 330
flat in vec3 v_Ef;
flat in vec3 v_Sf;
flat in vec3 v_Eb;
flat in vec3 v_Sb;
INTERP in vec3 v_alb;
INTERP in vec2 v_uv;
uniform bool textured;
uniform sampler2D tex;
out vec4 f_color;
void main() {
    vec3 alb = textured ? texture(tex, v_uv).rgb : v_alb;
    vec3 E = gl_FrontFacing ? v_Ef : v_Eb;
    vec3 S = gl_FrontFacing ? v_Sf : v_Sb;
    f_color = vec4(alb * E + S, 1.0);
}
"""

_FULLSCREEN_VS = """
#version 330
void main() {
    vec2 p = vec2(float((gl_VertexID & 1) << 2) - 1.0, float((gl_VertexID & 2) << 1) - 1.0);
    gl_Position = vec4(p, 0.0, 1.0);
}
"""

# Resolve of the supersampled image: the N x N block of each pixel averaged in linear light.
_BOX_FS = """
#version 330
uniform sampler2D src;
uniform int n;
out vec4 f_color;
void main() {
    ivec2 base = ivec2(gl_FragCoord.xy) * n;
    vec3 acc = vec3(0.0);
    for (int j = 0; j < n; ++j)
        for (int i = 0; i < n; ++i)
            acc += texelFetch(src, base + ivec2(i, j), 0).rgb;
    f_color = vec4(acc / float(n * n), 1.0);
}
"""

# Output encoding: linear -> 8-bit code values (written as integral floats, read back exactly).
_ENCODE_FS = """
#version 330
uniform sampler2D src;
uniform int mode;   // 0: sRGB (IEC 61966-2-1); 1: pure 2.2 gamma; 2: sRGB applied twice
out vec4 f_color;
vec3 srgb(vec3 x) {
    vec3 lo = 12.92 * x;
    vec3 hi = 1.055 * pow(x, vec3(1.0 / 2.4)) - 0.055;
    return mix(hi, lo, lessThanEqual(x, vec3(0.0031308)));
}
void main() {
    vec3 x = clamp(texelFetch(src, ivec2(gl_FragCoord.xy), 0).rgb, 0.0, 1.0);
    vec3 e;
    if (mode == 1) e = pow(x, vec3(1.0 / 2.2));
    else if (mode == 2) e = srgb(srgb(x));
    else e = srgb(x);
    f_color = vec4(floor(e * 255.0 + 0.5), 1.0);
}
"""


def _src(template: str, centroid: bool) -> str:
    return template.replace("%(LIGHTING)s", _LIGHTING).replace("INTERP", "centroid" if centroid else "")


# ----------------------------------------------------------------------------- maths (own)
def srgb_decode(c: np.ndarray) -> np.ndarray:
    c = np.asarray(c, dtype=np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / math.sqrt(float(v @ v))


def camera_basis(eye, target, up):
    fwd = _unit(np.asarray(target, float) - np.asarray(eye, float))
    right = _unit(np.cross(fwd, np.asarray(up, float)))
    return right, np.cross(right, fwd), fwd


def fit_camera(points: np.ndarray, sc, fov_deg: float):
    """(eye, target, up, near, far) per docs/rendering.md "camera": look along ``direction`` at
    the centre of the points' bounding box from the nearest distance at which every box corner
    lies inside the view shrunk by ``margin``; near halfway between the eye and the nearest
    corner, far twice the farthest. A given position/look_at is used as it is."""
    cam = sc.camera
    if not cam.fit:
        return (
            np.asarray(cam.position, float),
            np.asarray(cam.look_at, float),
            np.asarray(cam.up, float),
            0.1 if cam.near is None else cam.near,
            1e5 if cam.far is None else cam.far,
        )
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    p = p[np.isfinite(p).all(axis=1)]
    lo, hi = (p.min(axis=0), p.max(axis=0)) if len(p) else (np.zeros(3), np.zeros(3))
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    if not np.any(half > 0):
        half = np.full(3, 0.5)
    right, up, fwd = camera_basis(centre - np.asarray(cam.direction, float), centre, cam.up)
    tv = math.tan(math.radians(fov_deg) / 2)
    th = tv * sc.width / sc.height
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float) * half
    x, y, z = corners @ right, corners @ up, corners @ fwd
    dist = max(0.0, float(np.max(cam.margin * np.abs(x) / th - z)), float(np.max(cam.margin * np.abs(y) / tv - z)))
    dist = max(dist, float(-z.min()) + 1e-6 * (float(z.max() - z.min()) + 1.0))
    eye = centre - dist * fwd
    return eye, centre, np.asarray(cam.up, float), (dist + float(z.min())) / 2, 2 * (dist + float(z.max()))


def view_projection(eye, target, up, near, far, fov_deg, width, height, shift_px=(0.0, 0.0)) -> np.ndarray:
    """The OpenGL clip matrix (column vectors, float64) of a perspective camera; ``shift_px``
    moves the image by that many pixels (right, down)."""
    right, tup, fwd = camera_basis(eye, target, up)
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = right, tup, -fwd
    view[:3, 3] = -view[:3, :3] @ np.asarray(eye, float)
    f = 1.0 / math.tan(math.radians(fov_deg) / 2)
    proj = np.zeros((4, 4))
    proj[0, 0] = f * height / width
    proj[1, 1] = f
    proj[2, 2] = (far + near) / (near - far)
    proj[2, 3] = 2 * far * near / (near - far)
    proj[3, 2] = -1.0
    # x_ndc += 2 dx / W, y_ndc -= 2 dy / H (clip = ndc * w, w = -z_eye)
    proj[0, 2] -= 2.0 * shift_px[0] / width
    proj[1, 2] += 2.0 * shift_px[1] / height
    return proj @ view


def vertex_normals(V: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (the sum of the corner triangles' cross products,
    normalised; zero where the sum is zero)."""
    fn = np.cross(V[tris[:, 1]] - V[tris[:, 0]], V[tris[:, 2]] - V[tris[:, 0]])
    acc = np.zeros_like(V)
    for c in range(3):
        np.add.at(acc, tris[:, c], fn)
    n = np.linalg.norm(acc, axis=1, keepdims=True)
    return np.where(n > 0, acc / np.where(n > 0, n, 1.0), 0.0)


def load_texture_linear(path: Path) -> np.ndarray:
    """A texture file as linear float32 RGB [h, w, 3], top row first (integer formats are
    sRGB-encoded, float formats linear)."""
    import OpenImageIO as oiio

    buf = oiio.ImageBuf(str(path))
    px = buf.get_pixels(oiio.FLOAT)
    if buf.has_error or px is None:
        raise OSError(f"cannot read texture {path}: {buf.geterror()}")
    px = np.asarray(px, dtype=np.float64)
    if px.ndim == 2:
        px = px[:, :, None]
    rgb = px[:, :, :3] if px.shape[2] >= 3 else np.repeat(px[:, :, :1], 3, axis=2)
    if str(buf.spec().format) not in ("half", "float", "double"):
        rgb = srgb_decode(rgb)
    return np.ascontiguousarray(rgb, dtype=np.float32)


# ----------------------------------------------------------------------------- renderer
class GLRenderer:
    """One FaceState under one scenario, rendered by the variant ``variant``."""

    def __init__(self, state, scenario, variant: str = "msaa4", *, scene_dir=None, ctx=None) -> None:
        import moderngl

        if variant not in VARIANTS:
            raise ValueError(f"unknown variant {variant!r} (one of {', '.join(VARIANTS)})")
        self.mgl = moderngl
        self.ctx = ctx or gl_context()
        self.state, self.variant = state, variant
        self.scene_dir = Path(scene_dir) if scene_dir is not None else None
        sc = scenario
        # --- what the variant changes (a wrong variant starts from the plain 4x MSAA player)
        aa = variant if variant in FAITHFUL else BASE_WRONG
        self.ss = int(aa[4:]) if aa.startswith("ssaa") else 1
        self.samples = int(aa[4:5]) if aa.startswith("msaa") else 0
        self.centroid = aa.endswith("centroid")
        if self.samples > self.ctx.max_samples:
            raise NotSupported(
                f"{variant}: this GL supports at most {self.ctx.max_samples} samples "
                f"(GL_MAX_SAMPLES; {self.ctx.info.get('GL_RENDERER')})"
            )
        lights = list(sc.lights)
        if variant == "lights-mirrored":  # a handedness slip: light x negated
            lights = [(-lt.direction[0], lt.direction[1], lt.direction[2], lt) for lt in lights]
        else:
            lights = [(*lt.direction, lt) for lt in lights]
        if variant == "light-missing" and lights:  # an off-by-one in the light loop
            lights = lights[:-1]
        if len(lights) > MAX_LIGHTS:
            raise NotSupported(f"more than {MAX_LIGHTS} lights")
        self.light_L = np.zeros((MAX_LIGHTS, 3), np.float32)
        self.light_C = np.zeros((MAX_LIGHTS, 3), np.float32)
        for i, (dx, dy, dz, lt) in enumerate(lights):
            self.light_L[i] = -_unit((dx, dy, dz))
            self.light_C[i] = np.asarray(lt.color, float) * lt.intensity
        self.n_lights = len(lights)
        self.ambient = np.asarray(sc.ambient_color, float) * sc.ambient_intensity
        self.spec_on = sc.specular and variant != "specular-off"
        self.shading = sc.shading
        if variant == "wrong-shading":
            self.shading = "flat" if sc.shading == "gouraud" else "gouraud"
        self.cull = sc.cull_backfaces or variant == "cull-backfaces"
        self.fov = sc.camera.fov_deg * (1.1 if variant == "fov-wrong" else 1.0)
        self.shift = (1.0, 0.0) if variant == "camera-shift" else (0.0, 0.0)
        self.encode_mode = {"gamma22": 1, "gamma-twice": 2}.get(variant, 0)
        self.W, self.H = sc.width, sc.height
        self.background = srgb_decode(np.asarray(sc.background, float))
        self.scenario = sc

        # --- camera (from frame 0, or every frame)
        V = state.vertices
        pts = V.reshape(-1, 3) if (sc.camera.fit and sc.camera.fit_to == "all") else V[0]
        self.eye, self.target, self.up, self.near, self.far = fit_camera(pts, sc, self.fov)
        self.mvp = view_projection(
            self.eye, self.target, self.up, self.near, self.far, self.fov, self.W, self.H, self.shift
        )

        # --- static mesh data
        n_v = V.shape[1]
        alb = np.zeros((n_v, 3), np.float32)
        uv = np.zeros((n_v, 2), np.float32)
        self.parts = []  # (first index, index count, ks, expo, texture or None)
        tris_all = []
        textures: dict[str, object] = {}
        for p in state.parts:
            rows = slice(p.first_vertex, p.first_vertex + p.vertex_count)
            alb[rows] = np.asarray(p.vertex_colors if p.vertex_colors is not None else p.color, np.float32)
            tex = None
            if p.texture:
                uv[rows] = np.asarray(p.texcoords, np.float32)
                tex = textures.get(p.texture) or self._texture(p.texture)
                textures[p.texture] = tex
            t = np.asarray(p.triangles, np.int64).reshape(-1, 3) + p.first_vertex
            first = sum(len(x) for x in tris_all) * 3
            tris_all.append(t)
            self.parts.append((first, t.shape[0] * 3, float(p.specular), 128.0 * float(p.shininess), tex))
        self.tris = np.concatenate(tris_all) if tris_all else np.zeros((0, 3), np.int64)
        ctx = self.ctx
        self.vbo_pos = ctx.buffer(reserve=max(n_v, 1) * 12, dynamic=True)
        self.vbo_nrm = ctx.buffer(reserve=max(n_v, 1) * 12, dynamic=True)
        self.vbo_alb = ctx.buffer(alb.tobytes() or b"\0" * 12)
        self.vbo_uv = ctx.buffer(uv.tobytes() or b"\0" * 8)
        self.ibo = ctx.buffer(self.tris.astype(np.uint32).tobytes() or b"\0" * 12)
        if self.shading == "gouraud":
            self.prog = ctx.program(
                vertex_shader=_src(_GOURAUD_VS, self.centroid), fragment_shader=_src(_GOURAUD_FS, self.centroid)
            )
        else:
            self.prog = ctx.program(
                vertex_shader=_src(_FLAT_VS, self.centroid),
                geometry_shader=_src(_FLAT_GS, self.centroid),
                fragment_shader=_src(_FLAT_FS, self.centroid),
            )
        attrs = [(self.vbo_pos, "3f", "in_pos"), (self.vbo_alb, "3f", "in_alb"), (self.vbo_uv, "2f", "in_uv")]
        if self.shading == "gouraud":
            attrs.append((self.vbo_nrm, "3f", "in_nrm"))
        attrs = [a for a in attrs if a[2] in self.prog]
        self.vao = ctx.vertex_array(self.prog, attrs, index_buffer=self.ibo, index_element_size=4)
        self._set("eye", tuple(float(x) for x in self.eye))
        self._set("ambient", tuple(float(x) for x in self.ambient))
        self._set("n_lights", self.n_lights)
        if "light_L" in self.prog:
            self.prog["light_L"].write(self.light_L.tobytes())
            self.prog["light_C"].write(self.light_C.tobytes())
        self._set("spec_on", bool(self.spec_on))
        self._set("mvp", tuple(self.mvp.T.astype(np.float32).reshape(-1)))  # column-major
        self._set("tex", 0)

        # --- framebuffers: scene (N x supersampled, or multisampled) -> linear -> encoded
        W, H = self.W, self.H
        sw, sh = W * self.ss, H * self.ss
        if self.samples:
            self.scene_color = ctx.renderbuffer((W, H), 4, samples=self.samples, dtype="f4")
            self.scene_depth = ctx.depth_renderbuffer((W, H), samples=self.samples)
        else:
            self.scene_color = ctx.texture((sw, sh), 4, dtype="f4")
            self.scene_color.filter = (moderngl.NEAREST, moderngl.NEAREST)
            self.scene_depth = ctx.depth_renderbuffer((sw, sh))
        self.scene_fbo = ctx.framebuffer(color_attachments=[self.scene_color], depth_attachment=self.scene_depth)
        self.linear_tex = ctx.texture((W, H), 4, dtype="f4")
        self.linear_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.linear_fbo = ctx.framebuffer(color_attachments=[self.linear_tex])
        self.code_tex = ctx.texture((W, H), 4, dtype="f4")
        self.code_fbo = ctx.framebuffer(color_attachments=[self.code_tex])
        self.box_prog = ctx.program(vertex_shader=_FULLSCREEN_VS, fragment_shader=_BOX_FS)
        self.enc_prog = ctx.program(vertex_shader=_FULLSCREEN_VS, fragment_shader=_ENCODE_FS)
        self.enc_prog["mode"] = self.encode_mode
        self.box_vao = ctx.vertex_array(self.box_prog, [])
        self.enc_vao = ctx.vertex_array(self.enc_prog, [])

    # ------------------------------------------------------------------ helpers
    def _set(self, name, value) -> None:
        if name in self.prog:
            self.prog[name].value = value

    def _texture(self, name: str):
        p = Path(name)
        if not p.is_absolute() and self.scene_dir is not None:
            p = self.scene_dir / p
        rgb = load_texture_linear(p)
        if self.variant != "texture-flipped":
            rgb = rgb[::-1]  # GL's row 0 is t = 0 (the bottom); image files start at the top
        tex = self.ctx.texture((rgb.shape[1], rgb.shape[0]), 3, np.ascontiguousarray(rgb).tobytes(), dtype="f4")
        tex.filter = (self.mgl.LINEAR, self.mgl.LINEAR)  # bilinear, no mipmaps
        clamp = self.variant == "texture-clamp"
        tex.repeat_x = tex.repeat_y = not clamp
        return tex

    def _positions(self, k: int) -> np.ndarray:
        V = np.array(self.state.vertices[k], dtype=np.float64)
        if not np.all(np.isfinite(V)):
            raise ValueError(f"frame {k}: non-finite vertex position")
        if self.variant == "region-displaced" and V.shape[0]:
            # the jaw / lower-lip region (the lowest tenth of the face) slips 1.5 px sideways:
            # a region offset applied in the wrong space
            sel = V[:, 1] <= np.quantile(V[:, 1], 0.1)
            right, _, fwd = camera_basis(self.eye, self.target, self.up)
            depth = float((V[sel].mean(axis=0) - self.eye) @ fwd)
            per_px = 2.0 * depth * math.tan(math.radians(self.fov) / 2) / self.H
            V[sel] += 1.5 * per_px * right
        return V

    # ------------------------------------------------------------------ rendering
    def _draw_scene(self, k: int) -> None:
        ctx, mgl = self.ctx, self.mgl
        V = self._positions(k)
        self.vbo_pos.write(V.astype(np.float32).tobytes())
        if self.shading == "gouraud" and self.tris.size:
            self.vbo_nrm.write(vertex_normals(V, self.tris).astype(np.float32).tobytes())
        self.scene_fbo.use()
        self.scene_fbo.viewport = (0, 0, self.W * self.ss, self.H * self.ss)
        bg = tuple(float(x) for x in self.background)
        self.scene_fbo.clear(*bg, 1.0, depth=1.0)
        ctx.enable(mgl.DEPTH_TEST)
        ctx.depth_func = "<"
        ctx.front_face = "ccw"
        if self.cull:
            ctx.enable(mgl.CULL_FACE)
            ctx.cull_face = "back"
        else:
            ctx.disable(mgl.CULL_FACE)
        for first, count, ks, expo, tex in self.parts:
            if count == 0:
                continue
            self._set("ks", ks)
            self._set("expo", expo)
            self._set("textured", tex is not None)
            if tex is not None:
                tex.use(location=0)
            self.vao.render(mgl.TRIANGLES, vertices=count, first=first)
        ctx.disable(mgl.DEPTH_TEST | mgl.CULL_FACE)

    def _resolve(self) -> None:
        """The scene resolved to one linear value per pixel in linear_tex."""
        if self.samples:
            self.ctx.copy_framebuffer(self.linear_fbo, self.scene_fbo)  # MSAA resolve (blit)
        else:
            self.linear_fbo.use()
            self.linear_fbo.viewport = (0, 0, self.W, self.H)
            self.scene_color.use(location=0)
            self.box_prog["src"] = 0
            self.box_prog["n"] = self.ss
            self.box_vao.render(self.mgl.TRIANGLES, vertices=3)

    def render_linear(self, k: int) -> np.ndarray:
        """Frame k, linear float32 [H, W, 3], top row first."""
        self._draw_scene(k)
        self._resolve()
        raw = self.linear_fbo.read(components=4, dtype="f4")
        return np.frombuffer(raw, np.float32).reshape(self.H, self.W, 4)[::-1, :, :3].copy()

    def render_srgb8(self, k: int) -> np.ndarray:
        """Frame k as the variant writes it: uint8 [H, W, 3] sRGB, top row first."""
        self._draw_scene(k)
        self._resolve()
        self.code_fbo.use()
        self.code_fbo.viewport = (0, 0, self.W, self.H)
        self.linear_tex.use(location=0)
        self.enc_prog["src"] = 0
        self.enc_vao.render(self.mgl.TRIANGLES, vertices=3)
        raw = self.code_fbo.read(components=4, dtype="f4")
        codes = np.frombuffer(raw, np.float32).reshape(self.H, self.W, 4)[::-1, :, :3]
        return np.clip(codes, 0, 255).astype(np.uint8)

    def release(self) -> None:
        for name in (
            "vao",
            "box_vao",
            "enc_vao",
            "prog",
            "box_prog",
            "enc_prog",
            "vbo_pos",
            "vbo_nrm",
            "vbo_alb",
            "vbo_uv",
            "ibo",
            "scene_fbo",
            "scene_color",
            "scene_depth",
            "linear_fbo",
            "linear_tex",
            "code_fbo",
            "code_tex",
        ):
            obj = getattr(self, name, None)
            if obj is not None:
                obj.release()
        for *_, tex in self.parts:
            if tex is not None:
                try:
                    tex.release()
                except Exception:  # noqa: BLE001, S110 - shared between parts: released once
                    pass


def render_frames(face_states, scenario, variant: str = "msaa4", *, scene_dir=None, frames=None) -> list[np.ndarray]:
    """The scenario's frames (or ``frames``) of a FaceState as uint8 sRGB [H, W, 3] images,
    rendered by ``variant``. No file I/O."""
    r = GLRenderer(face_states, scenario, variant, scene_dir=scene_dir)
    try:
        idx = scenario.frame_indices(face_states.n_frames) if frames is None else list(frames)
        return [r.render_srgb8(k) for k in idx]
    finally:
        r.release()


def write_png(path: Path, px: np.ndarray) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(px.shape[1], px.shape[0], 3, oiio.UINT8)):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    ok = out.write_image(np.ascontiguousarray(px))
    out.close()
    if not ok:
        raise OSError(f"cannot write {path}: {out.geterror()}")


def write_exr(path: Path, px: np.ndarray) -> None:
    import OpenImageIO as oiio

    out = oiio.ImageOutput.create(str(path))
    if out is None or not out.open(str(path), oiio.ImageSpec(px.shape[1], px.shape[0], 3, oiio.FLOAT)):
        raise OSError(f"cannot write {path}: {oiio.geterror()}")
    out.write_image(np.ascontiguousarray(px, dtype=np.float32))
    out.close()


# ----------------------------------------------------------------------------- decoder CLI
def decode(a) -> None:
    from fbaconf.bitstreams.fapio import save_faps
    from fbaconf.reference.pipeline import load_stream, state_of

    frames = load_stream(a.input)
    if a.faps_out is not None:
        save_faps(state_of(frames) if a.input.suffix.lower() == ".fap" else frames, a.faps_out)
    if a.vertices_out is None and a.images_dir is None:
        return
    from fbaconf.animation.engine import animate
    from fbaconf.animation.stateio import save_npz

    state = animate(frames, scene=a.scene)
    if a.vertices_out is not None:
        save_npz(state, a.vertices_out)
    if a.images_dir is None:
        return
    from fbaconf.rendering.scenario import Scenario

    sc = Scenario.load(a.scenario) if a.scenario is not None else Scenario.default()
    scene_dir = Path(a.scene).resolve().parent if a.scene else None
    a.images_dir.mkdir(parents=True, exist_ok=True)
    r = GLRenderer(state, sc, a.variant, scene_dir=scene_dir)
    for k in sc.frame_indices(state.n_frames):
        if sc.format == "exr":
            write_exr(a.images_dir / f"frame_{k:05d}.exr", r.render_linear(k))
        else:
            write_png(a.images_dir / f"frame_{k:05d}.png", r.render_srgb8(k))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="glrender", description=__doc__.split("\n\n")[0])
    ap.add_argument("--variant", default="msaa4", choices=VARIANTS)
    sub = ap.add_subparsers(dest="cmd", required=True)
    d = sub.add_parser("decode")
    d.add_argument("input", type=Path)
    d.add_argument("--scene", type=Path)
    d.add_argument("--scenario", type=Path)
    d.add_argument("--faps-out", type=Path)
    d.add_argument("--vertices-out", type=Path)
    d.add_argument("--images-dir", type=Path)
    m = sub.add_parser("decode-multi")
    m.add_argument("--out-dir", type=Path, required=True)
    m.add_argument("--format", choices=("npz", "fap"), default="npz")
    m.add_argument("inputs", type=Path, nargs="+")
    a = ap.parse_args(argv)
    from fbaconf.errors import FbaconfInputError

    try:
        if a.cmd == "decode":
            decode(a)
        else:
            from fbaconf.reference.pipeline import multi_outputs

            multi_outputs(a.inputs, a.out_dir, a.format)
    except FbaconfInputError as e:
        print(f"glrender: error: {e}", file=sys.stderr)
        return 2
    except NotSupported as e:
        print(f"glrender: not supported: {e}", file=sys.stderr)
        return EXIT_NOT_SUPPORTED
    return 0


if __name__ == "__main__":
    sys.exit(main())
