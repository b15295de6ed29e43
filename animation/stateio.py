"""FaceState <-> .npz (the ``fbaconf animate`` output; the "vertices" output of docs/harness.md).

Arrays: ``format`` = "fbaconf.FaceState/1", ``vertices`` float64[F, N, 3], ``time_ms``
float64[F], ``part_names`` str[P], ``part_first`` / ``part_count`` int64[P],
``part_color`` float64[P, 3], ``triangles`` int64[M, 3] (global vertex indices),
``triangle_part`` int64[M], and every FaceState extra as ``extra_<name>``.
"""

from __future__ import annotations

import io

import numpy as np

from fbaconf._atomic import atomic_write_bytes

from .facestate import FaceState, MeshPart

FORMAT = "fbaconf.FaceState/1"


def to_npz_bytes(state: FaceState) -> bytes:
    tris = [np.asarray(p.triangles, np.int64) + p.first_vertex for p in state.parts]
    tpart = [np.full(len(t), i, np.int64) for i, t in enumerate(tris)]
    arrays = dict(
        format=np.array(FORMAT),
        vertices=state.vertices,
        time_ms=state.time_ms,
        part_names=np.array([p.name for p in state.parts]),
        part_first=np.array([p.first_vertex for p in state.parts], np.int64),
        part_count=np.array([p.vertex_count for p in state.parts], np.int64),
        part_color=np.array([p.color for p in state.parts], np.float64).reshape(-1, 3),
        triangles=np.concatenate(tris) if tris else np.zeros((0, 3), np.int64),
        triangle_part=np.concatenate(tpart) if tpart else np.zeros(0, np.int64),
    )
    for k, v in state.extras.items():
        arrays[f"extra_{k}"] = v
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def save_npz(state: FaceState, path) -> None:
    atomic_write_bytes(path, to_npz_bytes(state))


def load_npz(path) -> FaceState:
    with np.load(path, allow_pickle=False) as z:
        if "format" not in z or str(z["format"]) != FORMAT:
            raise ValueError(f"not an {FORMAT} .npz file")
        tris, tpart = z["triangles"], z["triangle_part"]
        parts = []
        for i, name in enumerate(z["part_names"]):
            first = int(z["part_first"][i])
            parts.append(
                MeshPart(
                    str(name),
                    first,
                    int(z["part_count"][i]),
                    tris[tpart == i] - first,
                    tuple(float(c) for c in z["part_color"][i]),
                )
            )
        extras = {k[6:]: z[k] for k in z.files if k.startswith("extra_")}
        return FaceState(parts, z["vertices"], z["time_ms"], extras)
