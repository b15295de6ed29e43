"""FaceDefTables: FaceDefMesh (piecewise-linear vertex trajectories) and FaceDefTransform.

FaceDefMesh -- Ostermann 1998 section 2.3.2, steps 1-6, implemented literally:

* ``intervalBorders`` I_1 < I_2 < ... < I_max (strictly increasing) define n = max - 1
  intervals [I_j, I_j+1]; ``displacements`` hold n 3D vectors per vertex listed in
  ``coordIndex``, vertex-major (vertex 0's n displacements, then vertex 1's, ...), exactly
  as Table 3 of the seed lists them.
* With more than one interval, one border must be 0 (= I_k; the seed's formula assumes it).
* FAP >= 0 (step 2, step 3 beyond I_max):
  P' = P + FAPU * ((I_k+1 - 0) D_k + ... + (I_j - I_j-1) D_j-1 + (FAP - I_j) D_j).
* FAP < 0 (step 4, step 5 below I_1):
  P' = P + FAPU * ((I_j+1 - FAP) D_j + ... + (0 - I_k-1) D_k-1).
  Note the seed's step 4 uses the *positive* lengths of the covered intervals: the
  displacement of a negative-side interval is per unit of |FAP|. We follow it literally
  (a model that should move the opposite way for negative FAPs stores negated vectors for
  the negative intervals; the Ostermann-Haratsch example table has that sign pattern).
* One interval only (step 6): P' = P + FAPU * FAP * D_1 (signed FAP, borders ignored).
* Defined behaviour where the seed is silent: when 0 is the top border and FAP > 0, or
  the bottom border and FAP < 0, the interval touching 0 is extended across 0 along its
  own line (weight -FAP resp. FAP), just as steps 3 and 5 extend the outer intervals.
  Weights are therefore continuous in FAP everywhere.

FaceDefTransform -- fbaconf's reading (the seeds say only "the received value for the FAP
and the neutral value determine the actual value"; the example: "the rotation axis is
(0,-1,0) and the multiplication factor for the angle is 1. The FAP value determines the
rotation angle"). With a = FAP * FAPU (FAPU of that FAP; AU = 1e-5 rad for angles):

* ``fieldId`` 1 = rotation, 2 = scale, 3 = translation (any other value: SceneError).
* rotation: R = R_neutral * R(axis of rotationDef, a * angle of rotationDef)
  (the FAP rotation is applied in the Transform's frame before its neutral rotation).
* scale: s = s_neutral * (1 + a * (scaleDef - 1)) componentwise (scaleDef is the scale
  reached at a = 1, linear in a like the other two).
* translation: t = t_neutral + a * translationDef.
* Several tables on the same Transform field accumulate in ascending fapID order.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fbaconf.errors import SceneError

FIELD_IDS = {1: "rotation", 2: "scale", 3: "translation"}


# ---------------------------------------------------------------------------------- mesh
def validate_borders(borders, *, node_path: str | None = None) -> np.ndarray:
    b = np.asarray(borders, dtype=np.float64).reshape(-1)
    if b.size < 2:
        raise SceneError(
            f"intervalBorders needs at least 2 borders (1 interval), got {b.size}",
            rule="facedef-interval-count",
            node_path=node_path,
        )
    if not np.all(np.isfinite(b)):
        raise SceneError("intervalBorders must be finite", rule="facedef-borders-finite", node_path=node_path)
    if np.any(np.diff(b) <= 0):
        k = int(np.nonzero(np.diff(b) <= 0)[0][0])
        raise SceneError(
            f"intervalBorders must be strictly increasing: border {k + 1} ({b[k + 1]:g}) <= border {k} ({b[k]:g})",
            rule="facedef-borders-unsorted",
            node_path=node_path,
        )
    if b.size > 2 and not np.any(b == 0):
        raise SceneError(
            "with more than one interval, one of the intervalBorders must be 0",
            rule="facedef-borders-zero",
            node_path=node_path,
        )
    return b


def interval_weights(borders, fap) -> np.ndarray:
    """float64[F, n]: coefficient of D_j (interval j) for each FAP value (steps 1-6).

    The displacement of a vertex is ``FAPU * weights @ D`` with D its [n, 3] displacements.
    ``borders`` must have passed :func:`validate_borders`."""
    b = np.asarray(borders, dtype=np.float64)
    f = np.asarray(fap, dtype=np.float64).reshape(-1)[:, None]
    n = b.size - 1
    if n == 1:
        return f.copy()  # step 6: strictly linear
    k = int(np.nonzero(b == 0)[0][0])
    lo, hi = b[:-1][None, :], b[1:][None, :]
    length = hi - lo
    idx = np.arange(n)[None, :]
    pos_side = idx >= k
    neg_side = ~pos_side
    # FAP >= 0: intervals above 0 filled up to FAP; the last one is open upwards (step 3).
    wp = np.clip(f - lo, 0.0, length)
    wp = np.where(idx == n - 1, np.maximum(f - lo, 0.0), wp)
    wp = np.where(pos_side, wp, 0.0)
    # FAP < 0: intervals below 0 filled down to FAP; the first one is open downwards (step 5).
    wn = np.clip(hi - f, 0.0, length)
    wn = np.where(idx == 0, np.maximum(hi - f, 0.0), wn)
    wn = np.where(neg_side, wn, 0.0)
    if k == n:  # 0 is the top border: extend interval n-1 across 0 for FAP > 0
        wp = np.where(idx == n - 1, -f, 0.0)
    if k == 0:  # 0 is the bottom border: extend interval 0 across 0 for FAP < 0
        wn = np.where(idx == 0, f, 0.0)
    return np.where(f >= 0, wp, wn)


@dataclass
class MeshTable:
    """One FaceDefMesh of one FaceDefTables: FAP ``fap`` moves vertices ``indices`` of ``target``."""

    fap: int  # 1..68 (1/2 with high_level_select for high-level tables)
    target: str  # key of the IndexedFaceSet in the compiled model
    borders: np.ndarray  # float64[n + 1]
    indices: np.ndarray  # int64[V]
    displacements: np.ndarray  # float64[V, n, 3]
    high_level_select: int = 1
    node_path: str | None = None

    @classmethod
    def build(
        cls,
        fap: int,
        target: str,
        borders,
        coord_index,
        displacements,
        n_vertices: int,
        *,
        high_level_select: int = 1,
        node_path: str | None = None,
    ) -> MeshTable:
        b = validate_borders(borders, node_path=node_path and node_path + ".intervalBorders")
        n = b.size - 1
        idx = np.asarray(coord_index, dtype=np.int64).reshape(-1)
        d = np.asarray(displacements, dtype=np.float64).reshape(-1, 3) if np.size(displacements) else np.zeros((0, 3))
        if np.size(displacements) % 3:
            raise SceneError(
                "displacements must be 3D vectors",
                rule="facedef-displacement-count",
                node_path=node_path and node_path + ".displacements",
            )
        if d.shape[0] != n * idx.size:
            raise SceneError(
                f"{d.shape[0]} displacements for {idx.size} vertices x {n} intervals (need {n * idx.size})",
                rule="facedef-displacement-count",
                node_path=node_path and node_path + ".displacements",
            )
        bad = np.nonzero((idx < 0) | (idx >= n_vertices))[0]
        if bad.size:
            raise SceneError(
                f"coordIndex[{int(bad[0])}] = {int(idx[bad[0]])} names a vertex the mesh does not "
                f"have (it has {n_vertices})",
                rule="facedef-missing-vertex",
                node_path=node_path and node_path + ".coordIndex",
            )
        if not np.all(np.isfinite(d)):
            raise SceneError(
                "displacements must be finite",
                rule="facedef-displacement-finite",
                node_path=node_path and node_path + ".displacements",
            )
        return cls(fap, target, b, idx, d.reshape(idx.size, n, 3), high_level_select, node_path)

    def displacement(self, fap_values, fapu: float) -> np.ndarray:
        """float64[F, V, 3] displacement of the table's vertices for FAP values [F]."""
        w = interval_weights(self.borders, fap_values)
        return fapu * np.einsum("fn,vnd->fvd", w, self.displacements)

    def apply(self, positions: np.ndarray, fap_values, fapu: float) -> None:
        """Add the displacement to ``positions`` [F, N, 3] in place (duplicate indices add up)."""
        disp = self.displacement(fap_values, fapu)
        if np.unique(self.indices).size == self.indices.size:
            positions[:, self.indices, :] += disp
        else:
            np.add.at(positions, (slice(None), self.indices), disp)


