"""High-level FAPs: visemes (FAP 1) and expressions (FAP 2) -> low-level FAP values.

The default model's tables live in ``data/highlevel.csv`` (one row per viseme/expression
and low-level FAP). Blending per spec notes 2.2:

    viseme     = V[v1] * (blend/63) + V[v2] * (1 - blend/63)
    expression = E[e1] * (i1/63)    + E[e2] * (i2/63)

(select 0 = none contributes nothing). The viseme applies in frames where FAP 1's status
is not FREE, the expression where FAP 2's is not FREE. The sum viseme + expression is
written ONLY into low-level FAPs that are still FREE in that frame (IST 3.1.1: high-level
FAPs only affect FAPs that may be interpolated) and that the selected tables mention with a
non-zero weight; those become DERIVED. ``viseme_def``, ``expression_def`` and
``init_face`` are carried but not interpreted (no table learning).

A scene may replace a viseme/expression by its own FaceDefTables (fapID 1/2 with
``highLevelSelect`` = the viseme/expression number); such tables deform the model directly
(see engine) and the default table entry for that number is then not used.
"""

from __future__ import annotations

import csv
from functools import lru_cache
from importlib import resources

import numpy as np

from fbaconf.bitstreams.frames import DERIVED, FREE
from fbaconf.bitstreams.tables import NUM_FAPS, fap_by_name

NUM_VISEMES = 14
NUM_EXPRESSIONS = 6


@lru_cache(maxsize=1)
def default_tables() -> tuple[np.ndarray, np.ndarray]:
    """(visemes float64[15, 68], expressions float64[7, 68]); row 0 (none/neutral) is zero."""
    text = resources.files("fbaconf.animation").joinpath("data", "highlevel.csv").read_text("utf-8")
    rows = csv.DictReader([ln for ln in text.splitlines() if ln.strip() and not ln.startswith("#")])
    vis = np.zeros((NUM_VISEMES + 1, NUM_FAPS))
    exp = np.zeros((NUM_EXPRESSIONS + 1, NUM_FAPS))
    for r in rows:
        table, top = (vis, NUM_VISEMES) if r["kind"] == "viseme" else (exp, NUM_EXPRESSIONS)
        if r["kind"] not in ("viseme", "expression"):
            raise RuntimeError(f"highlevel.csv: bad kind {r['kind']!r}")
        n = int(r["number"])
        if not 1 <= n <= top:
            raise RuntimeError(f"highlevel.csv: {r['kind']} number {n} out of range")
        fap = fap_by_name(r["fap"]).number
        if fap < 3:
            raise RuntimeError("highlevel.csv: only low-level FAPs may be listed")
        table[n, fap - 1] = float(r["value"])
    vis.setflags(write=False)
    exp.setflags(write=False)
    return vis, exp


def high_level_weights(high: np.ndarray, status: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame weights of each viseme [F, 15] and expression [F, 7] (column 0 unused = 0).

    ``high`` int[F, 10] in HIGH_LEVEL_FIELDS order; ``status`` uint8[F, 68]. Selections out of
    range (viseme > 14, expression > 6; the BIFS fields allow up to 31) contribute nothing."""
    high = np.asarray(high)
    F = high.shape[0]
    rows = np.arange(F)
    wv = np.zeros((F, NUM_VISEMES + 1))
    we = np.zeros((F, NUM_EXPRESSIONS + 1))
    vis_on = status[:, 0] != FREE
    exp_on = status[:, 1] != FREE
    v1, v2, blend = high[:, 0], high[:, 1], high[:, 2] / 63.0
    e1, i1, e2, i2 = high[:, 4], high[:, 5] / 63.0, high[:, 6], high[:, 7] / 63.0
    for sel, w, on, table, top in (
        (v1, blend, vis_on, wv, NUM_VISEMES),
        (v2, 1.0 - blend, vis_on, wv, NUM_VISEMES),
        (e1, i1, exp_on, we, NUM_EXPRESSIONS),
        (e2, i2, exp_on, we, NUM_EXPRESSIONS),
    ):
        ok = on & (sel >= 1) & (sel <= top)
        np.add.at(table, (rows[ok], sel[ok]), w[ok])
    return wv, we


def apply_high_level(
    values: np.ndarray,
    status: np.ndarray,
    high: np.ndarray,
    tables: tuple[np.ndarray, np.ndarray] | None = None,
    exclude_visemes=(),
    exclude_expressions=(),
) -> tuple[np.ndarray, np.ndarray]:
    """Blend visemes/expressions into the FREE low-level FAPs.

    ``values`` float64[F, 68], ``status`` uint8[F, 68] (not modified); returns new
    (values, status). ``exclude_*``: numbers handled by scene FaceDefTables instead."""
    vis, exp = tables if tables is not None else default_tables()
    vis = np.array(vis, dtype=np.float64)
    exp = np.array(exp, dtype=np.float64)
    vis[list(exclude_visemes)] = 0.0
    exp[list(exclude_expressions)] = 0.0
    wv, we = high_level_weights(high, status)
    contrib = wv @ vis + we @ exp
    touched = (wv @ (vis != 0)) + (we @ (exp != 0)) > 0
    touched[:, :2] = False
    target = touched & (status == FREE)
    values = np.where(target, contrib, values)
    status = np.where(target, np.uint8(DERIVED), status).astype(np.uint8)
    return values, status
