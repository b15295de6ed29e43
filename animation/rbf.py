"""Radial basis function interpolation for calibration, with its linear system stated and checked.

Calibration (:mod:`.calibrate`) fits two interpolants: the 3D displacement field of the feature
points and the 2D map from projected feature points to texture coordinates. Both are the same
construction, written out here so that every reference implementation can solve the same system
and so that the reference never depends on how a LAPACK build treats a (nearly) singular one:

1. **Merging.** Data points closer to each other than ``MERGE_TOLERANCE`` times the extent of
   the point set (the largest coordinate range) are one data point: their position and value
   are the means of the group (groups are formed transitively, single linkage, in input order).
   Coincident points with different values cannot be interpolated; near-coincident ones make
   the system ill-conditioned.
2. **Normalisation.** Positions are centred on their mean and divided by the extent, so the
   system does not depend on the model's units.
3. **Kernel.** ``n`` merged points in ``k`` dimensions: one point is a constant (no system);
   ``n >= k + 1`` points whose affine hull is the whole space (rank of ``[1 | s]`` is ``k + 1``
   at tolerance 1e-9) use the thin-plate spline phi(r) = r^2 log r (phi(0) = 0) with a degree-1
   polynomial ``[1, x, y(, z)]``; any other set uses the linear kernel phi(r) = -r with a
   constant.
4. **System.** ``[[Phi, P], [P^T, 0]] [w; a] = [values; 0]`` with ``Phi_ij = phi(|s_i - s_j|)``;
   the interpolant is ``f(x) = sum_i w_i phi(|x - s_i|) + P(x) a``.
5. **Conditioning.** The 2-norm condition number of that matrix (ratio of its extreme singular
   values) must not exceed ``CONDITION_BOUND``; a larger one is refused (rule
   ``calibration-degenerate``, checker code FAP-SCENE-004) instead of being solved.

``CONDITION_BOUND`` = 1e8: a solve loses at most about log10(cond) of float64's ~16 digits, so
below the bound a solution keeps at least 8 significant digits on any LAPACK -- more than the
6 decimals the goldens are written at. ``MERGE_TOLERANCE`` = 1e-4 follows from it: measured on
the default head's 81 distinct feature points (condition number 4.1e5), one extra point at
1e-3, 1e-4, 1e-5 of the extent from another gives 2.9e6, 2.1e8, 1.6e10 (the condition number
grows as 1/distance^2), so points closer than 1e-4 are merged and a pair just outside the
tolerance (up to ~1.5e-4) is refused, not solved. Every suite scene is measured far below the
bound (``fbaconf suites build`` prints the worst).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fbaconf.errors import SceneError

MERGE_TOLERANCE = 1e-4
CONDITION_BOUND = 1e8
AFFINE_RANK_TOL = 1e-9


@dataclass
class RbfFit:
    """An interpolant ``R^k -> R^m`` through merged data points (see the module docstring)."""

    centre: np.ndarray  # float64[k]: subtracted before the division by scale
    scale: float
    nodes: np.ndarray  # float64[n, k]: normalised merged positions
    weights: np.ndarray  # float64[n, m] (empty for a constant)
    poly: np.ndarray  # float64[1 or k + 1, m]
    kernel: str  # "constant", "linear" or "thin_plate_spline"
    condition: float  # 2-norm condition number of the system (1.0 for a constant)
    merged: int  # data points merged away (input count - nodes)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        s = (x.reshape(-1, self.nodes.shape[1]) - self.centre) / self.scale
        out = np.broadcast_to(self.poly[0], (len(s), self.poly.shape[1])).copy()
        if self.kernel != "constant":
            out = out + _kernel(self.kernel, _distances(s, self.nodes)) @ self.weights
            if len(self.poly) > 1:
                out = out + s @ self.poly[1:]
        return out


def _distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(axis=-1))


def _kernel(name: str, r: np.ndarray) -> np.ndarray:
    if name == "linear":
        return -r
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0.0, r * r * np.log(np.where(r > 0.0, r, 1.0)), 0.0)


def merge_groups(points: np.ndarray, tolerance: float = MERGE_TOLERANCE) -> np.ndarray:
    """int[n]: the group of each point (0, 1, ... in order of first appearance); points closer
    than ``tolerance`` x the set's extent are in one group (transitively)."""
    p = np.asarray(points, dtype=np.float64)
    n = len(p)
    extent = float(np.ptp(p, axis=0).max()) if n else 0.0
    close = _distances(p, p) <= tolerance * extent
    group = np.full(n, -1)
    g = 0
    for i in range(n):
        if group[i] >= 0:
            continue
        stack, group[i] = [i], g
        while stack:
            j = stack.pop()
            for k in np.flatnonzero(close[j] & (group < 0)):
                group[k] = g
                stack.append(k)
        g += 1
    return group


