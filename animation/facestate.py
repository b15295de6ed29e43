"""FaceState: the value passed from the animation stage to the rendering stage.

Topology is static over a sequence, positions change per frame, so a FaceState holds
the mesh parts once and the vertex positions of all parts for all frames in one array
(vectorised over frames and vertices):

``vertices``  float64[n_frames, n_vertices, 3]  world-space positions (every Transform of
              the scene graph already applied) of all parts, concatenated in part order.
``parts``     the mesh parts; part ``p`` owns rows ``p.first_vertex : p.first_vertex +
              p.vertex_count`` of the vertex axis.

Coordinates follow VRML/BIFS: y up, +z towards the viewer, right-handed; units are
those of the scene (the bundled models use millimetres-like units, see animation docs).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class MeshPart:
    name: str
    first_vertex: int
    vertex_count: int
    triangles: np.ndarray  # int32[m, 3], indices local to the part (0 .. vertex_count-1), CCW = front
    color: tuple[float, float, float] = (0.8, 0.8, 0.8)  # diffuse, linear RGB in [0, 1]
    vertex_colors: np.ndarray | None = None  # float32[vertex_count, 3] linear RGB, overrides color
    texcoords: np.ndarray | None = None  # float64[vertex_count, 2] in [0, 1], v up
    texture: str | None = None  # image path (absolute, or relative to the scene file)
    specular: float = 0.0  # specular intensity in [0, 1]
    shininess: float = 0.2  # VRML Material.shininess in [0, 1]

    def __post_init__(self) -> None:
        self.triangles = np.asarray(self.triangles, dtype=np.int32).reshape(-1, 3)


@dataclass
class FaceState:
    parts: list[MeshPart]
    vertices: np.ndarray  # float64[n_frames, n_vertices, 3]
    time_ms: np.ndarray  # float64[n_frames]
    # Optional per-frame extras (e.g. feature point positions) keyed by name.
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        if self.vertices.ndim != 3 or self.vertices.shape[2] != 3:
            raise ValueError("FaceState.vertices must be float64[n_frames, n_vertices, 3]")
        self.time_ms = np.asarray(self.time_ms, dtype=np.float64).reshape(self.vertices.shape[0])
        total = sum(p.vertex_count for p in self.parts)
        if total != self.vertices.shape[1]:
            raise ValueError(f"parts own {total} vertices but the array has {self.vertices.shape[1]}")

    @property
    def n_frames(self) -> int:
        return self.vertices.shape[0]

    def part_vertices(self, part: MeshPart, frame: int) -> np.ndarray:
        return self.vertices[frame, part.first_vertex : part.first_vertex + part.vertex_count]

    def frame(self, k: int) -> FaceState:
        return FaceState(
            self.parts,
            self.vertices[k : k + 1],
            self.time_ms[k : k + 1],
            {n: a[k : k + 1] for n, a in self.extras.items()},
        )
