"""The image stage: a contrast-aware per-pixel rule and CIEDE2000 against converged golden images,
heat-map artefacts."""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.harness.results import Outcome, StageResult
from fbaconf.rendering.images import colour_science, openimageio, srgb_to_linear, write_png

from .base import DEFAULT_MAX_BYTES, DEFAULT_MAX_PIXELS, PSNR_CAP, OutputError, worst
from .loaders import check_output_file
from .tolerances import ImageTolerances


class _ImageUnreadable(Exception):
    pass


def _read_encoded(path: Path, max_bytes: int, max_pixels: int) -> np.ndarray:
    """An image as float64[H, W, C] sRGB-encoded values: integer formats as stored
    (normalised to [0, 1]), float formats (linear) clipped to [0, 1] and sRGB-encoded.
    Raises _ImageUnreadable with a reason."""
    try:
        check_output_file(path, max_bytes)
    except OutputError as e:
        raise _ImageUnreadable(e.message) from None
    size = path.stat().st_size
    if size > max_bytes:
        raise _ImageUnreadable(f"image is {size} bytes, more than the limit of {max_bytes}")
    oiio = openimageio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise _ImageUnreadable(f"cannot read image: {oiio.geterror() or 'unknown format'}")
    try:
        spec = inp.spec()
        w, h, c = int(spec.width), int(spec.height), int(spec.nchannels)
        if w <= 0 or h <= 0 or c <= 0 or spec.depth > 1:
            raise _ImageUnreadable(f"unsupported image geometry {w}x{h}x{c} (depth {spec.depth})")
        if w * h * c > max_pixels:
            raise _ImageUnreadable(f"image of {w}x{h}x{c} values exceeds the limit of {max_pixels}")
        fmt = str(spec.format)
        px = inp.read_image(0, 0, 0, c, oiio.FLOAT)
        if px is None or inp.has_error:
            raise _ImageUnreadable(f"cannot read image: {inp.geterror() or oiio.geterror() or 'read failed'}")
    finally:
        inp.close()
    px = np.asarray(px, dtype=np.float64).reshape(h, w, c)
    if fmt in ("half", "float", "double"):
        px = np.nan_to_num(px, nan=0.0, posinf=1.0, neginf=0.0)
        rgb = min(c, 3)
        px[:, :, :rgb] = np.asarray(colour_science().cctf_encoding(np.clip(px[:, :, :rgb], 0.0, 1.0), function="sRGB"))
        px = np.clip(px, 0.0, 1.0)
    out: np.ndarray = px
    return out


def _rgb(px: np.ndarray) -> np.ndarray:
    return px[:, :, :3] if px.shape[2] >= 3 else np.repeat(px[:, :, :1], 3, axis=2)


def _delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """CIEDE2000 per pixel between two sRGB-encoded float images (RGB[H, W, 3])."""
    colour = colour_science()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        la = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(a))
        lb = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(b))
        de = np.asarray(colour.difference.delta_E_CIE2000(la, lb), dtype=np.float64)
    return np.nan_to_num(de, nan=0.0)


def _buf(px: np.ndarray) -> Any:  # an OpenImageIO ImageBuf
    oiio = openimageio()
    h, w, c = px.shape
    b = oiio.ImageBuf(oiio.ImageSpec(w, h, c, oiio.FLOAT))
    b.set_pixels(oiio.ROI(), np.ascontiguousarray(px, dtype=np.float32))
    return b


# Heat-map stops (display sRGB), from 0 (black) to 1 (white): black, indigo, red, orange, yellow, white.
_HEAT = np.array(
    [[0.0, 0.0, 0.0], [0.25, 0.0, 0.55], [0.85, 0.1, 0.15], [1.0, 0.55, 0.0], [1.0, 0.95, 0.2], [1.0, 1.0, 1.0]]
)


