"""The reference software rasteriser: pure numpy, float64, deterministic.

Everything here is a fixed sequence of element-wise numpy operations (no BLAS, no
threads, no reductions whose order depends on memory layout), so the same inputs give
bit-identical outputs run to run on the same machine.

Conventions (all normative for fbaconf's golden images)
-------------------------------------------------------
* World space is VRML's: y up, +z towards the viewer, right-handed.
* Camera: ``forward = normalize(look_at - position)``, ``right = normalize(forward x up)``,
  ``true_up = right x forward``. ``fov_deg`` is the *vertical* field of view. A point at
  view depth ``d = (p - eye) . forward`` projects to
  ``sx = W/2 + f * xc / d``, ``sy = H/2 - f * yc / d`` with ``f = (H/2) / tan(fov/2)``;
  screen x grows right, y grows down, pixel ``(i, j)`` covers ``[i, i+1) x [j, j+1)`` and
  is sampled at its centre ``(i + 0.5, j + 0.5)``.
* Screen positions are snapped to 1/256 pixel (round half up) and coverage is decided in
  exact int64 arithmetic with edge functions; samples exactly on an edge belong to one
  side only (an edge a->b owns its samples when ``dy > 0`` or ``dy == 0 and dx > 0``), so
  meshes are watertight and no pixel is drawn twice by adjacent triangles.
* Clipping (defined behaviour, not an error): a triangle with any vertex nearer than the
  near plane (``d < near``, which includes vertices behind the eye) is *skipped* whole;
  so is one with a vertex projecting farther than 2**20 pixels from the image centre.
  Fragments farther than the far plane are discarded per sample. Zero-area triangles
  (in screen space after snapping) cover nothing.
* Depth test: the fragment with the largest interpolated ``1/d`` (nearest) wins; exact
  ties go to the triangle drawn first (lowest global triangle index, parts in order).
* Faces are two-sided by default: a back-facing triangle (CW on screen; CCW is front, as
  in VRML) is drawn and lit with its normals flipped. ``cull_backfaces`` drops them.
* Attributes are interpolated perspective-correctly (barycentrics weighted by ``1/d``).
* Normals: per frame, from the animated mesh. Flat: the triangle's geometric normal.
  Gouraud: per-vertex normal = sum of the (area-weighted) cross products of the
  triangles using the vertex, normalised; a zero-length sum gives a zero normal
  (ambient light only).
* Lighting in linear RGB: ``colour = albedo * (ambient + sum_l max(0, n.L_l) C_l)
  + sum_l [n.L_l > 0] k_s max(0, n.H_l)^(128 shininess) C_l`` with ``L_l = -direction_l``
  (VRML DirectionalLight), ``C_l = color_l * intensity_l``, ``H = normalize(L + V)``,
  ``V`` towards the eye (from the vertex, or the centroid for flat). Gouraud evaluates
  the lit colour ``albedo * E + S`` at the vertices (albedo = part colour or vertex
  colour) and interpolates it; on textured parts it interpolates ``E`` and ``S`` and
  multiplies ``E`` by the texture sample per sample (VRML: the RGB texture replaces the
  diffuse colour). Flat evaluates ``E`` and ``S`` once per triangle at its centroid and
  multiplies ``E`` by the per-sample albedo (interpolated vertex colour or texture).
* Textures: bilinear between texel centres, ``repeat`` wrap in both directions (VRML
  ImageTexture ``repeatS``/``repeatT`` defaults), ``t`` (v) up: texel row
  ``(1 - t) * height - 0.5``.
* Anti-aliasing: render at ``N x`` the size and average each ``N x N`` block in linear light
  (each sample row's N samples added left to right, then the N row sums top to bottom,
  then divided by ``N*N``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

SUBPIXEL_BITS = 8
SUB = 1 << SUBPIXEL_BITS
HALF = SUB // 2
MAX_SCREEN_PX = float(1 << 20)  # vertices projecting farther than this from centre -> triangle skipped
_MAX_FRAGMENTS = 1 << 21  # samples generated at once (bounds the working memory)


@dataclass(frozen=True)
class Camera:
    """A resolved perspective camera (world space)."""

    position: tuple[float, float, float]
    look_at: tuple[float, float, float]
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    fov_deg: float = 30.0
    near: float = 0.1
    far: float = 1e5

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, true_up, forward), each a unit float64[3]."""
        eye = np.asarray(self.position, dtype=np.float64)
        fwd = np.asarray(self.look_at, dtype=np.float64) - eye
        fwd = fwd / _norm3(fwd)
        up = np.asarray(self.up, dtype=np.float64)
        right = _cross3(fwd, up)
        right = right / _norm3(right)
        tup = _cross3(right, fwd)
        return right, tup, fwd

    def focal_px(self, height: int) -> float:
        return (height / 2.0) / float(np.tan(np.radians(self.fov_deg) / 2.0))


