"""The float goldens: the rounding step each is written at, its margin to that step, and the
tolerance ``fbaconf golden verify`` falls back to where regeneration is not byte for byte.

A regenerated golden is byte-identical on another platform (numpy, BLAS, libm, CPU) only when
no value sits within that platform's float noise of the boundary of the step it is rounded at:

* FaceState arrays ``vertices``, ``extra_feature_points`` (stored as float32) and
  ``extra_fap_values`` (float64) are rounded to ``DECIMALS`` = 6 decimals: the boundaries are
  the half-steps (k + 1/2) x 1e-6.
* PNG images are ``floor(e x 255 + 1/2)`` of the sRGB-encoded value e: the boundaries are
  e x 255 + 1/2 = integer.
* Every other float array is exact: ``time_ms``/``frame_rate`` come from +, -, x, / of the
  stream's fields (IEEE-754 correctly rounded on every platform), ``part_color`` is the scene's
  value as read.

:func:`measure` reruns the reference for every case and reports, per golden, the smallest
distance of a value to its boundary, in units of the value's own float64 ulp ("ulps to
flip": how far another platform's result may be off before one byte changes). Measured on the
committed goldens (``fbaconf golden margins``): see docs/suites.md.

:func:`within_tolerance` is verify's second look at a regenerated file whose bytes differ:
the same arrays with floats at most one rounding step apart (``STEP`` plus one float32 ulp
for float32 arrays), everything else equal; images with the same size and every channel at
most ``IMAGE_LEVELS`` = 1 of 255 apart (or pixel-identical: another PNG encoder's bytes).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fbaconf.animation.engine import animate
from fbaconf.reference.pipeline import load_stream
from fbaconf.rendering.images import colour_science, read_image
from fbaconf.rendering.render import Renderer
from fbaconf.rendering.scenario import Scenario

DECIMALS = 6
STEP = 10.0**-DECIMALS
# FaceState arrays stored at the rounding step, with the dtype they are stored as
ROUNDED = {"vertices": np.float32, "extra_feature_points": np.float32, "extra_fap_values": np.float64}
IMAGE_LEVELS = 1
# A value closer than this many ulps to its boundary is reported as at risk: cross-platform
# differences of one pipeline (libm's sin/cos/log/pow, BLAS summation order) are a few ulps
# per operation, compounded over a handful of operations.
RISK_ULPS = 1024


def round_array(name: str, a: np.ndarray) -> np.ndarray:
    """``a`` as stored in a golden: rounded to DECIMALS and cast (``name`` in ROUNDED)."""
    return (np.round(np.asarray(a, dtype=np.float64), DECIMALS) + 0.0).astype(ROUNDED[name])


def vertex_ulps_to_flip(x: np.ndarray) -> np.ndarray:
    """Per value: the distance to the nearest rounding boundary (k + 1/2) x STEP, in ulps of the
    value (float64)."""
    x = np.asarray(x, dtype=np.float64).ravel()
    y = x / STEP
    d = np.abs((y - np.floor(y)) - 0.5) * STEP
    with np.errstate(over="ignore"):  # x = 0: spacing 5e-324, infinitely safe
        return d / np.spacing(np.abs(x))


def image_ulps_to_flip(encoded: np.ndarray) -> np.ndarray:
    """Per channel value e (sRGB-encoded, in [0, 1]): the distance of e x 255 + 1/2 to the nearest
    integer, in ulps of e (float64)."""
    e = np.asarray(encoded, dtype=np.float64).ravel()
    y = e * 255.0 + 0.5
    d = np.abs(y - np.rint(y)) / 255.0
    with np.errstate(over="ignore"):  # e = 0: half a level away, infinitely safe
        return d / np.spacing(np.abs(e))


@dataclass
class Margin:
    golden: str  # suite/case/file
    kind: str  # "vertices" or "image"
    values: int
    ulps: float  # smallest ulps to flip over the file's rounded values
    near: int  # values within RISK_ULPS of a boundary


def _case_margins(case, supersample: int) -> list[Margin]:
    out: list[Margin] = []
    stream = case.input_path("fba") or case.input_path("fap")
    state = animate(load_stream(stream), scene=case.input_path("scene"))
    where = f"{case.suite}/{case.id}"
    if "vertices" in case.stages:
        key = case.tolerances.get("vertices", {}).get("key")
        arrays = {"vertices": state.vertices, **{f"extra_{k}": v for k, v in state.extras.items()}}
        for name, a in arrays.items():
            if name in ROUNDED and (key is None or name == key):
                u = vertex_ulps_to_flip(a)
                out.append(
                    Margin(
                        f"{where}/{case.goldens['vertices']}:{name}",
                        "vertices",
                        u.size,
                        float(u.min()),
                        int((u < RISK_ULPS).sum()),
                    )
                )
    if "images" in case.stages:
        sc = Scenario.load(case.input_path("scenario")).with_(supersample=supersample)
        scene = case.input_path("scene")
        r = Renderer(state, sc, scene_dir=scene.resolve().parent if scene else None)
        for k in sc.frame_indices(state.n_frames):
            lin = np.clip(r.render(k), 0.0, 1.0)
            e = np.asarray(colour_science().cctf_encoding(lin, function="sRGB"), dtype=np.float64)
            u = image_ulps_to_flip(e)
            out.append(
                Margin(
                    f"{where}/{r.frame_path('', k).name}", "image", u.size, float(u.min()), int((u < RISK_ULPS).sum())
                )
            )
    return out


def measure(suites, supersample: int, log=print) -> list[Margin]:
    """The margin of every float golden of ``suites``, images rendered with ``supersample`` samples
    per pixel side as the goldens are (reruns the reference: minutes)."""
    out: list[Margin] = []
    for s in suites:
        for c in s.cases:
            if c.kind != "error" and ({"vertices", "images"} & set(c.stages)):
                out += _case_margins(c, supersample)
        log(f"margins: {s.name} done")
    return out


def summary(rows: list[Margin]) -> str:
    lines = []
    for kind, step in (("vertices", f"{STEP:g} (6 decimals)"), ("image", "1/255 (8-bit sRGB)")):
        rs = [r for r in rows if r.kind == kind]
        if not rs:
            continue
        worst = min(rs, key=lambda r: r.ulps)
        risky = [r for r in rs if r.near]
        lines.append(
            f"{kind}: {len(rs)} golden array(s), {sum(r.values for r in rs):,} values at step {step}; "
            f"smallest margin {worst.ulps:.3g} ulps ({worst.golden}); "
            f"{sum(r.near for r in rs)} value(s) in {len(risky)} golden(s) within {RISK_ULPS} ulps "
            f"of a boundary"
        )
        lines += [f"  near a boundary: {r.golden}: {r.near} value(s), smallest {r.ulps:.3g} ulps" for r in risky]
    return "\n".join(lines)


# ---------------------------------------------------------------------------- verify's tolerance
def within_tolerance(committed: Path, regenerated: Path) -> str | None:
    """How a regenerated golden whose bytes differ still matches the committed one ("pixel-identical",
    "values within one rounding step", ...), or None when it does not."""
    if committed.suffix == ".npz":
        return _npz_within(committed, regenerated)
    if committed.suffix == ".png":
        return _png_within(committed, regenerated)
    return None


def _npz_within(a: Path, b: Path) -> str | None:
    with np.load(a, allow_pickle=False) as za, np.load(b, allow_pickle=False) as zb:
        if sorted(za.files) != sorted(zb.files):
            return None
        moved = 0
        for k in za.files:
            x, y = za[k], zb[k]
            if x.dtype != y.dtype or x.shape != y.shape:
                return None
            if np.array_equal(x, y):
                continue
            if x.dtype.kind != "f" or k not in ROUNDED:
                return None
            diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
            allowed = STEP * 1.000001 + (np.spacing(np.abs(x)).astype(np.float64) if x.dtype == np.float32 else 0.0)
            if not np.all(diff <= allowed):
                return None
            moved += int((diff > 0).sum())
    return (
        f"{moved} value(s) differ, each by at most one rounding step ({STEP:g})"
        if moved
        else "equal arrays, other bytes"
    )


def _png_within(a: Path, b: Path) -> str | None:
    pa, pb = read_image(a)[0], read_image(b)[0]
    if pa.shape != pb.shape:
        return None
    d = np.rint(np.abs(pa.astype(np.float64) - pb.astype(np.float64)) * 255.0)
    if d.max() > IMAGE_LEVELS:
        return None
    n = int((d > 0).sum())
    return f"{n} channel value(s) differ by 1 of 255" if n else "pixel-identical, other bytes"