def heat_map(values: np.ndarray, scale: float) -> np.ndarray:
    """Display-sRGB float[H, W, 3] heat map of ``values / scale`` (clipped to [0, 1])."""
    t = np.clip(np.asarray(values, dtype=np.float64) / max(scale, 1e-12), 0.0, 1.0)
    xs = np.linspace(0.0, 1.0, len(_HEAT))
    return np.stack([np.interp(t, xs, _HEAT[:, ch]) for ch in range(3)], axis=-1)


def _write_display_png(path: Path, encoded_rgb: np.ndarray) -> None:
    write_png(path, srgb_to_linear(np.clip(encoded_rgb, 0.0, 1.0)))


def _px8(v: np.ndarray) -> list[int]:
    return [int(x) for x in np.floor(np.asarray(v, dtype=np.float64) * 255.0 + 0.5)]


def _neighbourhood(px: np.ndarray) -> list[np.ndarray]:
    """The nine 3x3-shifted views of ``px`` (edge-replicated): each pixel's neighbours in turn."""
    h, w = px.shape[:2]
    pad = np.pad(px, ((1, 1), (1, 1), (0, 0)), mode="edge")
    return [pad[dy : dy + h, dx : dx + w] for dy in (0, 1, 2) for dx in (0, 1, 2)]