def system(nodes: np.ndarray, kernel: str) -> np.ndarray:
    """The interpolation matrix ``[[Phi, P], [P^T, 0]]`` of normalised ``nodes``."""
    n, k = nodes.shape
    P = np.c_[np.ones(n), nodes] if kernel == "thin_plate_spline" else np.ones((n, 1))
    q = P.shape[1]
    A = np.zeros((n + q, n + q))
    A[:n, :n] = _kernel(kernel, _distances(nodes, nodes))
    A[:n, n:] = P
    A[n:, :n] = P.T
    return A


def condition(A: np.ndarray) -> float:
    """2-norm condition number (inf for a singular matrix)."""
    s = np.linalg.svd(A, compute_uv=False)
    return float(s[0] / s[-1]) if s[-1] > 0 else float("inf")


def fit(points: np.ndarray, values: np.ndarray, *, what: str, node_path: str | None = None) -> RbfFit:
    """The interpolant through ``points`` (float64[n, k]) with ``values`` (float64[n, m]).

    Raises SceneError(``calibration-empty``) without points and SceneError(``calibration-degenerate``)
    when the system's condition number exceeds CONDITION_BOUND; ``what`` names the fit in the message."""
    p = np.asarray(points, dtype=np.float64)
    v = np.asarray(values, dtype=np.float64).reshape(len(p), -1)
    if len(p) == 0:
        raise SceneError(f"{what}: needs at least one point", rule="calibration-empty", node_path=node_path)
    group = merge_groups(p)
    m = int(group.max()) + 1
    if m < len(p):
        p = np.array([p[group == g].mean(0) for g in range(m)])
        v = np.array([v[group == g].mean(0) for g in range(m)])
    merged = len(group) - m
    k = p.shape[1]
    centre = p.mean(0)
    scale = float(np.ptp(p, axis=0).max()) or 1.0
    s = (p - centre) / scale
    if m == 1:
        return RbfFit(centre, scale, s, np.zeros((0, v.shape[1])), v[:1].copy(), "constant", 1.0, merged)
    affine = m >= k + 1 and np.linalg.matrix_rank(np.c_[np.ones(m), s], tol=AFFINE_RANK_TOL) == k + 1
    kernel = "thin_plate_spline" if affine else "linear"
    A = system(s, kernel)
    cond = condition(A)
    if not cond <= CONDITION_BOUND:
        raise SceneError(
            f"{what}: the interpolation system is ill-conditioned (condition number {cond:.3g}, "
            f"bound {CONDITION_BOUND:.0e}): its solution would depend on the platform's LAPACK; "
            f"points too close to each other or nearly coplanar?",
            rule="calibration-degenerate",
            node_path=node_path,
        )
    rhs = np.zeros((len(A), v.shape[1]))
    rhs[:m] = v
    sol = np.linalg.solve(A, rhs)
    return RbfFit(centre, scale, s, sol[:m], sol[m:], kernel, cond, merged)
