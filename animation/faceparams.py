"""Feature points (84, groups 2-11) and FAPU computed from them.

Feature point labels follow spec notes section 5: group sizes 2:14, 3:14, 4:6, 5:4, 6:4,
7:1, 8:10, 9:15, 10:10, 11:6. Their canonical order (the order of FDP.featurePointsCoord)
is by label: group, then number ("3.14" before "4.1").

FAPU (spec notes 2.1, table ``bitstreams/data/fapu.csv``): IRISD0 = 3.1.y - 3.3.y,
ES0 = 3.5.x - 3.6.x, ENS0 = 3.5.y - 9.15.y, MNS0 = 9.15.y - 2.2.y, MW0 = 8.3.x - 8.4.x on
the neutral face; unit = distance / 1024; AU = 1e-5 rad.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fbaconf.bitstreams.tables import NUM_FAPS, fap_table, fapu_table
from fbaconf.errors import SceneError

FEATURE_POINT_GROUPS: dict[int, int] = {2: 14, 3: 14, 4: 6, 5: 4, 6: 4, 7: 1, 8: 10, 9: 15, 10: 10, 11: 6}
FEATURE_POINTS: tuple[str, ...] = tuple(f"{g}.{i}" for g, n in FEATURE_POINT_GROUPS.items() for i in range(1, n + 1))
NUM_FEATURE_POINTS = len(FEATURE_POINTS)  # 84
_FP_INDEX = {label: k for k, label in enumerate(FEATURE_POINTS)}
FAPU_NAMES = ("IRISD", "ES", "ENS", "MNS", "MW", "AU")
_AXIS = {"x": 0, "y": 1, "z": 2}


# fbaconf's convention for FDP subsets (docs/animation.md): featurePointsCoord lists the 84
# points in label order; a point whose three coordinates are all >= UNSENT (the SFFloat
# maximum) is "not sent". Shared by the engine and the checker.
UNSENT = 3.4e38


def fdp_point_rows(points) -> tuple[np.ndarray, np.ndarray]:
    """(float64[k, 3] rows, bool[k] sent) of a featurePointsCoord point list (k should be 84)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return pts, ~np.all(pts >= UNSENT, axis=1)


def fp_index(label: str) -> int:
    """Index of a feature point label ("3.5") in the canonical 84-point order."""
    try:
        return _FP_INDEX[label]
    except KeyError:
        raise KeyError(f"unknown feature point {label!r}") from None


@dataclass(frozen=True)
class Fapu:
    """FAPU values in model units (AU in radians)."""

    IRISD: float
    ES: float
    ENS: float
    MNS: float
    MW: float
    AU: float = 1e-5

    def unit(self, name: str) -> float:
        return float(getattr(self, name))

    def per_fap(self) -> np.ndarray:
        """float64[68]: the unit of each FAP (index = FAP number - 1; 1.0 for FAP 1/2)."""
        out = np.ones(NUM_FAPS, dtype=np.float64)
        for f in fap_table():
            if f.fapu:
                out[f.number - 1] = self.unit(f.fapu)
        return out

    def as_dict(self) -> dict[str, float]:
        return {n: self.unit(n) for n in FAPU_NAMES}


def points_to_dict(points) -> dict[str, np.ndarray]:
    """Accept a mapping label -> xyz or an array [84, 3] in canonical order (NaN rows = absent)."""
    if isinstance(points, Mapping):
        return {str(k): np.asarray(v, dtype=np.float64).reshape(3) for k, v in points.items()}
    arr = np.asarray(points, dtype=np.float64)
    if arr.shape != (NUM_FEATURE_POINTS, 3):
        raise SceneError(f"feature points must be [84, 3], got {arr.shape}", rule="fdp-feature-point-count")
    return {FEATURE_POINTS[k]: arr[k] for k in range(NUM_FEATURE_POINTS) if np.all(np.isfinite(arr[k]))}


def fapu_from_feature_points(points, *, node_path: str | None = None) -> Fapu:
    """FAPU of a neutral face from its feature points (mapping label -> xyz, or [84, 3])."""
    pts = points_to_dict(points)
    vals = {}
    for name, info in fapu_table().items():
        if info.unit_value is not None:
            vals[name] = info.unit_value
            continue
        for p in (info.point_a, info.point_b):
            if p not in pts:
                raise SceneError(
                    f"FAPU {name} needs feature point {p}, which the model does not define",
                    rule="fapu-missing-point",
                    node_path=node_path,
                )
        ax = _AXIS[info.axis]
        d = float(pts[info.point_a][ax] - pts[info.point_b][ax])
        if not np.isfinite(d) or d <= 0.0:
            raise SceneError(
                f"FAPU {name}0 = {info.point_a}.{info.axis} - {info.point_b}.{info.axis} = {d!r} "
                "must be positive on a neutral face",
                rule="fapu-degenerate",
                node_path=node_path,
            )
        vals[name] = d / info.divisor
    return Fapu(**{n: vals[n] for n in FAPU_NAMES})