def _norm3(v: np.ndarray) -> float:
    return float(np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))


def _cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot product of [..., 3] arrays in a fixed order (x + y) + z."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


def cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(a.shape, b.shape), dtype=np.float64)
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def normalize_rows(v: np.ndarray) -> np.ndarray:
    """Unit rows; zero rows stay zero."""
    n = np.sqrt(dot_rows(v, v))
    safe = np.where(n > 0.0, n, 1.0)
    return v / safe[..., None]


# ----------------------------------------------------------------------------- projection
@dataclass
class Projected:
    sx: np.ndarray  # float64[n] screen x (pixels)
    sy: np.ndarray  # float64[n] screen y (pixels, down)
    depth: np.ndarray  # float64[n] view depth d along forward


def project(vertices: np.ndarray, camera: Camera, width: int, height: int) -> Projected:
    right, tup, fwd = camera.basis()
    rel = vertices - np.asarray(camera.position, dtype=np.float64)
    xc = dot_rows(rel, right)
    yc = dot_rows(rel, tup)
    d = dot_rows(rel, fwd)
    f = camera.focal_px(height)
    dsafe = np.where(d > 0.0, d, 1.0)
    sx = width / 2.0 + f * xc / dsafe
    sy = height / 2.0 - f * yc / dsafe
    return Projected(sx, sy, d)