# ---------------------------------------------------------------------------------- transform
def axis_angle_matrices(axis, angles) -> np.ndarray:
    """float64[F, 3, 3] rotation matrices (right-handed, VRML SFRotation) for angles [F]."""
    a = np.asarray(axis, dtype=np.float64).reshape(3)
    nrm = np.linalg.norm(a)
    ang = np.asarray(angles, dtype=np.float64).reshape(-1)
    if nrm == 0.0:
        return np.broadcast_to(np.eye(3), (ang.size, 3, 3)).copy()
    x, y, z = a / nrm
    c, s = np.cos(ang), np.sin(ang)
    C = 1.0 - c
    m = np.empty((ang.size, 3, 3))
    m[:, 0, 0] = c + x * x * C
    m[:, 0, 1] = x * y * C - z * s
    m[:, 0, 2] = x * z * C + y * s
    m[:, 1, 0] = y * x * C + z * s
    m[:, 1, 1] = c + y * y * C
    m[:, 1, 2] = y * z * C - x * s
    m[:, 2, 0] = z * x * C - y * s
    m[:, 2, 1] = z * y * C + x * s
    m[:, 2, 2] = c + z * z * C
    return m


@dataclass
class TransformTable:
    """One FaceDefTransform: FAP ``fap`` drives field ``field`` of Transform ``target``."""

    fap: int
    target: str
    field: str  # rotation | scale | translation
    rotation: tuple[float, float, float, float] = (0.0, 0.0, 1.0, 0.0)
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0)
    translation: tuple[float, float, float] = (0.0, 0.0, 0.0)
    high_level_select: int = 1
    node_path: str | None = None

    @classmethod
    def build(
        cls,
        fap: int,
        target: str,
        field_id: int,
        rotation=(0, 0, 1, 0),
        scale=(1, 1, 1),
        translation=(0, 0, 0),
        *,
        high_level_select: int = 1,
        node_path: str | None = None,
    ) -> TransformTable:
        if field_id not in FIELD_IDS:
            raise SceneError(
                f"fieldId {field_id} is not 1 (rotation), 2 (scale) or 3 (translation)",
                rule="facedef-field-id",
                node_path=node_path and node_path + ".fieldId",
            )
        vals = [float(v) for v in (*rotation, *scale, *translation)]
        if not all(np.isfinite(vals)):
            raise SceneError(
                "rotationDef/scaleDef/translationDef must be finite",
                rule="facedef-transform-finite",
                node_path=node_path,
            )
        return cls(
            fap,
            target,
            FIELD_IDS[field_id],
            tuple(vals[:4]),
            tuple(vals[4:7]),
            tuple(vals[7:]),
            high_level_select,
            node_path,
        )


