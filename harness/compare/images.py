"""The image stage: OpenImageIO compare and CIEDE2000 against the golden images, warn and fail bands, heat-map artefacts."""
from __future__ import annotations

import math
import os
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from fbaconf.rendering.images import colour_science, openimageio

from fbaconf.harness.results import Outcome, StageResult
from .base import DEFAULT_MAX_BYTES, DEFAULT_MAX_PIXELS, OutputError, PSNR_CAP, worst
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
    return px


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


def _buf(px: np.ndarray):
    oiio = openimageio()
    h, w, c = px.shape
    b = oiio.ImageBuf(oiio.ImageSpec(w, h, c, oiio.FLOAT))
    b.set_pixels(oiio.ROI(), np.ascontiguousarray(px, dtype=np.float32))
    return b


# Heat-map stops (display sRGB), from 0 (black) to 1 (white): black, indigo, red, orange, yellow, white.
_HEAT = np.array([[0.0, 0.0, 0.0], [0.25, 0.0, 0.55], [0.85, 0.1, 0.15], [1.0, 0.55, 0.0], [1.0, 0.95, 0.2],
                  [1.0, 1.0, 1.0]])


def heat_map(values: np.ndarray, scale: float) -> np.ndarray:
    """Display-sRGB float[H, W, 3] heat map of ``values / scale`` (clipped to [0, 1])."""
    t = np.clip(np.asarray(values, dtype=np.float64) / max(scale, 1e-12), 0.0, 1.0)
    xs = np.linspace(0.0, 1.0, len(_HEAT))
    return np.stack([np.interp(t, xs, _HEAT[:, ch]) for ch in range(3)], axis=-1)


def _write_display_png(path: Path, encoded_rgb: np.ndarray) -> None:
    from fbaconf.rendering.images import srgb_to_linear, write_png
    write_png(path, srgb_to_linear(np.clip(encoded_rgb, 0.0, 1.0)))


def _px8(v: np.ndarray) -> list[int]:
    return [int(x) for x in np.floor(np.asarray(v, dtype=np.float64) * 255.0 + 0.5)]