# ----------------------------------------------------------------------------- normals
def face_normals_unnormalised(vertices: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Cross products (v1 - v0) x (v2 - v0): direction of the CCW front, length 2 x area."""
    v0 = vertices[tris[:, 0]]
    return cross_rows(vertices[tris[:, 1]] - v0, vertices[tris[:, 2]] - v0)


def vertex_normals(vertices: np.ndarray, tris: np.ndarray, fn: np.ndarray | None = None) -> np.ndarray:
    """Area-weighted vertex normals (unit; zero where the weighted sum is zero).

    Accumulated with ``np.bincount`` (sequential, in triangle order, corner 0, 1, 2)."""
    n = vertices.shape[0]
    if fn is None:
        fn = face_normals_unnormalised(vertices, tris)
    idx = tris.T.reshape(-1)  # corner-major: all corner-0 then corner-1 then corner-2
    acc = np.empty((n, 3), dtype=np.float64)
    for c in range(3):
        w = np.concatenate([fn[:, c], fn[:, c], fn[:, c]])
        acc[:, c] = np.bincount(idx, weights=w, minlength=n)
    return normalize_rows(acc)


# ----------------------------------------------------------------------------- lighting
@dataclass(frozen=True)
class LightSet:
    """Linear-light parameters: ``directions`` float64[L, 3] (direction light travels),
    ``colors`` float64[L, 3] (colour x intensity), ``ambient`` float64[3]."""

    directions: np.ndarray
    colors: np.ndarray
    ambient: np.ndarray
    specular: bool = True


def light(
    normals: np.ndarray, points: np.ndarray, eye: np.ndarray, lights: LightSet, ks: np.ndarray, exponent: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Diffuse irradiance E and specular S (float64[k, 3] each) for unit normals at points."""
    k = normals.shape[0]
    E = np.empty((k, 3), dtype=np.float64)
    E[:] = lights.ambient
    S = np.zeros((k, 3), dtype=np.float64)
    use_spec = lights.specular and bool(np.any(ks > 0.0))
    if use_spec:
        V = normalize_rows(eye - points)
    for li in range(lights.directions.shape[0]):
        d = lights.directions[li]
        L = -d / _norm3(d)
        col = lights.colors[li]
        ndl = dot_rows(normals, L[None, :])
        lam = np.maximum(ndl, 0.0)
        E += lam[:, None] * col[None, :]
        if use_spec:
            H = normalize_rows(V + L[None, :])
            ndh = np.maximum(dot_rows(normals, H), 0.0)
            s = np.where(ndl > 0.0, ks * np.power(ndh, exponent), 0.0)
            S += s[:, None] * col[None, :]
    return E, S


# ----------------------------------------------------------------------------- rasterise
@dataclass
class Coverage:
    """The visible surface per sample: for each covered sample (linear index
    ``pix = y * width + x``, each at most once, in a fixed but unspecified order), the
    triangle, its three vertex indices ``v0, v1, v2`` (in the order matching ``b0, b1,
    b2``), perspective-correct barycentric weights and whether the triangle faces the
    viewer."""

    pix: np.ndarray  # int64[k]
    tri: np.ndarray  # int64[k] global triangle index
    v0: np.ndarray  # int64[k]
    v1: np.ndarray
    v2: np.ndarray
    b0: np.ndarray  # float64[k]
    b1: np.ndarray
    b2: np.ndarray
    front: np.ndarray  # bool[k]
    n_skipped_near: int = 0  # triangles skipped by the near-plane / range rule

    @classmethod
    def empty(cls, n_skipped: int = 0) -> Coverage:
        i, f = np.zeros(0, np.int64), np.zeros(0, np.float64)
        return cls(i, i, i, i, i, f, f, f, np.zeros(0, bool), n_skipped)

    @property
    def bary(self) -> np.ndarray:
        return np.stack([self.b0, self.b1, self.b2], axis=1)

    @property
    def verts(self) -> np.ndarray:
        return np.stack([self.v0, self.v1, self.v2], axis=1)


PURE_PYTHON_ENV = "FBACONF_PURE_PYTHON"

try:
    from . import _fastraster as _native_module
except ImportError:  # not built (no compiler): the numpy path is used
    _native_module = None


def native():
    """The C scan converter (rendering/_fastraster.c), or None when it was not built or
    FBACONF_PURE_PYTHON is set: the numpy path below is the reference either way."""
    if _native_module is None or os.environ.get(PURE_PYTHON_ENV, "").strip() not in ("", "0"):
        return None
    return _native_module


def _scratch_buf(scratch: dict | None, name: str, size: int, dtype, fill) -> np.ndarray:
    """A work buffer of ``size`` items kept in ``scratch`` between calls, filled with ``fill``
    (None: left as it is, for outputs written before they are read)."""
    buf = None if scratch is None else scratch.get(name)
    if buf is None or buf.shape[0] != size or buf.dtype != dtype:
        buf = np.empty(size, dtype=dtype)
        if scratch is not None:
            scratch[name] = buf
    if fill is not None:
        buf.fill(fill)
    return buf


def rasterize(
    proj: Projected,
    tris: np.ndarray,
    width: int,
    height: int,
    near: float,
    far: float,
    cull_backfaces: bool = False,
    *,
    scratch: dict | None = None,
) -> Coverage:
    """Scan-convert all triangles into the samples of a ``width x height`` grid and resolve
    visibility with the depth test. ``tris`` is int64[m, 3] (global vertex indices).
    ``scratch``: an optional dict in which per-image work buffers are kept between calls (with
    the C scan converter the returned arrays may be views into them, valid until the next call)."""
    tris = np.asarray(tris, dtype=np.int64)
    cx, cy = width / 2.0, height / 2.0
    vok = (proj.depth >= near) & (np.abs(proj.sx - cx) <= MAX_SCREEN_PX) & (np.abs(proj.sy - cy) <= MAX_SCREEN_PX)
    X = np.floor(np.where(vok, proj.sx, 0.0) * SUB + 0.5).astype(np.int64)
    Y = np.floor(np.where(vok, proj.sy, 0.0) * SUB + 0.5).astype(np.int64)
    inv_d = np.where(vok, 1.0 / np.where(vok, proj.depth, 1.0), 0.0)

    tri_ok = vok[tris[:, 0]] & vok[tris[:, 1]] & vok[tris[:, 2]]
    n_skipped = int(tris.shape[0] - np.count_nonzero(tri_ok))
    x0, x1, x2 = X[tris[:, 0]], X[tris[:, 1]], X[tris[:, 2]]
    y0, y1, y2 = Y[tris[:, 0]], Y[tris[:, 1]], Y[tris[:, 2]]
    area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
    front = area < 0  # CCW in y-up world view == CW in y-down screen
    keep = tri_ok & (area != 0)
    if cull_backfaces:
        keep &= front
    # Orient every triangle positively (swap corners 1 and 2 of front faces).
    o = tris.copy()
    o[front, 1] = tris[front, 2]
    o[front, 2] = tris[front, 1]
    x1, x2 = np.where(front, x2, x1), np.where(front, x1, x2)
    y1, y2 = np.where(front, y2, y1), np.where(front, y1, y2)
    area = np.abs(area)

    # Sample-index bounding boxes (sample i at i*SUB + HALF), clipped to the image.
    mnx = np.minimum(np.minimum(x0, x1), x2)
    mxx = np.maximum(np.maximum(x0, x1), x2)
    mny = np.minimum(np.minimum(y0, y1), y2)
    mxy = np.maximum(np.maximum(y0, y1), y2)
    i0 = np.maximum(-((HALF - mnx) // SUB), 0)
    i1 = np.minimum((mxx - HALF) // SUB, width - 1)
    j0 = np.maximum(-((HALF - mny) // SUB), 0)
    j1 = np.minimum((mxy - HALF) // SUB, height - 1)
    keep &= (i0 <= i1) & (j0 <= j1)
    sel = np.flatnonzero(keep)

    empty = Coverage.empty(n_skipped)
    if sel.size == 0:
        return empty

    # Edge functions: w_q(p) = (bx - ax) * (py - ay) - (by - ay) * (px - ax) for the edge
    # opposite each corner (w0: v1->v2, w1: v2->v0, w2: v0->v1); a sample is inside when
    # every w_q > thr_q (thr = -1 on edges owning their samples, else 0). All int64, exact.
    s0, s1, s2 = o[sel, 0], o[sel, 1], o[sel, 2]
    X0, X1, X2 = x0[sel], x1[sel], x2[sel]
    Y0, Y1, Y2 = y0[sel], y1[sel], y2[sel]
    edges = ((X1, Y1, X2, Y2), (X2, Y2, X0, Y0), (X0, Y0, X1, Y1))
    si0, sj0 = i0[sel], j0[sel]
    bw, bh = i1[sel] - si0 + 1, j1[sel] - sj0 + 1
    px0, py0 = si0 * SUB + HALF, sj0 * SUB + HALF

    # Per triangle and edge: ownership threshold, edge value at the box's first sample,
    # steps per sample to the right (sx) and down (sy).
    edge_terms = []
    for ax, ay, bx, by in edges:
        edx, edy = bx - ax, by - ay
        thr = np.where((edy > 0) | ((edy == 0) & (edx > 0)), -1, 0)
        edge_terms.append((thr, edx * (py0 - ay) - edy * (px0 - ax), -edy * SUB, edx * SUB))
    # Interpolated inverse depth is affine in the sample position: iz = iz0 + A*dx + B*dy
    # (dx, dy in subpixel units from the triangle's corner 0).
    iz0, iz1, iz2 = inv_d[s0], inv_d[s1], inv_d[s2]
    ar = area[sel].astype(np.float64)
    A = -((Y2 - Y1) * iz0 + (Y0 - Y2) * iz1 + (Y1 - Y0) * iz2) / ar
    B = ((X2 - X1) * iz0 + (X0 - X2) * iz1 + (X1 - X0) * iz2) / ar
    ASUB = A * SUB
    # Far plane per sample (only triangles reaching beyond it are tested): such samples
    # get iz = -1 and can never win. Depth test: max 1/d wins (every iz of a drawn
    # sample is > 0), exact ties -> lowest triangle index.
    beyond = (iz0 * far < 1.0) | (iz1 * far < 1.0) | (iz2 * far < 1.0)
    any_beyond = bool(np.any(beyond))

    def fragments(t0: int, t1: int):
        """(pix, triangle (index into sel), 1/d) of every sample covered by triangles
        t0:t1, in triangle, row, column order. Scanline spans are exact: per row, each
        edge bounds the covered sample columns by an integer floor division."""
        tb = np.arange(t0, t1, dtype=np.int64)
        h = bh[t0:t1]
        n_rows = int(h.sum())
        r_tri = np.repeat(tb, h)
        r_y = np.arange(n_rows, dtype=np.int64) - np.repeat(np.cumsum(h) - h, h)  # row offset in box
        lo = np.zeros(n_rows, dtype=np.int64)
        hi = bw[r_tri] - 1
        for thr, w_org, sx_t, sy_t in edge_terms:
            # w(x) = w_row + sx * x > thr  <=>  sx * x > c
            c = thr[r_tri] - (w_org[r_tri] + sy_t[r_tri] * r_y)
            sx = sx_t[r_tri]
            pos, neg = sx > 0, sx < 0
            one = np.where(pos | neg, sx, 1)
            lo = np.where(pos, np.maximum(lo, c // one + 1), lo)
            hi = np.where(neg, np.minimum(hi, -((-c) // one) - 1), hi)
            # sx == 0: the edge is horizontal, the whole row is in (c < 0) or out.
            hi = np.where((sx == 0) & (c >= 0), -1, hi)
        cnt = np.maximum(hi - lo + 1, 0)
        nf = int(cnt.sum())
        r_px = px0[r_tri] + lo * SUB
        r_py = py0[r_tri] + r_y * SUB
        r_iz = iz0[r_tri] + A[r_tri] * (r_px - X0[r_tri]) + B[r_tri] * (r_py - Y0[r_tri])
        r_pix = (sj0[r_tri] + r_y) * width + si0[r_tri] + lo
        f_k = np.arange(nf, dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)  # sample within span
        f_tri = np.repeat(r_tri, cnt)
        f_pix = np.repeat(r_pix, cnt) + f_k
        f_iz = np.repeat(r_iz, cnt) + np.repeat(ASUB[r_tri], cnt) * f_k
        if any_beyond:
            f_iz = np.where((f_iz * far >= 1.0) | ~beyond[f_tri], f_iz, -1.0)
        return f_pix, f_tri, f_iz

    fast = native()
    if fast is not None:  # the same winners from the C extension (rendering/_fastraster.c)
        tri_i = np.stack(
            [X0, Y0, px0, py0, si0, sj0, bw, bh]
            + [a for term in edge_terms for a in (term[0], term[1], term[2], term[3])],
            axis=1,
        )
        tri_f = np.stack([iz0, A, B, ASUB], axis=1)
        zbuf = _scratch_buf(scratch, "zbuf", width * height, np.float64, 0.0)
        tbuf = _scratch_buf(scratch, "wbuf", width * height, np.int64, -1)
        fast.winners(
            width,
            height,
            float(far),
            any_beyond,
            np.ascontiguousarray(tri_i, dtype=np.int64),
            np.ascontiguousarray(tri_f, dtype=np.float64),
            np.ascontiguousarray(beyond, dtype=np.uint8),
            zbuf,
            tbuf,
        )
        size = width * height
        out = [_scratch_buf(scratch, f"res{i}", size, np.int64 if i < 2 else np.float64, None) for i in range(5)]
        tri_i = np.stack([X0, Y0, X1, Y1, X2, Y2, area[sel]], axis=1)
        tri_f = np.stack([ar, iz0, iz1, iz2], axis=1)
        n = fast.resolve(
            width,
            tbuf,
            np.ascontiguousarray(tri_i, dtype=np.int64),
            np.ascontiguousarray(tri_f, dtype=np.float64),
            *out,
        )
        if n == 0:
            return empty
        # with ``scratch`` the winners and barycentrics are views into it, valid until its next use
        wp, wt, b0, b1, b2 = (x[:n] if scratch is not None else x[:n].copy() for x in out)
        tg = sel[wt]
        return Coverage(wp, tg, s0[wt], s1[wt], s2[wt], b0, b1, b2, front[tg], n_skipped)
    else:
        # Triangles are processed in chunks whose boxes hold at most _MAX_FRAGMENTS samples
        # (bounded working memory; a single larger triangle is a chunk of its own): pass 1
        # builds the depth buffer, pass 2 keeps the samples equal to it.
        csum = np.cumsum(bw * bh)
        bounds = [0]
        while True:
            start = bounds[-1]
            base = int(csum[start - 1]) if start else 0
            if int(csum[-1]) - base <= _MAX_FRAGMENTS:
                break
            nxt = int(np.searchsorted(csum, base + _MAX_FRAGMENTS, side="right"))
            bounds.append(max(nxt, start + 1))
        bounds.append(sel.size)
        zbuf = _scratch_buf(scratch, "zbuf", width * height, np.float64, 0.0)
        single = None
        for t0, t1 in zip(bounds[:-1], bounds[1:]):
            fp, ft, fz = fragments(t0, t1)
            np.maximum.at(zbuf, fp, fz)
            if len(bounds) == 2:
                single = (fp, ft, fz)
        wps, wts = [], []
        for t0, t1 in zip(bounds[:-1], bounds[1:]):
            fp, ft, fz = single if single is not None else fragments(t0, t1)
            keep = np.flatnonzero(fz == zbuf[fp])
            wps.append(fp[keep])
            wts.append(ft[keep])
        wp = np.concatenate(wps)
        wt = np.concatenate(wts)
        if wp.size == 0:
            return empty
        mark = _scratch_buf(scratch, "mark", width * height, np.bool_, False)
        mark[wp] = True
        if np.count_nonzero(mark) != wp.size:  # exact depth ties: lowest triangle index wins
            tbuf = _scratch_buf(scratch, "tbuf", width * height, np.int64, np.iinfo(np.int64).max)
            np.minimum.at(tbuf, wp, wt)
            keep = wt == tbuf[wp]
            wp, wt = wp[keep], wt[keep]

    # Exact barycentrics of the winners, then perspective correction.
    spx = (wp % width) * SUB + HALF
    spy = (wp // width) * SUB + HALF
    wq = []
    for ax, ay, bx, by in edges[1:]:
        wq.append((bx - ax)[wt] * (spy - ay[wt]) - (by - ay)[wt] * (spx - ax[wt]))
    arw = ar[wt]
    w1, w2 = wq
    w0 = area[sel][wt] - w1 - w2
    q0 = (w0 / arw) * iz0[wt]
    q1 = (w1 / arw) * iz1[wt]
    q2 = (w2 / arw) * iz2[wt]
    izw = q0 + q1 + q2
    tg = sel[wt]
    return Coverage(wp, tg, s0[wt], s1[wt], s2[wt], q0 / izw, q1 / izw, q2 / izw, front[tg], n_skipped)


# ----------------------------------------------------------------------------- textures
def sample_bilinear_repeat(tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear sample of a linear float64[h, w, 3] texture at uv float64[k, 2] (v up),
    ``repeat`` wrap."""
    th, tw = tex.shape[0], tex.shape[1]
    u = uv[:, 0] - np.floor(uv[:, 0])
    v = uv[:, 1] - np.floor(uv[:, 1])
    x = u * tw - 0.5
    y = (1.0 - v) * th - 0.5
    xf, yf = np.floor(x), np.floor(y)
    fx, fy = (x - xf)[:, None], (y - yf)[:, None]
    xa = np.mod(xf.astype(np.int64), tw)
    ya = np.mod(yf.astype(np.int64), th)
    xb = xa + 1
    xb[xb == tw] = 0
    yb = ya + 1
    yb[yb == th] = 0
    # gathers by flat index (np.take: 2.6x faster than tex[ya, xa]; the same values), then the four
    # weighted texels added left to right, as ``a + b + c + d`` is: bit for bit the same sum
    flat = tex.reshape(th * tw, -1)
    ra, rb = ya * tw, yb * tw
    c00, c10 = flat.take(ra + xa, axis=0), flat.take(ra + xb, axis=0)
    c01, c11 = flat.take(rb + xa, axis=0), flat.take(rb + xb, axis=0)
    gx, gy = 1.0 - fx, 1.0 - fy
    out = (gx * gy) * c00
    out += (fx * gy) * c10
    out += (gx * fy) * c01
    out += (fx * fy) * c11
    return out


# ----------------------------------------------------------------------------- resolve
def box_downsample_planes(planes: np.ndarray, n: int) -> np.ndarray:
    """Average n x n blocks of float64[C, H*n, W*n]: for each output pixel, the n samples
    of each sample row are added left to right, then the n row sums top to bottom, then
    divided by n*n."""
    if n == 1:
        return planes
    C, Hn, Wn = planes.shape
    H, W = Hn // n, Wn // n
    fast = native()
    if fast is not None and planes.dtype == np.float64 and planes.flags.c_contiguous:
        out = np.empty((C, H, W), dtype=np.float64)
        fast.box_downsample(planes, C, H, W, n, out)
        return out
    v = planes.reshape(C * Hn, W, n)
    sx = v[:, :, 0] + v[:, :, 1]
    for dx in range(2, n):
        sx += v[:, :, dx]
    r = sx.reshape(C, H, n, W)
    s = r[:, :, 0] + r[:, :, 1]
    for dy in range(2, n):
        s += r[:, :, dy]
    return s / float(n * n)
