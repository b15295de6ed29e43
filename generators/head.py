"""The generated default head: skull, skin with nose, lips and eye openings, eyeballs, eyebrows, teeth,
tongue, mouth cavity, ears and neck, and its 84 feature points on real vertices (deterministic: no
randomness, no files read)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fbaconf.animation.faceparams import FEATURE_POINTS

PREDICTABLE_L1_MAX_VERTICES = 5000  # profiles-and-levels.md, Predictable L1 (provisional)

COLORS = {
    "skin": (0.80, 0.58, 0.47),
    "lips": (0.70, 0.30, 0.30),
    "eye_white": (0.93, 0.93, 0.90),
    "iris": (0.25, 0.42, 0.62),
    "pupil": (0.03, 0.03, 0.03),
    "brows": (0.22, 0.14, 0.09),
    "teeth": (0.92, 0.90, 0.82),
    "tongue": (0.72, 0.35, 0.36),
    "cavity": (0.18, 0.05, 0.05),
    "ears": (0.78, 0.56, 0.45),
    "neck": (0.76, 0.55, 0.45),
    "logo": (0.15, 0.45, 0.80),
}

# Face layout (neutral), millimetres.
EYE_Y = 25.0
EYE_X = 32.0
EYE_HALF_W = 13.0
IRIS_R = 5.6  # eyelids tangent to the iris: IRISD0 = 2 * IRIS_R
EYE_R = 12.0
MOUTH_Y = -45.0
MOUTH_HALF_W = 25.0
NOSE_BASE_Y = -20.0


def _smooth(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


HEAD_C = np.array([0.0, 8.0, 0.0])
HEAD_AX = np.array([74.0, 102.0, 92.0])


def _radii(y):
    y = np.asarray(y, dtype=np.float64)
    s = np.sqrt(np.clip(1.0 - ((y - HEAD_C[1]) / HEAD_AX[1]) ** 2, 0.0, 1.0))
    jaw = 1.0 - 0.30 * _smooth((-25.0 - y) / 60.0)
    return HEAD_AX[0] * s * jaw, HEAD_AX[2] * s * (1.0 - 0.12 * _smooth((-30.0 - y) / 60.0))


def _features(x, y):
    """Forward (z) relief of the face: nose, brows, cheeks, lips, chin."""
    ax = np.abs(x)
    ny = [-26.0, -20.0, -14.0, -9.0, 0.0, 12.0, 24.0, 32.0]
    nh = [0.0, 9.0, 20.0, 23.0, 17.0, 10.0, 4.0, 0.0]
    nw = [13.0, 12.0, 10.0, 8.0, 6.5, 5.5, 5.0, 5.0]
    h = np.interp(y, ny, nh, left=0.0, right=0.0) * np.exp(-((x / np.interp(y, ny, nw)) ** 2))
    # nostril wings
    h += 5.0 * np.exp(-(((ax - 10.0) / 4.5) ** 2 + ((y + 16.0) / 4.5) ** 2))
    h += 5.0 * np.exp(-(((y - 39.0) / 6.0) ** 2)) * np.exp(-(((ax - 28.0) / 22.0) ** 2))  # brow ridge
    h += 6.0 * np.exp(-(((ax - 40.0) ** 2 + (y + 10.0) ** 2) / 18.0**2))  # cheeks
    lips = np.exp(-((x / 24.0) ** 4))
    h += 6.0 * lips * np.exp(-(((y + 41.5) / 4.5) ** 2)) + 6.5 * lips * np.exp(-(((y + 49.0) / 5.0) ** 2))
    h += 3.0 * np.exp(-((x / 28.0) ** 2)) * np.exp(-(((y + 45.0) / 12.0) ** 2))  # mouth region
    h += 7.0 * np.exp(-((x / 20.0) ** 2 + ((y + 76.0) / 10.0) ** 2))  # chin
    h -= 4.0 * np.exp(-((x / 22.0) ** 2 + ((y + 62.0) / 5.0) ** 2))  # groove under the lip
    return h


def eye_open(xrel):
    """Neutral upper and lower lid offsets from the eye line (almond), xrel in [-1, 1]."""
    u = np.clip(np.abs(xrel), 0.0, 1.0)
    base = np.sqrt(np.clip(1.0 - u**2, 0.0, 1.0))
    return IRIS_R * base**0.9, IRIS_R * base


@dataclass
class Part:
    name: str
    vertices: np.ndarray
    triangles: np.ndarray
    color: str
    parent: str = "Head"  # Transform the part lives in: Head, LeftEye, RightEye, LeftPupil, RightPupil, root
    texcoords: np.ndarray | None = None
    tags: dict = field(default_factory=dict)


@dataclass
class HeadModel:
    parts: dict[str, Part]
    transforms: dict[str, dict]  # name -> {translation, center, parent}
    feature_points: dict[str, tuple[str, int]]  # label -> (part, vertex)
    eye_z: float = 0.0

    def world(self, part: str, idx=None) -> np.ndarray:
        p = self.parts[part]
        v = p.vertices if idx is None else p.vertices[idx]
        t = p.parent
        while t != "root":
            v = v + np.asarray(self.transforms[t]["translation"])
            t = self.transforms[t]["parent"]
        return v

    def fp_positions(self) -> np.ndarray:
        return np.array([self.world(*self.feature_points[label]) for label in FEATURE_POINTS])

    def vertex_count(self) -> int:
        return sum(p.vertices.shape[0] for p in self.parts.values())


def _row_levels(density: float):
    d = density
    segs = [(-93.0, -60.0, 6.0), (-60.0, -30.0, 2.5), (-30.0, 10.0, 5.0), (10.0, 40.0, 2.5), (40.0, 108.0, 7.0)]
    ys = []
    for a, b, step in segs:
        n = max(int(round((b - a) / (step / d))), 1)
        ys.extend(np.linspace(a, b, n, endpoint=False))
    ys.append(108.0)
    ys = np.array(ys)
    for target in (EYE_Y, MOUTH_Y):  # snap one row exactly onto the slit lines
        ys[np.argmin(np.abs(ys - target))] = target
    return ys


def _build_skin(n_lon: int, density: float):
    ys = _row_levels(density)
    t = -1.0 + 2.0 * np.arange(n_lon) / n_lon
    phi = np.sign(t) * np.pi * np.abs(t) ** 1.6
    R, C = len(ys), n_lon
    Y = np.repeat(ys[:, None], C, axis=1)
    rx, rz = _radii(ys)
    X = rx[:, None] * np.sin(phi)[None, :]
    Zb = rz[:, None] * np.cos(phi)[None, :]
    front = np.clip(np.cos(phi), 0.0, 1.0)[None, :] ** 2
    r_m = int(np.argmin(np.abs(ys - MOUTH_Y)))
    r_e = int(np.argmin(np.abs(ys - EYE_Y)))
    # slit columns (strictly between the corner columns, which stay shared)
    fr = np.cos(phi) > 0
    xm = X[r_m]
    corner_m = int(np.argmin(np.where(fr & (xm > 0), np.abs(xm - MOUTH_HALF_W), 1e9)))
    xcm = xm[corner_m]
    mouth_cols = np.nonzero(fr & (np.abs(xm) < xcm - 1e-6))[0]
    xe = X[r_e]
    eye_cols, eye_info = {}, {}
    for side, sx in (("l", 1.0), ("r", -1.0)):
        c_in = int(np.argmin(np.where(fr & (sx * xe > 0), np.abs(sx * xe - (EYE_X - EYE_HALF_W)), 1e9)))
        c_out = int(np.argmin(np.where(fr & (sx * xe > 0), np.abs(sx * xe - (EYE_X + EYE_HALF_W)), 1e9)))
        lo, hi = sorted((xe[c_in], xe[c_out]))
        cols = np.nonzero(fr & (xe > lo + 1e-6) & (xe < hi - 1e-6))[0]
        c_mid = cols[np.argmin(np.abs(np.abs(xe[cols]) - EYE_X))]
        eye_cols[side] = cols
        eye_info[side] = dict(
            lo=lo,
            hi=hi,
            xc=float(xe[c_mid]),
            half=(hi - lo) / 2,
            mid=(hi + lo) / 2,
            c_mid=int(c_mid),
            c_in=c_in,
            c_out=c_out,
        )
        hu_c, hl_c = eye_open((xe[c_mid] - (hi + lo) / 2) / ((hi - lo) / 2))
        eye_info[side]["irisd0"] = float(hu_c + hl_c)  # eyelid distance at the pupil = iris diameter
    # open the eyes: move rows above/below the eye line apart (monotonic, no folds)
    dY = np.zeros_like(Y)
    for _side, info in eye_info.items():
        xrel = (X - info["mid"]) / info["half"]
        inside = (np.abs(xrel) < 1.0) & (Zb > 0)
        hu, hl = eye_open(xrel)
        up = Y > EYE_Y
        dn = Y < EYE_Y
        near = np.abs(Y - EYE_Y) < 30.0
        dY += np.where(inside & up & near, hu * np.exp(-(Y - EYE_Y) / 7.0), 0.0)
        dY -= np.where(inside & dn & near, hl * np.exp(-(EYE_Y - Y) / 7.0), 0.0)
    Y2 = Y + dY
    Z = Zb + _features(X, Y2) * front
    # eye sockets: blend the skin onto a shell around the eyeball
    skin_at_eye = float(_radii(EYE_Y)[1] * np.cos(np.arcsin(EYE_X / _radii(EYE_Y)[0])) + _features(EYE_X, EYE_Y))
    eye_z = skin_at_eye - EYE_R - 1.5

    def eye_shell(x, y, info):
        d2 = (x - info["xc"]) ** 2 + (y - EYE_Y) ** 2
        return eye_z + np.sqrt(np.clip((EYE_R + 0.7) ** 2 - d2, 0.0, None))

    for _side, info in eye_info.items():
        w = np.exp(-((((X - info["xc"]) / 15.5) ** 2 + ((Y2 - EYE_Y) / 10.5) ** 2) ** 2)) * (Zb > 0)
        Z = (1 - w) * Z + w * np.maximum(eye_shell(X, Y2, info), Z - 6.0)
    P = np.stack([X, Y2, Z], axis=-1)
    # vertices: grid + upper copies of slit vertices + two poles
    verts = list(P.reshape(-1, 3))
    idx = np.arange(R * C).reshape(R, C)
    upper = idx.copy()
    nxt = R * C
    slit = {}
    for r, cols, name in [(r_m, mouth_cols, "mouth")] + [(r_e, c, "eye_" + s) for s, c in eye_cols.items()]:
        for c in cols:
            p = P[r, c].copy()
            if name.startswith("eye"):
                info = eye_info[name[-1]]
                hu, hl = eye_open((p[0] - info["mid"]) / info["half"])
                p_up = np.array([p[0], EYE_Y + hu, 0.0])
                p_lo = np.array([p[0], EYE_Y - hl, 0.0])
                p_up[2] = eye_shell(p_up[0], p_up[1], info)
                p_lo[2] = eye_shell(p_lo[0], p_lo[1], info)
                verts[idx[r, c]] = p_lo
                verts.append(p_up)
            else:
                verts.append(p)
            upper[r, c] = nxt
            slit.setdefault(name, []).append((int(idx[r, c]), nxt))
            nxt += 1
    top = nxt
    verts.append(np.array([0.0, HEAD_C[1] + HEAD_AX[1], 0.0]))
    bottom = nxt + 1
    verts.append(np.array([0.0, ys[0] - 1.0, -5.0]))
    tris = []
    for r in range(R - 1):
        for c in range(C):
            c2 = (c + 1) % C
            a, b = idx[r, c], idx[r, c2]
            if r in (r_m, r_e):
                a, b = upper[r, c], upper[r, c2]
            d, e = idx[r + 1, c], idx[r + 1, c2]
            tris.append((a, b, e))
            tris.append((a, e, d))
    for c in range(C):
        c2 = (c + 1) % C
        tris.append((idx[R - 1, c], idx[R - 1, c2], top))
        tris.append((idx[0, c2], idx[0, c], bottom))
    V = np.array(verts)
    is_upper = np.zeros(len(V), bool)
    is_lower = np.zeros(len(V), bool)
    for name in slit:
        for lo_i, up_i in slit[name]:
            is_lower[lo_i] = True
            is_upper[up_i] = True
    phis = np.concatenate(
        [
            np.tile(phi, R),
            phi[
                np.array(
                    [g[0] % C for g in slit.get("mouth", [])]
                    + [g[0] % C for n in slit if n != "mouth" for g in slit[n]],
                    dtype=int,
                )
            ],
            [0.0, 0.0],
        ]
    )
    u = (phis / (2 * np.pi) + 0.5) % 1.0
    v = (V[:, 1] - V[:, 1].min()) / np.ptp(V[:, 1])
    tags = dict(
        slit=slit,
        eye_info=eye_info,
        eye_shell=eye_shell,
        mouth_row_y=MOUTH_Y,
        upper_copy=is_upper,
        lower_copy=is_lower,
        front=np.cos(phis),
        corner_x=float(xcm),
        grid=(idx, upper, r_m, r_e, mouth_cols),
    )
    return V, np.array(tris, dtype=np.int64), np.stack([u, v], axis=1), tags, eye_z, eye_shell


def _lip_mask(V, front):
    """Vertices coloured as lips: inside the outer lip line (cupid's bow on top)."""
    x, y = V[:, 0], V[:, 1]
    top = -38.0 - 1.2 * np.cos(np.clip(x / 7.0, -np.pi, np.pi)) - 3.5 * (np.abs(x) / MOUTH_HALF_W) ** 2
    bottom = -52.5 + 7.0 * (np.abs(x) / MOUTH_HALF_W) ** 2
    return (np.abs(x) <= MOUTH_HALF_W + 0.5) & (y < top) & (y > bottom) & (front > 0.3)


def _uv_sphere(center, radii, n_lat, n_lon, inward=False, lat_range=(-np.pi / 2, np.pi / 2)):
    lat = np.linspace(lat_range[0], lat_range[1], n_lat + 1)[1:-1]
    lon = np.linspace(-np.pi, np.pi, n_lon, endpoint=False)
    cl, sl = np.cos(lat)[:, None], np.sin(lat)[:, None]
    pts = np.stack(
        [cl * np.sin(lon)[None, :], np.broadcast_to(sl, (len(lat), n_lon)), cl * np.cos(lon)[None, :]], axis=-1
    ).reshape(-1, 3)
    pts = np.vstack(
        [
            pts,
            [
                [0, np.sin(lat_range[0]) if lat_range[0] > -np.pi / 2 else -1, 0],
                [0, np.sin(lat_range[1]) if lat_range[1] < np.pi / 2 else 1, 0],
            ],
        ]
    )
    V = np.asarray(center) + pts * np.asarray(radii)
    rows = len(lat)
    idx = np.arange(rows * n_lon).reshape(rows, n_lon)
    bot, top = rows * n_lon, rows * n_lon + 1
    tris = []
    for r in range(rows - 1):
        for c in range(n_lon):
            c2 = (c + 1) % n_lon
            tris += [(idx[r, c], idx[r, c2], idx[r + 1, c2]), (idx[r, c], idx[r + 1, c2], idx[r + 1, c])]
    for c in range(n_lon):
        c2 = (c + 1) % n_lon
        tris += [(idx[0, c2], idx[0, c], bot), (idx[rows - 1, c], idx[rows - 1, c2], top)]
    T = np.array(tris, dtype=np.int64)
    if inward:
        T = T[:, ::-1]
    return V, T


def _cap(radius, half_angle, n_rings, n_seg, z_axis=(0, 0, 1)):
    """Spherical cap around +z (centre vertex first), CCW seen from +z."""
    pts = [[0.0, 0.0, radius]]
    for k in range(1, n_rings + 1):
        a = half_angle * k / n_rings
        for s in range(n_seg):
            b = 2 * np.pi * s / n_seg
            pts.append([radius * np.sin(a) * np.cos(b), radius * np.sin(a) * np.sin(b), radius * np.cos(a)])
    tris = []
    for s in range(n_seg):
        tris.append((0, 1 + s, 1 + (s + 1) % n_seg))
    for k in range(1, n_rings):
        b0, b1 = 1 + (k - 1) * n_seg, 1 + k * n_seg
        for s in range(n_seg):
            s2 = (s + 1) % n_seg
            tris += [(b0 + s, b1 + s, b1 + s2), (b0 + s, b1 + s2, b0 + s2)]
    return np.array(pts), np.array(tris, dtype=np.int64)


def _slab(xs, zfun, y0, y1, thick):
    """Curved slab (teeth) following z = zfun(x) (front surface), from y0 to y1, front faces out."""
    n = len(xs)
    zf = zfun(xs)
    ring = []
    for dz in (0.0, -thick):
        for y in (y0, y1):
            ring.append(np.stack([xs * (1 - 0.15 * (dz != 0)), np.full(n, y), zf + dz], axis=1))
    V = np.vstack(ring)  # blocks: outer-low, outer-high, inner-low, inner-high
    ol, oh, il, ih = (np.arange(n) + k * n for k in range(4))
    tris = []
    for i in range(n - 1):
        j = i + 1
        tris += [(ol[i], ol[j], oh[j]), (ol[i], oh[j], oh[i])]  # outer (front)
        tris += [(il[j], il[i], ih[i]), (il[j], ih[i], ih[j])]  # inner
        tris += [(oh[i], oh[j], ih[j]), (oh[i], ih[j], ih[i])]  # top
        tris += [(ol[j], ol[i], il[i]), (ol[j], il[i], il[j])]  # bottom
    for i, s in ((0, 1), (n - 1, -1)):
        q = (ol[i], il[i], ih[i], oh[i])
        tri = [(q[0], q[1], q[2]), (q[0], q[2], q[3])]
        tris += tri if s < 0 else [t[::-1] for t in tri]
    return V, np.array(tris, dtype=np.int64)


def _nearest(V, p, mask=None):
    d = np.linalg.norm(V - np.asarray(p), axis=1)
    if mask is not None:
        d = np.where(mask, d, np.inf)
    return int(np.argmin(d))


def build_head(n_lon: int = 48, density: float = 1.0, filler_vertices: int = 0) -> HeadModel:
    V, T, UV, tags, eye_z, eye_shell = _build_skin(n_lon, density)
    skin = Part("Skin", V, T, "skin", texcoords=UV, tags=tags)
    front = tags["front"]
    lips = _lip_mask(V, front)
    skin.tags["lips"] = lips
    parts = {"Skin": skin}
    info_l, info_r = tags["eye_info"]["l"], tags["eye_info"]["r"]
    transforms = {"Head": dict(translation=(0.0, 0.0, 0.0), center=None, parent="root")}
    for side, info in (("Left", info_l), ("Right", info_r)):
        transforms[f"{side}Eye"] = dict(translation=(info["xc"], EYE_Y, eye_z), parent="Head")
        transforms[f"{side}Pupil"] = dict(translation=(0.0, 0.0, 0.0), parent=f"{side}Eye")
        ev, et = _uv_sphere((0, 0, 0), (EYE_R, EYE_R, EYE_R), 12 + 4 * int(density > 1), 16 + 4 * int(density > 1))
        parts[f"{side}Eyeball"] = Part(f"{side}Eyeball", ev, et, "eye_white", parent=f"{side}Eye")
        iris_r = info["irisd0"] / 2  # neutral face: eyelids tangent to the iris
        iv, it = _cap(EYE_R + 0.06, np.arcsin(iris_r / (EYE_R + 0.06)), 2, 16)
        parts[f"{side}Iris"] = Part(f"{side}Iris", iv, it, "iris", parent=f"{side}Eye")
        pv, pt = _cap(EYE_R + 0.12, np.arcsin(iris_r / 3 / (EYE_R + 0.12)), 1, 12)  # pupil = IRISD0 / 3
        parts[f"{side}PupilDisc"] = Part(f"{side}PupilDisc", pv, pt, "pupil", parent=f"{side}Pupil")

    # eyebrows: strips hugging the skin
    def skin_z(x, y):
        k = _nearest(V[:, :2], (x, y), mask=front > 0.2)
        return V[k, 2]

    for side, sx in (("Left", 1.0), ("Right", -1.0)):
        xs = np.linspace(13.0, 50.0, 10)
        mid = 39.0 + 4.0 * np.sin(np.pi * (xs - 13.0) / 37.0) - 1.5 * (xs - 13) / 37
        bv = []
        for dy in (-2.2, 2.2):
            for x, m in zip(xs, mid):
                bv.append([sx * x, m + dy * (1 - 0.45 * (x - 13) / 37), 0.0])
        bv = np.array(bv)
        bv[:, 2] = [skin_z(p[0], p[1]) + 1.3 for p in bv]
        n = len(xs)
        bt_ = []
        for i in range(n - 1):
            a, b, c, d = i, i + 1, n + i + 1, n + i
            tri = [(a, b, c), (a, c, d)]
            bt_ += tri if sx > 0 else [t[::-1] for t in tri]
        parts[f"{side}Brow"] = Part(f"{side}Brow", bv, np.array(bt_, dtype=np.int64), "brows")
    # teeth, tongue and mouth cavity behind the lips (following the lip line's depth profile)
    row = (np.abs(V[:, 1] - MOUTH_Y) < 1e-6) & (front > 0)
    order = np.argsort(V[row, 0])
    px, pz = V[row, 0][order], V[row, 2][order]
    lip_front = float(np.interp(0.0, px, pz))

    def zfun(x):
        return np.interp(x, px, pz) - 5.5 - 4.0 * (x / 15.0) ** 2

    xs = np.linspace(-15.0, 15.0, 11)
    uv_, ut = _slab(xs, zfun, MOUTH_Y, MOUTH_Y + 7.0, 3.0)
    parts["UpperTeeth"] = Part("UpperTeeth", uv_, ut, "teeth")
    lv, lt = _slab(xs * 0.94, lambda x: zfun(x) - 0.8, MOUTH_Y - 7.0, MOUTH_Y, 3.0)
    parts["LowerTeeth"] = Part("LowerTeeth", lv, lt, "teeth")
    tip_z = lip_front - 5.5 - 3.8
    gv, gt = _uv_sphere((0.0, MOUTH_Y - 3.5, tip_z - 20.0), (14.0, 3.5, 20.0), 8, 16)
    parts["Tongue"] = Part("Tongue", gv, gt, "tongue")
    cv, ct = _uv_sphere((0.0, MOUTH_Y - 1.0, lip_front - 29.0), (20.0, 12.0, 16.0), 10, 16, inward=True)
    parts["Cavity"] = Part("Cavity", cv, ct, "cavity")
    # ears
    for side, sx in (("Left", 1.0), ("Right", -1.0)):
        ex = sx * (float(_radii(12.0)[0]) - 3.0)
        ev, et = _uv_sphere((ex, 12.0, -6.0), (4.5, 26.0, 14.0), 8, 14)
        ev[:, 0] += sx * 3.0 * np.clip((ev[:, 0] - ex) * sx / 4.5, 0.0, 1.0)  # thicker outer rim
        parts[f"{side}Ear"] = Part(f"{side}Ear", ev, et, "ears")
    # neck (outside the head Transform) with the skull-base point 7.1 at its top centre
    nseg, nrows = 20, 6
    nv = []
    for k in range(nrows):
        y = -150.0 + 120.0 * k / (nrows - 1)
        for s in range(nseg):
            a = 2 * np.pi * s / nseg
            nv.append([36.0 * np.sin(a), y, -15.0 + 38.0 * np.cos(a)])
    nv.append([0.0, -30.0, -15.0])
    nt = []
    for k in range(nrows - 1):
        for s in range(nseg):
            s2 = (s + 1) % nseg
            a, b, c, d = k * nseg + s, k * nseg + s2, (k + 1) * nseg + s2, (k + 1) * nseg + s
            nt += [(a, b, c), (a, c, d)]
    cap = nrows * nseg
    for s in range(nseg):
        nt.append(((nrows - 1) * nseg + s, (nrows - 1) * nseg + (s + 1) % nseg, cap))
    parts["Neck"] = Part("Neck", np.array(nv), np.array(nt, dtype=np.int64), "neck", parent="root")
    if filler_vertices:
        k = filler_vertices
        a = 2 * np.pi * np.arange(k - 1) / (k - 1)
        fv = np.vstack(
            [[0.0, -120.0, 24.5], np.stack([6 * np.sin(a), -120.0 + 6 * np.cos(a), np.full(k - 1, 24.5)], 1)]
        )
        ft = np.array([(0, 1 + i, 1 + (i + 1) % (k - 1)) for i in range(k - 1)], dtype=np.int64)[:, [0, 2, 1]]
        parts["Badge"] = Part("Badge", fv, ft, "iris", parent="root")
    model = HeadModel(parts, transforms, {}, eye_z)
    model.feature_points = _feature_points(model, tags, eye_z)
    return model


def _feature_points(m: HeadModel, tags, eye_z) -> dict[str, tuple[str, int]]:
    S = m.parts["Skin"].vertices
    front = tags["front"] > 0.2
    up, lo = tags["upper_copy"], tags["lower_copy"]
    on_slit = up | lo
    slit_m = np.zeros(len(S), bool)
    for a, b in tags["slit"]["mouth"]:
        slit_m[a] = slit_m[b] = True
    fp: dict[str, tuple[str, int]] = {}

    def skin(label, p, mask=front):
        """Nearest skin vertex; z = 200 means 'the front surface': nearest in x-y among front vertices."""
        if p[2] == 200:
            fp[label] = ("Skin", _nearest(S[:, :2], p[:2], mask & (tags["front"] > 0)))
        else:
            fp[label] = ("Skin", _nearest(S, p, mask))

    xc = tags["corner_x"]
    mx = np.where(slit_m, np.abs(S[:, 0]), -1)
    inner_corner = float(mx.max())
    skin("2.2", (0, MOUTH_Y, 200), up & slit_m)
    skin("2.3", (0, MOUTH_Y, 200), lo & slit_m)
    skin("2.4", (inner_corner, MOUTH_Y, 200), up & slit_m)
    skin("2.5", (-inner_corner, MOUTH_Y, 200), up & slit_m)
    skin("2.6", (inner_corner / 2, MOUTH_Y, 200), up & slit_m)
    skin("2.7", (-inner_corner / 2, MOUTH_Y, 200), up & slit_m)
    skin("2.8", (inner_corner / 2, MOUTH_Y, 200), lo & slit_m)
    skin("2.9", (-inner_corner / 2, MOUTH_Y, 200), lo & slit_m)
    skin("2.1", (0, -95, 40), front & (S[:, 1] < -80))
    skin("2.10", (0, -72, 200))
    skin("2.11", (16, -74, 200))
    skin("2.12", (-16, -74, 200))
    skin("2.13", (55, -45, 20), tags["front"] > 0)
    skin("2.14", (-55, -45, 20), tags["front"] > 0)
    for side, s, lab in (
        ("l", 1, ("3.1", "3.3", "3.7", "3.11", "3.9", "3.13")),
        ("r", -1, ("3.2", "3.4", "3.8", "3.12", "3.10", "3.14")),
    ):
        info = tags["eye_info"][side]
        eye_slit = np.zeros(len(S), bool)
        for a, b in tags["slit"]["eye_" + side]:
            eye_slit[a] = eye_slit[b] = True
        skin(lab[0], (info["xc"], EYE_Y + 9, 200), up & eye_slit)
        skin(lab[1], (info["xc"], EYE_Y - 9, 200), lo & eye_slit)
        outer = info["hi"] if s > 0 else info["lo"]
        inner = info["lo"] if s > 0 else info["hi"]
        skin(lab[2], (outer, EYE_Y, 200), front & ~on_slit)
        skin(lab[3], (inner, EYE_Y, 200), front & ~on_slit)
        skin(lab[4], (info["xc"], EYE_Y - 11, 200), front & ~on_slit)
        skin(lab[5], (info["xc"], EYE_Y + 11, 200), front & ~on_slit)
    fp["3.5"] = ("LeftPupilDisc", 0)
    fp["3.6"] = ("RightPupilDisc", 0)
    for label, (part, x) in {
        "4.1": ("LeftBrow", 13),
        "4.2": ("RightBrow", -13),
        "4.3": ("LeftBrow", 31),
        "4.4": ("RightBrow", -31),
        "4.5": ("LeftBrow", 50),
        "4.6": ("RightBrow", -50),
    }.items():
        B = m.parts[part].vertices
        fp[label] = (part, _nearest(B[len(B) // 2 :, :1], (x,)) + len(B) // 2)  # upper edge of the brow
    skin("5.1", (38, -38, 200))
    skin("5.2", (-38, -38, 200))
    skin("5.3", (42, -2, 200))
    skin("5.4", (-42, -2, 200))
    G = m.parts["Tongue"].vertices
    fp["6.1"] = ("Tongue", int(np.argmax(G[:, 2])))
    fp["6.2"] = ("Tongue", int(np.argmax(G[:, 1])))
    fp["6.3"] = ("Tongue", int(np.argmax(G[:, 0] - 0.1 * np.abs(G[:, 2] - G[:, 2].mean()))))
    fp["6.4"] = ("Tongue", int(np.argmin(G[:, 0] + 0.1 * np.abs(G[:, 2] - G[:, 2].mean()))))
    fp["7.1"] = ("Neck", m.parts["Neck"].vertices.shape[0] - 1)
    outer_ok = front & ~(up & slit_m) & ~(lo & slit_m)
    skin("8.1", (0, -38.5, 200), outer_ok)
    skin("8.2", (0, -53, 200), outer_ok)
    fp["8.3"] = ("Skin", _nearest(S, (xc, MOUTH_Y, 200), front & ~on_slit & (np.abs(S[:, 1] - MOUTH_Y) < 0.5)))
    fp["8.4"] = ("Skin", _nearest(S, (-xc, MOUTH_Y, 200), front & ~on_slit & (np.abs(S[:, 1] - MOUTH_Y) < 0.5)))
    skin("8.5", (13, -40, 200), outer_ok)
    skin("8.6", (-13, -40, 200), outer_ok)
    skin("8.7", (13, -51.5, 200), outer_ok)
    skin("8.8", (-13, -51.5, 200), outer_ok)
    skin("8.9", (6, -37.5, 200), outer_ok)
    skin("8.10", (-6, -37.5, 200), outer_ok)
    skin("9.1", (11, -17, 200))
    skin("9.2", (-11, -17, 200))
    skin("9.3", (0, -9, 200))
    skin("9.4", (15, -21, 200))
    skin("9.5", (-15, -21, 200))
    skin("9.6", (6, 16, 200))
    skin("9.7", (-6, 16, 200))
    skin("9.8", (0, -60, 200))  # [?] description not found; fbaconf: under the lower lip
    skin("9.9", (0, -31, 200))  # [?] fbaconf: philtrum
    U, L = m.parts["UpperTeeth"].vertices, m.parts["LowerTeeth"].vertices
    fp["9.10"] = ("UpperTeeth", _nearest(U, (0, MOUTH_Y, U[:, 2].max())))
    fp["9.11"] = ("LowerTeeth", _nearest(L, (0, MOUTH_Y, L[:, 2].max())))
    skin("9.12", (0, 24, 200))
    skin("9.13", (8, 4, 200))
    skin("9.14", (-8, 4, 200))
    fp["9.15"] = ("Skin", _nearest(S[:, :2], (0, NOSE_BASE_Y), front & (np.abs(S[:, 0]) < 0.5)))
    for side, s, labs in (
        ("Left", 1, ("10.1", "10.3", "10.5", "10.7", "10.9")),
        ("Right", -1, ("10.2", "10.4", "10.6", "10.8", "10.10")),
    ):
        E = m.parts[f"{side}Ear"].vertices
        cx = E[:, 0].mean()
        out = s * (E[:, 0] - cx) > -1
        fp[labs[0]] = (f"{side}Ear", int(np.argmax(E[:, 1])))
        fp[labs[1]] = (f"{side}Ear", _nearest(E, (cx + s * 10, 12, -20), out))
        fp[labs[2]] = (f"{side}Ear", int(np.argmin(E[:, 1])))
        fp[labs[3]] = (f"{side}Ear", _nearest(E, (cx, 12, 20)))
        fp[labs[4]] = (f"{side}Ear", _nearest(E, (cx, -4, 10)))
    top_y = S[:, 1].max()
    skin("11.1", (0, 85, 200), front)
    skin("11.2", (35, 78, 200), front)
    skin("11.3", (-35, 78, 200), front)
    fp["11.4"] = ("Skin", int(np.argmax(S[:, 1])))
    skin("11.5", (70, 30, 0), tags["front"] > -0.2)
    skin("11.6", (-70, 30, 0), tags["front"] > -0.2)
    assert top_y > 0 and len(fp) == 84, sorted(set(FEATURE_POINTS) - set(fp))
    return fp