def compare_images(expected: Sequence[Path], got: Sequence[Path], tol: ImageTolerances, artefact_dir: Path, *,
                   frames: Sequence[int] | None = None, relative_to: Path | None = None,
                   max_artefact_frames: int = 10, max_bytes: int = DEFAULT_MAX_BYTES,
                   max_pixels: int = DEFAULT_MAX_PIXELS) -> StageResult:
    """Compare a decoder's frame images with the golden ones, pairwise.

    Each pair is compared on sRGB-encoded values in [0, 1] (8-bit images as stored; float
    images, taken as linear, are encoded) with OpenImageIO ``ImageBufAlgo.compare`` at
    ``tol.fail_threshold`` / ``tol.warn_threshold`` (per channel), and by CIEDE2000 ΔE per
    pixel. A frame **fails** when its image is missing/unreadable, its size or channel
    count differs, more than ``tol.fail_percent`` % of its pixels exceed the fail
    threshold, any value differs by more than ``tol.hard_fail``, or ΔE mean / p95 exceed
    the fail limits. It **warns** (QualityWarning) when it does not fail but some pixel
    exceeds the warn threshold or ΔE mean / p95 exceed the warn limits. An unreadable
    golden image is an Error. The stage outcome is the worst frame outcome; a different
    number of images fails.

    For up to ``max_artefact_frames`` failing or warning frames, ``frame<F>_expected.png``,
    ``frame<F>_got.png`` and ``frame<F>_diff.png`` (a black-to-white heat map of per-pixel
    ΔE, white = max(ΔE max of the frame, tol.deltae_warn_p95)) are written into
    ``artefact_dir``; ``artefacts`` maps ``frame<F>_expected`` etc. to their paths —
    relative to ``relative_to`` when given (e.g. the run's output folder), else absolute.
    ``F`` is ``frames[i]`` when ``frames`` (the sequence frame index of each image) is
    given, else the list position i.

    ``first_difference`` (first frame with the stage's outcome): frame, pixel [x, y],
    expected / got RGB (sRGB 0-255), reason. ``series``: per frame ``psnr`` (dB, capped at
    PSNR_CAP) and ``deltae_mean`` (NaN where the frame could not be compared; the JSON
    report writer spells it "NaN", as the run-report schema allows)."""
    expected, got = [Path(p) for p in expected], [Path(p) for p in got]
    artefact_dir = Path(artefact_dir)
    labels = list(frames) if frames is not None else list(range(len(expected)))
    if len(labels) != len(expected):
        return StageResult("images", Outcome.ERROR, f"{len(labels)} frame labels for {len(expected)} images")
    psnr_s: list[float] = []
    de_s: list[float] = []
    outcomes: list[Outcome] = []
    notes: list[str] = []
    firsts: list[dict | None] = []
    artefacts: dict[str, str] = {}
    agg = {"max_error": 0.0, "fail_pixel_percent_max": 0.0, "deltae_mean_max": 0.0, "deltae_p95_max": 0.0}
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
            firsts.append({"frame": fr, "what": "size", "expected": [ea.shape[1], ea.shape[0], ea.shape[2]],
                           "got": [ga.shape[1], ga.shape[0], ga.shape[2]]})
            continue
        oiio = openimageio()
        cr = oiio.ImageBufAlgo.compare(_buf(ea), _buf(ga), float(tol.fail_threshold), float(tol.warn_threshold))
        h, w = ea.shape[:2]
        fail_pct = 100.0 * int(cr.nfail) / (w * h)
        de = _delta_e(_rgb(ea), _rgb(ga))
        de_mean, de_p95 = float(de.mean()), float(np.percentile(de, 95))
        psnr = float(cr.PSNR) if math.isfinite(cr.PSNR) else PSNR_CAP
        psnr = min(psnr, PSNR_CAP)
        psnr_s[-1], de_s[-1] = psnr, de_mean
        psnrs.append(psnr)
        agg["max_error"] = max(agg["max_error"], float(cr.maxerror))
        agg["fail_pixel_percent_max"] = max(agg["fail_pixel_percent_max"], fail_pct)
        agg["deltae_mean_max"] = max(agg["deltae_mean_max"], de_mean)
        agg["deltae_p95_max"] = max(agg["deltae_p95_max"], de_p95)

        reasons_fail, reasons_warn = [], []
        if fail_pct > tol.fail_percent:
            reasons_fail.append(f"{fail_pct:.3g}% of pixels differ by more than {tol.fail_threshold:g} "
                                f"(limit {tol.fail_percent:g}%)")
        if cr.maxerror > tol.hard_fail:
            reasons_fail.append(f"a value differs by {cr.maxerror:.3g} > hard_fail {tol.hard_fail:g}")
        oiio_fail = bool(reasons_fail)
        if de_mean > tol.deltae_fail_mean:
            reasons_fail.append(f"ΔE2000 mean {de_mean:.3g} > {tol.deltae_fail_mean:g}")
        if de_p95 > tol.deltae_fail_p95:
            reasons_fail.append(f"ΔE2000 p95 {de_p95:.3g} > {tol.deltae_fail_p95:g}")
        if int(cr.nwarn) > 0:
            reasons_warn.append(f"{int(cr.nwarn)} pixel(s) differ by more than {tol.warn_threshold:g}")
        if de_mean > tol.deltae_warn_mean:
            reasons_warn.append(f"ΔE2000 mean {de_mean:.3g} > {tol.deltae_warn_mean:g}")
        if de_p95 > tol.deltae_warn_p95:
            reasons_warn.append(f"ΔE2000 p95 {de_p95:.3g} > {tol.deltae_warn_p95:g}")
        outcome = Outcome.FAIL if reasons_fail else Outcome.QUALITY_WARNING if reasons_warn else Outcome.PASS
        outcomes.append(outcome)
        if outcome is Outcome.PASS:
            firsts.append(None)
            continue
        if oiio_fail or (outcome is Outcome.QUALITY_WARNING and int(cr.nwarn) > 0):
            x, y = int(cr.maxx), int(cr.maxy)
        else:
            y, x = (int(v) for v in np.unravel_index(int(np.argmax(de)), de.shape))
        first = {"frame": fr, "pixel": [x, y], "expected": _px8(_rgb(ea)[y, x]), "got": _px8(_rgb(ga)[y, x]),
                 "deltae": float(de[y, x]), "reason": "; ".join(reasons_fail or reasons_warn)}
        firsts.append(first)
        notes.append(f"frame {fr}: {first['reason']}; worst pixel ({x}, {y}): expected RGB {first['expected']}, "
                     f"got {first['got']}")
        if written < max_artefact_frames:
            written += 1
            scale = max(float(de.max()), tol.deltae_warn_p95)
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
    metrics = {"frames_compared": float(len(psnrs)), "frames": float(len(expected)),
               "frames_failing": float(sum(o is Outcome.FAIL for o in outcomes)),
               "frames_warning": float(sum(o is Outcome.QUALITY_WARNING for o in outcomes)),
               "psnr_min": float(min(psnrs)) if psnrs else 0.0, **agg}
    series = {"psnr": psnr_s, "deltae_mean": de_s}
    if overall is Outcome.PASS:
        msg = (f"{len(expected)} image(s) within tolerance (PSNR >= {metrics['psnr_min']:.4g} dB, "
               f"ΔE2000 mean <= {agg['deltae_mean_max']:.3g})")
        return StageResult("images", overall, msg, None, metrics, series, artefacts)
    first = next((f for o, f in zip(outcomes, firsts) if o is overall and f is not None), None)
    n_bad = sum(o is overall for o in outcomes)
    msg = f"{overall.value}: {n_bad} of {len(expected)} image(s); " + "; ".join(notes[:3])
    if len(notes) > 3:
        msg += f"; ... ({len(notes) - 3} more)"
    return StageResult("images", overall, msg, first, metrics, series, artefacts)