def local_range(px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel minimum and maximum of each pixel's 3x3 neighbourhood (edge-replicated)."""
    lo, hi = px.copy(), px.copy()
    for win in _neighbourhood(px):
        np.minimum(lo, win, out=lo)
        np.maximum(hi, win, out=hi)
    return lo, hi


@dataclass
class FrameJudgement:
    """What the image rules measured on one frame (sRGB-encoded values in [0, 1])."""

    diff: np.ndarray  # float[H, W]: largest channel difference per pixel
    allowed: np.ndarray  # float[H, W]: abs_tol + contrast_k x local contrast of the golden
    edge: np.ndarray  # bool[H, W]: the golden's local contrast above edge_contrast
    violating: np.ndarray  # bool[H, W]: diff > allowed
    deltae: np.ndarray  # float[H, W]: CIEDE2000 per pixel of the 3x3-blurred images
    violation_limit: int  # a frame fails with more violating pixels than this

    @property
    def violations(self) -> int:
        return int(self.violating.sum())

    @property
    def interior(self) -> np.ndarray:
        return self.deltae[~self.edge] if (~self.edge).any() else np.zeros(1)


def judge_frame(expected: np.ndarray, got: np.ndarray, tol: ImageTolerances) -> FrameJudgement:
    """The per-pixel rule of the image stage (harness/data/tolerances.toml [images] says why
    each number): a pixel *violates* when its largest channel difference exceeds ``abs_tol +
    contrast_k x c``, c the largest channel range of the golden over the pixel's 3x3
    neighbourhood. Interiors (c small) are held to ``abs_tol``; at silhouettes, contours and
    texture edges the band grows with the local contrast, so a different anti-aliasing (any
    sampler with enough samples) stays inside while a shift of a whole pixel, which moves a
    pixel by about the full contrast, does not."""
    e, g = _rgb(expected), _rgb(got)
    diff = np.abs(g - e).max(axis=2)
    if expected.shape[2] > 3:  # alpha counts like a colour channel
        diff = np.maximum(diff, np.abs(got[:, :, 3:] - expected[:, :, 3:]).max(axis=2))
    lo, hi = local_range(expected)
    contrast = (hi - lo).max(axis=2)
    allowed = tol.abs_tol + tol.contrast_k * contrast
    h, w = diff.shape
    limit = max(int(tol.fail_pixels), int(math.floor(tol.fail_percent / 100.0 * w * h)))
    return FrameJudgement(
        diff, allowed, contrast > tol.edge_contrast, diff > allowed, _delta_e(_box3(e), _box3(g)), limit
    )


def _box3(px: np.ndarray) -> np.ndarray:
    """Each pixel replaced by the mean of its 3x3 neighbourhood (edge-replicated): colour
    difference is judged as seen, after the eye's spatial blur (the idea of S-CIELAB), so
    uncorrelated 1-code rounding noise does not count as a colour change while a uniform shift does."""
    acc = np.zeros_like(px)
    for win in _neighbourhood(px):
        acc += win
    return acc / 9.0


def compare_images(  # noqa: PLR0913 - keyword options of the image stage
    expected: Sequence[Path],
    got: Sequence[Path],
    tol: ImageTolerances,
    artefact_dir: Path,
    *,
    frames: Sequence[int] | None = None,
    relative_to: Path | None = None,
    max_artefact_frames: int = 10,
    max_bytes: int = DEFAULT_MAX_BYTES,
    max_pixels: int = DEFAULT_MAX_PIXELS,
) -> StageResult:
    """Compare a decoder's frame images with the golden ones, pairwise.

    Each pair is compared on sRGB-encoded values in [0, 1] (8-bit images as stored; float
    images, taken as linear, are encoded). The goldens approximate the ideal image (rendered
    with 8 x 8 samples per pixel, conformance/golden.py), so any faithful renderer is judged
    by the same rule whatever its anti-aliasing (:func:`judge_frame`). A frame **fails** when
    its image is missing/unreadable, its size or channel count differs, more pixels violate
    the per-pixel rule than ``max(fail_pixels, fail_percent % of the pixels)`` (no verdict from
    a single pixel), or the CIEDE2000 ΔE of the interior (pixels off edges) has a mean above
    ``interior_deltae_fail_mean`` or a 99th percentile above ``interior_deltae_fail_p99``, or
    the whole image's ΔE mean is above ``deltae_fail_mean``. It gets a **QualityWarning** only
    when it does not fail and the interior's ΔE mean is above ``interior_deltae_warn_mean``: a
    uniform colour difference below one just-noticeable difference; violating pixels under
    the limit are reported (metric ``violations_max``), never a warning, so edges alone never
    warn. An unreadable golden image is an Error. The stage outcome is the worst frame
    outcome; a different number of images fails.

    For up to ``max_artefact_frames`` failing or warning frames, ``frame<F>_expected.png``,
    ``frame<F>_got.png`` and ``frame<F>_diff.png`` (a black-to-white heat map of per-pixel
    ΔE, white = max(ΔE max of the frame, 2)) are written into ``artefact_dir``; ``artefacts``
    maps ``frame<F>_expected`` etc. to their paths — relative to ``relative_to`` when given
    (e.g. the run's output folder), else absolute. ``F`` is ``frames[i]`` when ``frames`` (the
    sequence frame index of each image) is given, else the list position i.

    ``first_difference`` (first frame with the stage's outcome): frame, pixel [x, y] (the pixel
    furthest over its allowed difference, or the largest ΔE), expected / got RGB (sRGB 0-255),
    reason. ``series``: per frame ``psnr`` (dB, capped at PSNR_CAP, OpenImageIO's), ``deltae_mean``
    and ``violations`` (NaN where the frame could not be compared; the JSON report writer spells
    it "NaN", as the run-report schema allows)."""
    expected, got = [Path(p) for p in expected], [Path(p) for p in got]
    artefact_dir = Path(artefact_dir)
    labels = list(frames) if frames is not None else list(range(len(expected)))
    if len(labels) != len(expected):
        return StageResult("images", Outcome.ERROR, f"{len(labels)} frame labels for {len(expected)} images")
    psnr_s: list[float] = []
    de_s: list[float] = []
    viol_s: list[float] = []
    outcomes: list[Outcome] = []
    notes: list[str] = []
    firsts: list[dict[str, Any] | None] = []
    artefacts: dict[str, str] = {}
    agg = {
        "max_error": 0.0,
        "violations_max": 0.0,
        "violation_limit": 0.0,
        "deltae_mean_max": 0.0,
        "interior_deltae_mean_max": 0.0,
        "interior_deltae_p99_max": 0.0,
    }
    psnrs: list[float] = []
    written = 0

    def rel(p: Path) -> str:
        if relative_to is not None:
            return os.path.relpath(p, relative_to).replace(os.sep, "/")
        return str(p.resolve())

    for i, exp_path in enumerate(expected):
        fr = labels[i]
        psnr_s.append(math.nan)
        de_s.append(math.nan)
        viol_s.append(math.nan)
        try:
            ea = _read_encoded(exp_path, max_bytes, max_pixels)
        except Exception as e:  # noqa: BLE001 - an unreadable golden is a harness Error
            outcomes.append(Outcome.ERROR)
            notes.append(f"frame {fr}: golden image {exp_path}: {e}")
            firsts.append({"frame": fr, "what": "golden unreadable", "file": str(exp_path)})
            continue
        if i >= len(got):
            outcomes.append(Outcome.FAIL)
            notes.append(f"frame {fr}: no image from the decoder")
            firsts.append({"frame": fr, "what": "missing", "expected": list(ea.shape), "got": None})
            continue
        gp = got[i]
        try:
            ga = _read_encoded(gp, max_bytes, max_pixels)
        except Exception as e:  # noqa: BLE001 - untrusted image: a Fail, never an exception
            outcomes.append(Outcome.FAIL)
            notes.append(f"frame {fr}: {gp}: {e}")
            firsts.append({"frame": fr, "what": "unreadable", "file": str(gp), "reason": str(e)})
            continue
        if ea.shape != ga.shape:
            dims = [("height", 0), ("width", 1), ("channels", 2)]
            bad = [f"{n} expected {ea.shape[a]}, got {ga.shape[a]}" for n, a in dims if ea.shape[a] != ga.shape[a]]
            outcomes.append(Outcome.FAIL)
            notes.append(f"frame {fr}: image size/channels differ: {'; '.join(bad)}")
            firsts.append(
                {
                    "frame": fr,
                    "what": "size",
                    "expected": [ea.shape[1], ea.shape[0], ea.shape[2]],
                    "got": [ga.shape[1], ga.shape[0], ga.shape[2]],
                }
            )
            continue
        oiio = openimageio()
        cr = oiio.ImageBufAlgo.compare(_buf(ea), _buf(ga), 1.0, 1.0)
        j = judge_frame(ea, ga, tol)
        de = j.deltae
        de_mean = float(de.mean())
        inner = j.interior
        in_mean, in_p99 = float(inner.mean()), float(np.percentile(inner, 99))
        psnr = float(cr.PSNR) if math.isfinite(cr.PSNR) else PSNR_CAP
        psnr = min(psnr, PSNR_CAP)
        psnr_s[-1], de_s[-1], viol_s[-1] = psnr, de_mean, float(j.violations)
        psnrs.append(psnr)
        agg["max_error"] = max(agg["max_error"], float(cr.maxerror))
        agg["violations_max"] = max(agg["violations_max"], float(j.violations))
        agg["violation_limit"] = float(j.violation_limit)
        agg["deltae_mean_max"] = max(agg["deltae_mean_max"], de_mean)
        agg["interior_deltae_mean_max"] = max(agg["interior_deltae_mean_max"], in_mean)
        agg["interior_deltae_p99_max"] = max(agg["interior_deltae_p99_max"], in_p99)

        reasons_fail, reasons_warn = [], []
        if j.violations > j.violation_limit:
            reasons_fail.append(
                f"{j.violations} pixel(s) differ by more than {tol.abs_tol:g} + {tol.contrast_k:g} x "
                f"the golden's local contrast (limit {j.violation_limit} pixels)"
            )
        if in_mean > tol.interior_deltae_fail_mean:
            reasons_fail.append(f"interior ΔE2000 mean {in_mean:.3g} > {tol.interior_deltae_fail_mean:g}")
        if in_p99 > tol.interior_deltae_fail_p99:
            reasons_fail.append(f"interior ΔE2000 p99 {in_p99:.3g} > {tol.interior_deltae_fail_p99:g}")
        if de_mean > tol.deltae_fail_mean:
            reasons_fail.append(f"ΔE2000 mean {de_mean:.3g} > {tol.deltae_fail_mean:g}")
        if in_mean > tol.interior_deltae_warn_mean:
            reasons_warn.append(
                f"interior ΔE2000 mean {in_mean:.3g} > {tol.interior_deltae_warn_mean:g} "
                f"(a uniform difference below one just-noticeable difference)"
            )
        outcome = Outcome.FAIL if reasons_fail else Outcome.QUALITY_WARNING if reasons_warn else Outcome.PASS
        outcomes.append(outcome)
        if outcome is Outcome.PASS:
            firsts.append(None)
            continue
        if j.violations:
            y, x = (int(v) for v in np.unravel_index(int(np.argmax(j.diff - j.allowed)), j.diff.shape))
        else:
            y, x = (int(v) for v in np.unravel_index(int(np.argmax(de)), de.shape))
        fd: dict[str, Any] = {
            "frame": fr,
            "pixel": [x, y],
            "expected": _px8(_rgb(ea)[y, x]),
            "got": _px8(_rgb(ga)[y, x]),
            "deltae": float(de[y, x]),
            "reason": "; ".join(reasons_fail or reasons_warn),
        }
        firsts.append(fd)
        notes.append(
            f"frame {fr}: {fd['reason']}; worst pixel ({x}, {y}): expected RGB {fd['expected']}, got {fd['got']}"
        )
        if written < max_artefact_frames:
            written += 1
            scale = max(float(de.max()), 2.0)
            for kind, img in (("expected", _rgb(ea)), ("got", _rgb(ga)), ("diff", heat_map(de, scale))):
                p = artefact_dir / f"frame{fr}_{kind}.png"
                _write_display_png(p, img)
                artefacts[f"frame{fr}_{kind}"] = rel(p)

    if len(got) > len(expected):
        outcomes.append(Outcome.FAIL)
        notes.append(f"the decoder wrote {len(got)} images, expected {len(expected)}")
        firsts.append({"frame": len(expected), "what": "image count", "expected": len(expected), "got": len(got)})
    elif len(got) < len(expected):
        notes.insert(0, f"the decoder wrote {len(got)} images, expected {len(expected)}")

    overall = worst(outcomes) if outcomes else Outcome.PASS
    metrics = {
        "frames_compared": float(len(psnrs)),
        "frames": float(len(expected)),
        "frames_failing": float(sum(o is Outcome.FAIL for o in outcomes)),
        "frames_warning": float(sum(o is Outcome.QUALITY_WARNING for o in outcomes)),
        "psnr_min": float(min(psnrs)) if psnrs else 0.0,
        **agg,
    }
    series = {"psnr": psnr_s, "deltae_mean": de_s, "violations": viol_s}
    if overall is Outcome.PASS:
        msg = (
            f"{len(expected)} image(s) within tolerance (at most {int(agg['violations_max'])} violating "
            f"pixel(s) of {int(agg['violation_limit'])} allowed, interior ΔE2000 mean <= "
            f"{agg['interior_deltae_mean_max']:.3g}, PSNR >= {metrics['psnr_min']:.4g} dB)"
        )
        return StageResult("images", overall, msg, None, metrics, series, artefacts)
    first = next((f for o, f in zip(outcomes, firsts) if o is overall and f is not None), None)
    n_bad = sum(o is overall for o in outcomes)
    msg = f"{overall.value}: {n_bad} of {len(expected)} image(s); " + "; ".join(notes[:3])
    if len(notes) > 3:
        msg += f"; ... ({len(notes) - 3} more)"
    return StageResult("images", overall, msg, first, metrics, series, artefacts)
