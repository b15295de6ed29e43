"""The vertex stage: per-frame maximum and RMS euclidean error of the animated mesh, the first vertex
named with its mesh part."""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from fbaconf.harness.results import Outcome, StageResult


class MeshPart(Protocol):
    """A named run of a mesh's vertices (animation's FaceState parts)."""

    @property
    def name(self) -> str: ...
    @property
    def first_vertex(self) -> int: ...
    @property
    def vertex_count(self) -> int: ...


def part_namer(parts: Iterable[MeshPart | tuple[str, int, int]]) -> Callable[[int], str | None]:
    """A ``part_of(vertex_index)`` callback from FaceState mesh parts (objects with
    ``name``, ``first_vertex``, ``vertex_count``) or ``(name, first, count)`` tuples."""
    rows = sorted(
        (int(p[1]), int(p[2]), str(p[0]))
        if isinstance(p, (tuple, list))
        else (int(p.first_vertex), int(p.vertex_count), str(p.name))
        for p in parts
    )
    starts = [r[0] for r in rows]

    def part_of(i: int) -> str | None:
        k = bisect.bisect_right(starts, i) - 1
        if k >= 0 and rows[k][0] <= i < rows[k][0] + rows[k][1]:
            return rows[k][2]
        return None

    return part_of


def compare_vertices(
    expected: np.ndarray,
    got: np.ndarray,
    *,
    max_tol: float,
    rms_tol: float,
    part_of: Callable[[int], str | None] | None = None,
    what: str = "vertices",
) -> StageResult:
    """Compare float[F, N, 3] vertex (or feature point) positions.

    Fail on a shape mismatch (naming the axis), on NaN/inf in ``got`` (naming the first
    frame/vertex), or when a frame's maximum euclidean error exceeds ``max_tol`` or its RMS
    error exceeds ``rms_tol``. ``first_difference`` names the first frame and the first
    vertex above ``max_tol`` (when only the RMS is exceeded: the first such frame and its
    worst vertex) with part (via ``part_of``), expected, got and distance. Error (harness
    problem) when ``expected`` itself is malformed or not finite. ``series``: per-frame
    ``max_error`` and ``rms_error``."""
    exp = np.asarray(expected)
    gt = np.asarray(got)
    if exp.ndim != 3 or exp.shape[2] != 3 or exp.dtype.kind not in "fiu" or not np.isfinite(exp).all():
        return StageResult(
            what,
            Outcome.ERROR,
            f"golden {what} are not a finite float[F, N, 3] array (shape {list(exp.shape)}, dtype {exp.dtype})",
        )
    if gt.dtype.kind not in "fiu":
        return StageResult(
            what,
            Outcome.FAIL,
            f"{what}: dtype {gt.dtype} is not numeric",
            {"what": "dtype", "expected": "float", "got": str(gt.dtype)},
        )
    if gt.ndim != 3:
        return StageResult(
            what,
            Outcome.FAIL,
            f"{what}: shape {list(gt.shape)}, expected {list(exp.shape)} ([frames, vertices, 3])",
            {"what": "shape", "expected": list(exp.shape), "got": list(gt.shape)},
        )
    for axis, label in enumerate(("frame count", "vertex count", "coordinate count")):
        if exp.shape[axis] != gt.shape[axis]:
            first: dict[str, Any] = {
                "what": label,
                "axis": axis,
                "expected": int(exp.shape[axis]),
                "got": int(gt.shape[axis]),
            }
            if axis == 0:
                first["frame"] = int(min(exp.shape[0], gt.shape[0]))
            return StageResult(
                what,
                Outcome.FAIL,
                f"{what}: {label} (axis {axis}): expected {exp.shape[axis]}, got {gt.shape[axis]}",
                first,
            )
    exp = exp.astype(np.float64)
    gt = gt.astype(np.float64)
    F, N = exp.shape[:2]

    def locate(f: int, v: int, **extra: object) -> dict[str, Any]:
        d: dict[str, Any] = {"frame": f, "vertex": v}
        if part_of is not None:
            d["part"] = part_of(v)
        d.update(expected=exp[f, v].tolist(), got=gt[f, v].tolist(), **extra)
        return d

    def part_txt(d: dict[str, Any]) -> str:
        return f" ({d['part']})" if d.get("part") else ""

    bad = ~np.isfinite(gt).all(axis=2)
    if bad.any():
        f, v = (int(x[0]) for x in np.nonzero(bad))
        first = locate(f, v, what="non-finite")
        return StageResult(
            what,
            Outcome.FAIL,
            f"{what}: frame {f}, vertex {v}{part_txt(first)} is not finite: "
            f"expected {first['expected']}, got {first['got']}",
            first,
            {"frames_compared": float(F), "vertices": float(N), "nonfinite_values": float((~np.isfinite(gt)).sum())},
        )
    dist = np.sqrt(((gt - exp) ** 2).sum(axis=2)) if N else np.zeros((F, 0))
    fmax = dist.max(axis=1, initial=0.0)
    frms = np.sqrt((dist**2).mean(axis=1)) if N else np.zeros(F)
    series = {"max_error": [float(x) for x in fmax], "rms_error": [float(x) for x in frms]}
    over_max = fmax > max_tol
    over_rms = frms > rms_tol
    metrics = {
        "frames_compared": float(F),
        "vertices": float(N),
        "max_error": float(np.max(fmax, initial=0.0)),
        "rms_error": float(np.max(frms, initial=0.0)),
        "frames_over_max": float(over_max.sum()),
        "frames_over_rms": float(over_rms.sum()),
        "max_tol": float(max_tol),
        "rms_tol": float(rms_tol),
    }
    summary = (
        f"max error {metrics['max_error']:.6g} (tolerance {max_tol:g}), "
        f"rms {metrics['rms_error']:.6g} (tolerance {rms_tol:g}) over {F} frame(s) x {N} {what}"
    )
    if not over_max.any() and not over_rms.any():
        return StageResult(what, Outcome.PASS, summary, None, metrics, series)
    if over_max.any():
        f = int(np.nonzero(over_max)[0][0])
        v = int(np.nonzero(dist[f] > max_tol)[0][0])
        first = locate(f, v, distance=float(dist[f, v]), what="max")
        why = f"error {dist[f, v]:.6g} > max tolerance {max_tol:g}"
    else:
        f = int(np.nonzero(over_rms)[0][0])
        v = int(np.argmax(dist[f]))
        first = locate(f, v, distance=float(dist[f, v]), what="rms", rms=float(frms[f]))
        why = f"frame rms {frms[f]:.6g} > rms tolerance {rms_tol:g}; worst vertex error {dist[f, v]:.6g}"
    msg = (
        f"{what}: first at frame {f}, vertex {v}{part_txt(first)}: {why}: expected "
        f"{_fmt_xyz(first['expected'])}, got {_fmt_xyz(first['got'])}; {summary}"
    )
    return StageResult(what, Outcome.FAIL, msg, first, metrics, series)


def _fmt_xyz(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"
