"""Generated FaceDefTables for the default head: FaceDefMesh (4-5 intervals per FAP) and
FaceDefTransform (eyeballs, pupils, head rotation) for all 66 low-level FAPs."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fbaconf.bitstreams.tables import fap_table

from .head import EYE_Y, IRIS_R, MOUTH_Y, HeadModel, eye_open


@dataclass
class MeshSpec:
    part: str
    indices: np.ndarray
    displacements: np.ndarray  # [V, n, 3] per FAPU unit, as stored in the table
    borders: tuple[int, ...]


@dataclass
class TransformSpec:
    target: str
    field_id: int
    rotation: tuple = (0.0, 0.0, 1.0, 0.0)
    scale: tuple = (1.0, 1.0, 1.0)
    translation: tuple = (0.0, 0.0, 0.0)


def mesh_from_function(part: str, indices, disp_fn, borders, unit: float, min_disp: float = 1e-4) -> MeshSpec | None:
    """Table for a motion given as a function: ``disp_fn(a)`` -> [V, 3] displacement at FAP value a.

    The trajectory is sampled at the interval borders and stored so that the seed formula
    (FaceDefMesh, steps 1-6, literal negative-side reading) reproduces it exactly at every
    border and linearly in between."""
    b = [int(x) for x in borders]
    k = b.index(0)
    P = {x: np.asarray(disp_fn(float(x)), dtype=np.float64) for x in b}
    n = len(b) - 1
    D = np.zeros((len(indices), n, 3))
    for j in range(n):
        lo, hi = b[j], b[j + 1]
        if j >= k:
            D[:, j] = (P[hi] - P[lo]) / ((hi - lo) * unit)
        else:
            D[:, j] = (P[lo] - P[hi]) / ((hi - lo) * unit)
    keep = np.abs(D).max(axis=(1, 2)) * unit * max(abs(b[0]), abs(b[-1])) > min_disp
    if not keep.any():
        return None
    D = np.round(D[keep], 9)
    return MeshSpec(part, np.asarray(indices)[keep], D, tuple(b))


def fap_borders(fap: int) -> tuple[int, ...]:
    f = fap_table()[fap - 1]
    R = 100000 if f.fapu == "AU" else 1024
    if f.direction == "U":
        return (-R // 4, 0, R // 4, R // 2, R)
    return (-R, -R // 2, 0, R // 4, R // 2, R)


def saturate(a, fap):
    R = 100000.0 if fap_table()[fap - 1].fapu == "AU" else 1024.0
    return 1.0 / (1.0 + 0.2 * abs(a) / R)


def head_tables(m: HeadModel, fapu) -> dict[int, list]:
    """The default head's animation rules: fapID -> list of MeshSpec / TransformSpec."""
    S = m.parts["Skin"]
    V = S.vertices
    x, y, z = V[:, 0], V[:, 1], V[:, 2]
    tags = S.tags
    front = tags["front"]
    mouth_up = np.zeros(len(V), bool)
    mouth_lo = np.zeros(len(V), bool)
    for a, b in tags["slit"]["mouth"]:
        mouth_lo[a] = True
        mouth_up[b] = True
    shared_row = (np.abs(y - MOUTH_Y) < 1e-9) & ~mouth_up & ~mouth_lo
    side_u = np.where(mouth_up | ((y > MOUTH_Y) & ~mouth_lo), 1.0, 0.0) + 0.5 * shared_row
    side_l = np.where(mouth_lo | ((y < MOUTH_Y) & ~mouth_up), 1.0, 0.0) + 0.5 * shared_row
    fr = (front > 0.2).astype(float)
    units = fapu.per_fap()
    T: dict[int, list] = {}

    def gx(c, s):
        return np.exp(-(((x - c) / s) ** 2))

    def add_lin(fap, part, w, direction, verts=None):
        w = np.asarray(w, dtype=np.float64)
        idx = np.nonzero(w > 0.02)[0]
        if idx.size == 0:
            return
        d = np.asarray(direction, dtype=np.float64)
        u = units[fap - 1]
        ww = w[idx]
        spec = mesh_from_function(
            part, idx, lambda a: (a * u * saturate(a, fap)) * ww[:, None] * d[None, :], fap_borders(fap), u
        )
        if spec is not None:
            T.setdefault(fap, []).append(spec)

    vin_u = np.exp(-(((y - MOUTH_Y) / 3.0) ** 2)) + 0.35 * np.exp(-(((y - MOUTH_Y - 6.5) / 4.0) ** 2))
    vin_l = np.exp(-(((y - MOUTH_Y) / 3.0) ** 2)) + 0.35 * np.exp(-(((y - MOUTH_Y + 7.0) / 4.0) ** 2))
    vout_u = np.exp(-(((y - MOUTH_Y - 6.5) / 3.5) ** 2)) + 0.5 * np.exp(-(((y - MOUTH_Y) / 3.0) ** 2))
    vout_l = np.exp(-(((y - MOUTH_Y + 7.0) / 3.5) ** 2)) + 0.5 * np.exp(-(((y - MOUTH_Y) / 3.0) ** 2))
    xc = tags["corner_x"]
    corner = {s: np.exp(-(((x - s * xc) / 13.0) ** 2 + ((y - MOUTH_Y) / 9.0) ** 2)) * fr for s in (1, -1)}
    corner_o = {s: np.exp(-(((x - s * (xc + 2)) / 15.0) ** 2 + ((y - MOUTH_Y) / 12.0) ** 2)) * fr for s in (1, -1)}
    lipx = np.exp(-((x / 22.0) ** 4)) * fr
    # --- group 2: jaw, inner lip, corners, chin
    hinge = np.array([0.0, 0.0, -20.0])
    chin = m.world(*m.feature_points["2.1"])
    cy, cz = (chin - hinge)[1:]
    c_r = float(np.hypot(cy, cz))
    wy = np.clip((MOUTH_Y - y) / (2.0 + np.maximum(np.abs(x) - 20.0, 0.0) * 0.6), 0.0, 1.0)
    wy = np.where(mouth_lo | ((np.abs(x) < xc - 0.1) & (y < MOUTH_Y)), 1.0, wy)
    wy = np.where(mouth_up, 0.0, wy)
    w_jaw = wy * np.clip((72.0 - np.abs(x)) / 30.0, 0.0, 1.0) * np.clip(front * 2.0, 0.0, 1.0)

    def jaw_rot(P, w, a):
        """Jaw opening: rotation about the hinge by drop / |hinge -> chin| (the shape of the opening)
        plus the translation that makes the chin (2.1) move exactly (0, -a * MNS, 0)."""
        drop = a * units[2]
        th = drop / c_r
        c, s_ = np.cos(th), np.sin(th)
        q = P - hinge
        q2 = np.stack([q[:, 0], q[:, 1] * c - q[:, 2] * s_, q[:, 1] * s_ + q[:, 2] * c], axis=1)
        chin_d = np.array([0.0, cy * c - cz * s_ - cy, cy * s_ + cz * c - cz])
        d = q2 - q + (np.array([0.0, -drop, 0.0]) - chin_d)[None, :]
        return d * w[:, None]

    jaw_parts = [
        ("Skin", V, w_jaw),
        ("LowerTeeth", m.parts["LowerTeeth"].vertices, None),
        ("Tongue", m.parts["Tongue"].vertices, None),
        ("Cavity", m.parts["Cavity"].vertices, "cav"),
    ]
    for part, P, w in jaw_parts:
        if w is None:
            w = np.ones(len(P))
        elif isinstance(w, str):
            w = np.clip((MOUTH_Y + 2.0 - P[:, 1]) / 8.0, 0.0, 1.0)
        idx = np.nonzero(w > 0.02)[0]
        spec = mesh_from_function(part, idx, lambda a, P=P[idx], w=w[idx]: jaw_rot(P, w, a), fap_borders(3), units[2])
        if spec is not None:
            T.setdefault(3, []).append(spec)
        for fap, d in ((14, (0, 0, 1)), (15, (-1, 0, 0))):
            ww = np.zeros(len(P))
            ww[idx] = w[idx]
            add_lin(fap, part, ww, d)
    add_lin(4, "Skin", side_u * gx(0, 10) * vin_u * fr, (0, -1, 0))
    add_lin(5, "Skin", side_l * gx(0, 10) * vin_l * fr, (0, 1, 0))
    add_lin(6, "Skin", corner[1], (1, 0, -0.5))
    add_lin(7, "Skin", corner[-1], (-1, 0, -0.5))
    add_lin(8, "Skin", side_u * gx(12, 7) * vin_u * fr, (0, -1, 0))
    add_lin(9, "Skin", side_u * gx(-12, 7) * vin_u * fr, (0, -1, 0))
    add_lin(10, "Skin", side_l * gx(12, 7) * vin_l * fr, (0, 1, 0))
    add_lin(11, "Skin", side_l * gx(-12, 7) * vin_l * fr, (0, 1, 0))
    add_lin(12, "Skin", corner[1], (0, 1, 0))
    add_lin(13, "Skin", corner[-1], (0, 1, 0))
    add_lin(16, "Skin", side_l * lipx * (vin_l + vout_l) * 0.6, (0, 0, 1))
    add_lin(17, "Skin", side_u * lipx * (vin_u + vout_u) * 0.6, (0, 0, 1))
    add_lin(18, "Skin", side_l * np.exp(-((x / 18.0) ** 2 + ((y + 72.0) / 10.0) ** 2)) * fr, (0, 1, 0))
    # --- group 3: eyelids (follow the eyeball), eyeballs and pupils (Transforms)
    shell = tags["eye_shell"]
    for side, _s, (ft, fb) in (("l", 1, (19, 21)), ("r", -1, (20, 22))):
        info = tags["eye_info"][side]
        up_c = np.zeros(len(V), bool)
        lo_c = np.zeros(len(V), bool)
        for a, b in tags["slit"]["eye_" + side]:
            lo_c[a] = True
            up_c[b] = True
        xrel = (x - info["mid"]) / info["half"]
        hu, hl = eye_open(xrel)
        r = np.where(np.abs(xrel) < 1, (hu + hl) / (2 * IRIS_R), 0.0)
        wwin = np.exp(-((((x - info["xc"]) / 15.5) ** 2 + ((y - EYE_Y) / 10.5) ** 2) ** 2)) * (front > 0)
        for fap, upper in ((ft, True), (fb, False)):
            if upper:
                sel = (up_c | ((y > EYE_Y) & ~lo_c)) & (r > 0)
                fall = np.where(up_c, 1.0, np.exp(-np.clip(y - (EYE_Y + hu), 0, None) / 4.0))
                sign = -1.0
            else:
                sel = (lo_c | ((y < EYE_Y) & ~up_c)) & (r > 0)
                fall = np.where(lo_c, 1.0, np.exp(-np.clip((EYE_Y - hl) - y, 0, None) / 4.0))
                sign = 1.0
            idx = np.nonzero(sel & (fall * r > 0.02))[0]
            u = units[fap - 1]

            def lid(a, idx=idx, fall=fall, sign=sign, info=info, u=u):
                c = a * u * (1.0 if sign < 0 else 0.5)  # the lower lid travels half as far
                dy = sign * c * r[idx] * fall[idx]
                ny = y[idx] + dy
                dz = wwin[idx] * (shell(x[idx], ny, info) - shell(x[idx], y[idx], info))
                return np.stack([np.zeros_like(dy), dy, dz], axis=1)

            spec = mesh_from_function("Skin", idx, lid, fap_borders(fap), u)
            if spec is not None:
                T.setdefault(fap, []).append(spec)
    for side, _s, (fy, fp_, ft, fd) in (("Left", 1, (23, 25, 27, 29)), ("Right", -1, (24, 26, 28, 30))):
        T[fy] = [TransformSpec(f"{side}Eye", 1, rotation=(0.0, 1.0, 0.0, 1.0))]
        T[fp_] = [TransformSpec(f"{side}Eye", 1, rotation=(1.0, 0.0, 0.0, 1.0))]
        T[ft] = [TransformSpec(f"{side}Eye", 3, translation=(0.0, 0.0, 1.0))]
        irisd0 = fapu.IRISD * 1024
        sd = 1.0 + 3.0 / irisd0
        T[fd] = [TransformSpec(f"{side}Pupil", 2, scale=(sd, sd, 1.0))]
    # --- group 4: eyebrows (brow strips + forehead skin)
    for side, s in (("Left", 1), ("Right", -1)):
        B = m.parts[f"{side}Brow"].vertices
        bx = B[:, 0]
        above = (y > EYE_Y + 6.0).astype(float) * fr
        for fap, cx in zip((31, 33, 35) if s > 0 else (32, 34, 36), (14.0, 31.0, 48.0)):
            add_lin(fap, f"{side}Brow", np.exp(-(((bx - s * cx) / 10.0) ** 2)), (0, 1, 0))
            add_lin(fap, "Skin", above * np.exp(-(((x - s * cx) / 11.0) ** 2 + ((y - 40.0) / 10.0) ** 2)), (0, 1, 0))
        fap = 37 if s > 0 else 38
        add_lin(fap, f"{side}Brow", np.exp(-(((bx - s * 13.0) / 16.0) ** 2)), (-s, 0, 0))
        add_lin(fap, "Skin", above * np.exp(-(((x - s * 16.0) / 11.0) ** 2 + ((y - 38.0) / 9.0) ** 2)), (-s, 0, 0))
    # --- group 5: cheeks
    for s, fp_, fl in ((1, 39, 41), (-1, 40, 42)):
        add_lin(fp_, "Skin", np.exp(-(((x - s * 42.0) ** 2 + (y + 28.0) ** 2) / 16.0**2)) * fr, (0.8 * s, 0, 0.6))
        add_lin(
            fl, "Skin", np.exp(-(((x - s * 40.0) ** 2 + (y + 6.0) ** 2) / 14.0**2)) * fr * (y < EYE_Y - 3.0), (0, 1, 0)
        )
    # --- group 6: tongue
    G = m.parts["Tongue"].vertices
    zt = (G[:, 2] - G[:, 2].min()) / np.ptp(G[:, 2])
    tip = zt**2
    add_lin(43, "Tongue", tip, (-1, 0, 0))
    add_lin(44, "Tongue", tip, (0, 1, 0))
    add_lin(45, "Tongue", tip, (0, 0, 1))
    add_lin(46, "Tongue", np.exp(-(((zt - 0.5) / 0.3) ** 2)), (0, 1, 0))
    roll = np.abs(G[:, 0] - G[:, 0].mean())
    spec = mesh_from_function(
        "Tongue",
        np.nonzero(roll > 1.0)[0],
        lambda a, rr=roll[roll > 1.0]: np.stack(
            [np.zeros_like(rr), a * units[46] * rr * saturate(a, 47), np.zeros_like(rr)], 1
        ),
        fap_borders(47),
        units[46],
    )
    T.setdefault(47, []).append(spec)
    # --- group 7: head rotation about the skull base (7.1)
    T[48] = [TransformSpec("Head", 1, rotation=(1.0, 0.0, 0.0, 1.0))]
    T[49] = [TransformSpec("Head", 1, rotation=(0.0, 1.0, 0.0, 1.0))]
    T[50] = [TransformSpec("Head", 1, rotation=(0.0, 0.0, 1.0, 1.0))]
    # --- group 8: outer lip
    add_lin(51, "Skin", side_u * gx(0, 10) * vout_u * fr, (0, -1, 0))
    add_lin(52, "Skin", side_l * gx(0, 10) * vout_l * fr, (0, 1, 0))
    add_lin(53, "Skin", corner_o[1], (1, 0, -0.5))
    add_lin(54, "Skin", corner_o[-1], (-1, 0, -0.5))
    add_lin(55, "Skin", side_u * gx(12, 7) * vout_u * fr, (0, -1, 0))
    add_lin(56, "Skin", side_u * gx(-12, 7) * vout_u * fr, (0, -1, 0))
    add_lin(57, "Skin", side_l * gx(12, 7) * vout_l * fr, (0, 1, 0))
    add_lin(58, "Skin", side_l * gx(-12, 7) * vout_l * fr, (0, 1, 0))
    add_lin(59, "Skin", corner_o[1], (0, 1, 0))
    add_lin(60, "Skin", corner_o[-1], (0, 1, 0))
    # --- group 9: nose
    add_lin(61, "Skin", np.exp(-(((x - 11.0) / 5.0) ** 2 + ((y + 15.0) / 6.0) ** 2)) * fr, (1, 0, 0))
    add_lin(62, "Skin", np.exp(-(((x + 11.0) / 5.0) ** 2 + ((y + 15.0) / 6.0) ** 2)) * fr, (-1, 0, 0))
    add_lin(63, "Skin", np.exp(-((x / 9.0) ** 2 + ((y + 11.0) / 8.0) ** 2)) * fr, (0, 1, 0))
    add_lin(
        64,
        "Skin",
        np.exp(-((x / 10.0) ** 2 + ((y + 9.0) / 11.0) ** 2)) * fr * np.clip((z - 95.0) / 15.0, 0.0, 1.0),
        (-1, 0, 0),
    )
    # --- group 10: ears
    for side, s, (fr_, fpull) in (("Left", 1, (65, 67)), ("Right", -1, (66, 68))):
        E = m.parts[f"{side}Ear"].vertices
        add_lin(fr_, f"{side}Ear", np.clip((E[:, 1] - E[:, 1].min()) / np.ptp(E[:, 1]), 0.3, 1.0), (0, 1, 0))
        add_lin(
            fpull,
            f"{side}Ear",
            np.clip(s * (E[:, 0] - E[:, 0].min() if s > 0 else E[:, 0] - E[:, 0].max()) / np.ptp(E[:, 0]), 0.2, 1.0),
            (s, 0, 0),
        )
    missing = [f for f in range(3, 69) if f not in T]
    if missing:
        raise RuntimeError(f"default head has no table for FAPs {missing}")
    return T
