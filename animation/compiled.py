"""A compiled face: neutral geometry in local coordinates, its transforms and animation
rules, ready for the engine (:mod:`.engine`) to animate and for calibration
(:mod:`.calibrate`) to warp."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .facedef import MeshTable, TransformTable, axis_angle_matrices
from .faceparams import Fapu
from .interp import FitGraph


@dataclass
class PartInstance:
    name: str
    ifs: int  # key of the IndexedFaceSet (id of its node)
    chain: list[int]  # transform keys, root first
    triangles: np.ndarray
    color: tuple
    vertex_colors: np.ndarray | None = None
    texcoords: np.ndarray | None = None
    texture: str | None = None
    specular: float = 0.0
    shininess: float = 0.2


@dataclass
class CompiledFace:
    """A face model ready to animate (neutral geometry in local coordinates + rules)."""

    points: dict[int, np.ndarray]  # IFS key -> float64[n, 3] neutral local points
    ifs_names: dict[int, str]
    transforms: dict[int, dict]  # key -> {name, center, rotation, scale, scaleOrientation, translation}
    parts: list[PartInstance]
    mesh_tables: list[MeshTable]
    transform_tables: list[TransformTable]
    fapu: Fapu
    feature_points: np.ndarray  # float64[84, 3] neutral world; NaN rows = not defined
    fit: FitGraph | None = None
    high_level_tables: tuple | None = None  # (visemes, expressions) low-level tables, None = default
    fp_vertices: list | None = None  # per feature point (part index, vertex) or None
    useOrtho: bool = False
    extras: dict = field(default_factory=dict)


def local_matrices(tr: dict, fields: dict | None, F: int) -> np.ndarray:
    """float64[F, 4, 4] local matrix of one Transform (VRML order)."""
    if fields is None:
        r = tr["rotation"]
        R = axis_angle_matrices(r[:3], [r[3]])
        S = np.asarray(tr["scale"], dtype=np.float64).reshape(1, 3)
        Tt = np.asarray(tr["translation"], dtype=np.float64).reshape(1, 3)
    else:
        R, S, Tt = fields["R"], fields["scale"], fields["translation"]
    so = tr["scaleOrientation"]
    SR = axis_angle_matrices(so[:3], [so[3]])[0]
    C = np.asarray(tr["center"], dtype=np.float64)
    n = max(R.shape[0], S.shape[0], Tt.shape[0])
    lin = R @ (SR[None] @ (S[:, :, None] * SR.T[None]))  # R * SR * S * SR^-1
    lin = np.broadcast_to(lin, (n, 3, 3))
    M = np.zeros((n, 4, 4))
    M[:, :3, :3] = lin
    M[:, :3, 3] = np.broadcast_to(Tt, (n, 3)) + C - np.einsum("fij,j->fi", lin, C)
    M[:, 3, 3] = 1.0
    return M if n == F else np.broadcast_to(M, (F, 4, 4)) if n == 1 else M


def neutral_world(model: CompiledFace) -> list[np.ndarray]:
    """World positions of every part's vertices in the neutral face."""
    mats = {k: local_matrices(tr, None, 1)[0] for k, tr in model.transforms.items()}
    out = []
    for p in model.parts:
        M = np.eye(4)
        for k in p.chain:
            M = M @ mats[k]
        P = model.points[p.ifs]
        out.append(P @ M[:3, :3].T + M[:3, 3])
    return out
