"""Render FaceStates to images: the reference terminal's last stage.

``render_frame(state, k, scenario)``   -> float64[H, W, 3] linear RGB (not clipped; values
                                         above 1 are possible when lights add up past 1)
``render_frames(state, scenario, out_dir)`` -> [out_dir/frame_00000.png, ...] (one image per
                                         rendered frame, named by the frame's index in
                                         the FaceState; ``.exr`` when format = "exr")
``Renderer(state, scenario)``           prepares the mesh once; ``.render(k)`` per frame.

Relative texture paths are resolved against ``scene_dir`` (the scene file's folder), or
the current directory when it is None.

Bad geometry is reported, never drawn as NaN: a non-finite vertex position (in a frame
being rendered, or in frame 0 which places the fitted camera — every frame with
``fit_to = "all"``) raises
:class:`GeometryError` naming the frame, part and vertex; so do triangle indices outside
their part, vertex colours / texcoords of the wrong shape or non-finite, and a texture
without texcoords. Near-plane and zero-area handling: see :mod:`.raster`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fbaconf.animation.facestate import FaceState

from . import raster
from .errors import GeometryError, TextureError
from .images import read_texture, srgb_to_linear, write_image
from .scenario import Scenario


class Renderer:
    """A FaceState prepared for rendering under one scenario."""

    def __init__(self, state: FaceState, scenario: Scenario, *, scene_dir=None) -> None:
        self.state = state
        self.scenario = scenario
        self.scene_dir = Path(scene_dir) if scene_dir is not None else None
        n_v = state.vertices.shape[1]
        tris, tri_part = [], []
        albedo = np.empty((n_v, 3), dtype=np.float64)
        ks = np.zeros(n_v, dtype=np.float64)
        expo = np.zeros(n_v, dtype=np.float64)
        uv = np.zeros((n_v, 2), dtype=np.float64)
        self.textures: dict[int, np.ndarray] = {}
        self._texture_cache: dict[Path, np.ndarray] = {}
        ks_part, expo_part = [], []
        for pi, p in enumerate(state.parts):
            t = np.asarray(p.triangles, dtype=np.int64).reshape(-1, 3)
            if t.size and (t.min() < 0 or t.max() >= p.vertex_count):
                bad = int(np.flatnonzero(np.any((t < 0) | (t >= p.vertex_count), axis=1))[0])
                raise GeometryError(
                    f"triangle {bad} {t[bad].tolist()} indexes outside the part's {p.vertex_count} vertices",
                    part=p.name,
                    rule="geometry-index",
                )
            tris.append(t + p.first_vertex)
            tri_part.append(np.full(t.shape[0], pi, dtype=np.int64))
            rows = slice(p.first_vertex, p.first_vertex + p.vertex_count)
            if p.vertex_colors is not None:
                vc = np.asarray(p.vertex_colors, dtype=np.float64)
                if vc.shape != (p.vertex_count, 3) or not np.all(np.isfinite(vc)):
                    raise GeometryError(
                        f"vertex_colors must be finite float[{p.vertex_count}, 3], got shape {vc.shape}",
                        part=p.name,
                        rule="geometry-colors",
                    )
                albedo[rows] = vc
            else:
                col = np.asarray(p.color, dtype=np.float64).reshape(3)
                if not np.all(np.isfinite(col)):
                    raise GeometryError("colour is not finite", part=p.name, rule="geometry-colors")
                albedo[rows] = col
            spec, shin = float(p.specular), float(p.shininess)
            if not (math.isfinite(spec) and spec >= 0.0 and math.isfinite(shin) and shin >= 0.0):
                raise GeometryError(
                    f"specular ({p.specular}) and shininess ({p.shininess}) must be finite and >= 0",
                    part=p.name,
                    rule="geometry-material",
                )
            ks[rows] = spec
            expo[rows] = 128.0 * shin
            ks_part.append(spec)
            expo_part.append(128.0 * shin)
            if p.texture:
                if p.texcoords is None:
                    raise GeometryError("part has a texture but no texcoords", part=p.name, rule="geometry-texcoords")
                tc = np.asarray(p.texcoords, dtype=np.float64)
                if tc.shape != (p.vertex_count, 2) or not np.all(np.isfinite(tc)):
                    raise GeometryError(
                        f"texcoords must be finite float[{p.vertex_count}, 2], got shape {tc.shape}",
                        part=p.name,
                        rule="geometry-texcoords",
                    )
                uv[rows] = tc
                self.textures[pi] = self._load_texture(p.texture, p.name)
        self.tris = np.concatenate(tris) if tris else np.zeros((0, 3), np.int64)
        self.tri_part = np.concatenate(tri_part) if tri_part else np.zeros(0, np.int64)
        self.albedo, self.ks, self.exponent, self.uv = albedo, ks, expo, uv
        self.vertex_part = np.zeros(n_v, dtype=np.int64)
        for pi, p in enumerate(state.parts):
            self.vertex_part[p.first_vertex : p.first_vertex + p.vertex_count] = pi
        self.textured_vertex = np.isin(self.vertex_part, np.array(sorted(self.textures), dtype=np.int64))
        self.ks_tri = np.asarray(ks_part, dtype=np.float64)[self.tri_part] if ks_part else np.zeros(0)
        self.exponent_tri = np.asarray(expo_part, dtype=np.float64)[self.tri_part] if expo_part else np.zeros(0)

        sc = scenario
        if state.n_frames > 0:
            if sc.camera.fit and sc.camera.fit_to == "all":
                for k in range(state.n_frames):
                    self.check_frame(k)
                self.camera = sc.resolve_camera(state.vertices.reshape(-1, 3))
            else:
                self.check_frame(0)
                self.camera = sc.resolve_camera(state.vertices[0])
        else:
            self.camera = sc.resolve_camera(np.zeros((0, 3)))
        if sc.lights:
            dirs = np.array([lt.direction for lt in sc.lights], dtype=np.float64)
            cols = np.array([[c * lt.intensity for c in lt.color] for lt in sc.lights], dtype=np.float64)
        else:
            dirs = np.zeros((0, 3))
            cols = np.zeros((0, 3))
        amb = np.array(sc.ambient_color, dtype=np.float64) * sc.ambient_intensity
        self.lights = raster.LightSet(dirs, cols, amb, specular=sc.specular)
        self.background = srgb_to_linear(np.array(sc.background, dtype=np.float64))
        self.skipped_near: dict[int, int] = {}
        self.albedo_planes = np.ascontiguousarray(self.albedo.T)
        self._scratch: dict[str, np.ndarray] = {}

    # ------------------------------------------------------------------ helpers
    def _load_texture(self, tex: str, part: str) -> np.ndarray:
        p = Path(tex)
        if not p.is_absolute() and self.scene_dir is not None:
            p = self.scene_dir / p
        if p in self._texture_cache:
            return self._texture_cache[p]
        try:
            img = read_texture(p)
        except TextureError as e:
            raise TextureError(f"part '{part}': {e.message}", file=e.file) from None
        if img.shape[0] == 0 or img.shape[1] == 0 or not np.all(np.isfinite(img)):
            raise TextureError(f"part '{part}': texture is empty or has non-finite texels", file=str(p))
        self._texture_cache[p] = img
        return img

    def check_frame(self, k: int) -> np.ndarray:
        v = self.state.vertices[k]
        bad = ~np.all(np.isfinite(v), axis=1)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            pi = int(self.vertex_part[i]) if self.state.parts else 0
            p = self.state.parts[pi]
            raise GeometryError(
                f"vertex position is not finite: {v[i].tolist()}",
                part=p.name,
                vertex=i - p.first_vertex,
                frame=k,
                rule="geometry-nonfinite",
            )
        return v

    def _texture_samples(self, cov: raster.Coverage) -> tuple[np.ndarray, np.ndarray]:
        """(sample indices into the coverage, their bilinear texture colours float64[m, 3])
        for all samples on textured parts, parts in order."""
        part_f = self.tri_part[cov.tri]
        idx, cols = [], []
        for pi, tex in self.textures.items():
            m = np.flatnonzero(part_f == pi)
            if m.size:
                U = self.uv
                uv = cov.b0[m, None] * U[cov.v0[m]] + cov.b1[m, None] * U[cov.v1[m]] + cov.b2[m, None] * U[cov.v2[m]]
                idx.append(m)
                cols.append(raster.sample_bilinear_repeat(tex, uv))
        if not idx:
            return np.zeros(0, np.int64), np.zeros((0, 3))
        return np.concatenate(idx), np.concatenate(cols)

    # ------------------------------------------------------------------ rendering
    def _planes(self, size: int) -> np.ndarray:
        """A reused float64[3, size] buffer (avoids page-faulting a fresh image per frame)."""
        buf = self._scratch.get("planes")
        if buf is None or buf.shape[1] != size:
            buf = self._scratch["planes"] = np.empty((3, size), dtype=np.float64)
        for c in range(3):
            buf[c].fill(self.background[c])
        return buf

    def render_planes(self, k: int) -> np.ndarray:
        """Linear float64[3, H*N, W*N] (channel planes) at the supersampled resolution.
        The array is a buffer reused by the next call."""
        sc = self.scenario
        n = sc.supersample
        W, H = sc.width * n, sc.height * n
        if not 0 <= k < self.state.n_frames:
            raise IndexError(f"frame {k} out of range (0 .. {self.state.n_frames - 1})")
        V = self.check_frame(k)
        img = self._planes(H * W)
        if self.tris.shape[0] == 0:
            return img.reshape(3, H, W)
        cam = self.camera
        proj = raster.project(V, cam, W, H)
        cov = raster.rasterize(proj, self.tris, W, H, cam.near, cam.far, sc.cull_backfaces, scratch=self._scratch)
        self.skipped_near[k] = cov.n_skipped_near
        if cov.pix.size == 0:
            return img.reshape(3, H, W)
        eye = np.asarray(cam.position, dtype=np.float64)
        textured = bool(self.textures) and bool(self.textured_vertex.any())
        fn = raster.face_normals_unnormalised(V, self.tris)
        b0, b1, b2, pix = cov.b0, cov.b1, cov.b2, cov.pix
        if sc.shading == "flat":
            # Per triangle: E, S with the normal facing the viewer; albedo per sample.
            nrm = raster.normalize_rows(fn)
            t = self.tris
            cen = (V[t[:, 0]] + V[t[:, 1]] + V[t[:, 2]]) / 3.0
            Ef, Sf = raster.light(nrm, cen, eye, self.lights, self.ks_tri, self.exponent_tri)
            Eb, Sb = raster.light(-nrm, cen, eye, self.lights, self.ks_tri, self.exponent_tri)
            side = np.where(cov.front, cov.tri, cov.tri + t.shape[0])
            Et = np.ascontiguousarray(np.concatenate([Ef, Eb]).T)
            St = np.ascontiguousarray(np.concatenate([Sf, Sb]).T)
            At = self.albedo_planes
            tex = self._texture_samples(cov) if textured else None
            for c in range(3):
                a = At[c]
                alb = b0 * a[cov.v0] + b1 * a[cov.v1] + b2 * a[cov.v2]
                if tex is not None:
                    alb[tex[0]] = tex[1][:, c]
                img[c][pix] = alb * Et[c][side] + St[c][side]
        else:
            # Gouraud: per vertex (both sides) the lit colour albedo*E + S, interpolated; for
            # textured parts E and S are interpolated and the texture sample modulates E.
            vn = raster.vertex_normals(V, self.tris, fn)
            Ef, Sf = raster.light(vn, V, eye, self.lights, self.ks, self.exponent)
            Eb, Sb = raster.light(-vn, V, eye, self.lights, self.ks, self.exponent)
            tv = self.textured_vertex[:, None]
            Ff = np.where(tv, Ef, self.albedo * Ef + Sf)
            Fb = np.where(tv, Eb, self.albedo * Eb + Sb)
            nv = V.shape[0]
            Ft = np.ascontiguousarray(np.concatenate([Ff, Fb]).T)  # [3, 2 nv]: front then back
            off = np.where(cov.front, 0, nv)
            i0, i1, i2 = cov.v0 + off, cov.v1 + off, cov.v2 + off
            tex = None
            if textured:
                St = np.ascontiguousarray(np.concatenate([Sf, Sb]).T)
                tex = self._texture_samples(cov)
            fast = raster.native()
            if fast is not None:  # the same sums in C (rendering/_fastraster.c), then the textured samples
                fast.interp_scatter(Ft, i0, i1, i2, b0, b1, b2, pix, img)
                if tex is not None:
                    m, ts = tex
                    for c in range(3):
                        f, s = Ft[c], St[c]
                        col = b0[m] * f[i0[m]] + b1[m] * f[i1[m]] + b2[m] * f[i2[m]]
                        img[c][pix[m]] = ts[:, c] * col + (b0[m] * s[i0[m]] + b1[m] * s[i1[m]] + b2[m] * s[i2[m]])
                return img.reshape(3, H, W)
            for c in range(3):
                f = Ft[c]
                col = b0 * f[i0] + b1 * f[i1] + b2 * f[i2]
                if tex is not None:
                    m, ts = tex
                    s = St[c]
                    col[m] = ts[:, c] * col[m] + (b0[m] * s[i0[m]] + b1[m] * s[i1[m]] + b2[m] * s[i2[m]])
                img[c][pix] = col
        return img.reshape(3, H, W)

    def render(self, k: int) -> np.ndarray:
        """Linear float64[H, W, 3] of frame k (box-filtered down from the supersampled grid)."""
        planes = raster.box_downsample_planes(self.render_planes(k), self.scenario.supersample)
        out = np.ascontiguousarray(planes.transpose(1, 2, 0))
        if not np.all(np.isfinite(out)):  # pragma: no cover - guarded above; a bug if reached
            raise RuntimeError(f"internal error: non-finite pixel in frame {k}")
        return out

    def frame_path(self, out_dir, k: int) -> Path:
        return Path(out_dir) / f"frame_{k:05d}.{self.scenario.format}"

    def write(self, k: int, out_dir) -> Path:
        return write_image(self.frame_path(out_dir, k), self.render(k), self.scenario.format)


def render_frame(state: FaceState, k: int, scenario: Scenario, *, scene_dir=None) -> np.ndarray:
    """Frame k of ``state`` as linear float64[H, W, 3]."""
    return Renderer(state, scenario, scene_dir=scene_dir).render(k)


def render_frames(state: FaceState, scenario: Scenario, out_dir, *, scene_dir=None) -> list[Path]:
    """Render the scenario's frames (all by default) to ``out_dir/frame_NNNNN.png|exr``."""
    idx = scenario.frame_indices(state.n_frames)
    r = Renderer(state, scenario, scene_dir=scene_dir)
    for k in idx:  # validate every frame before writing any image
        r.check_frame(k)
    return [r.write(k, out_dir) for k in idx]