def transform_fields(neutral: dict, tables: list[TransformTable], fap_of, fapu_of) -> dict[str, np.ndarray]:
    """Per-frame rotation matrices, scales and translations of one Transform.

    ``neutral``: dict with 'rotation' (4), 'scale' (3), 'translation' (3) of the node;
    ``fap_of(table)`` -> float64[F] FAP (or high-level amplitude) values; ``fapu_of(table)`` -> unit.
    Returns {'R': [F,3,3], 'scale': [F,3], 'translation': [F,3]} (F from the FAP arrays) or
    broadcastable [1, ...] arrays when no table applies."""
    r0 = neutral.get("rotation", (0, 0, 1, 0))
    R = axis_angle_matrices(r0[:3], [r0[3]])
    s = np.asarray(neutral.get("scale", (1, 1, 1)), dtype=np.float64).reshape(1, 3)
    t = np.asarray(neutral.get("translation", (0, 0, 0)), dtype=np.float64).reshape(1, 3)
    for tab in sorted(tables, key=lambda x: (x.fap, x.high_level_select)):
        a = np.asarray(fap_of(tab), dtype=np.float64).reshape(-1) * fapu_of(tab)
        if tab.field == "rotation":
            R = R @ axis_angle_matrices(tab.rotation[:3], a * tab.rotation[3])
        elif tab.field == "scale":
            s = s * (1.0 + a[:, None] * (np.asarray(tab.scale) - 1.0)[None, :])
        else:
            t = t + a[:, None] * np.asarray(tab.translation)[None, :]
    return {"R": R, "scale": s, "translation": t}
