"""The comparison ladder: a decoder's outputs against the golden (reference) outputs.

Pure functions (no subprocesses): the runner reads a decoder's output files with the
``load_output_*`` functions and judges them with the ``compare_*`` functions, each giving
one :class:`~fbaconf.harness.results.StageResult`.

* ``faps`` (:func:`compare_faps`) — exact and normative: frame count, frame numbers, and
  per frame the value of every FAP whose expected status is SET, RETAINED or DERIVED (and
  the high-level fields of FAP 1/2 when they are not FREE). FREE values are the decoder's
  choice. FapFrames ``.npz`` outputs must also reproduce the status of every FAP; ``.fap``
  text carries no SET/RETAINED distinction, so there only "a value is present" is checked.
* ``vertices`` (:func:`compare_vertices`) — per-frame maximum and RMS euclidean error
  against tolerances (:class:`VertexTolerances`).
* ``images`` (:func:`compare_images`) — OpenImageIO ``ImageBufAlgo.compare`` on
  sRGB-encoded values plus CIEDE2000 (colour-science), with a fail band and a warn band
  (:class:`ImageTolerances`); failing/warning frames leave expected/got/diff PNGs.

Default tolerances live in one data file, ``harness/data/tolerances.toml``, with the
reasoning for each number; suite cases override them per comparison with a dict.

Decoder outputs are untrusted: :func:`load_output_faps` and :func:`load_output_vertices`
raise :class:`OutputError` (an :class:`~fbaconf.errors.FbaconfInputError`)
naming the file for any unreadable, oversized, mis-shaped, mistyped or non-finite input,
and never another exception. ``.npz`` members are read without pickles, and every array's
header is checked (dtype, shape, size against the byte cap) before any data is read, so a
zip bomb or a header claiming a huge array cannot exhaust memory. Unreadable images are a
``Fail`` of the images stage, not an exception.
"""
from __future__ import annotations

import bisect
import math
import os
import stat
import tomllib
import warnings
import zipfile
import zlib
from dataclasses import asdict, dataclass, fields
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from fbaconf.errors import FbaconfInputError
from fbaconf.bitstreams.frames import (FREE, HIGH_LEVEL_FIELDS, STATUS_NAMES, VISEME_FIELDS, FapFrames)
from fbaconf.bitstreams.tables import NUM_FAPS, fap_table
from fbaconf.rendering.images import _colour, _oiio

from .results import OUTCOME_ORDER, Outcome, StageResult

__all__ = ["OutputError", "ToleranceError", "DEFAULT_MAX_BYTES", "DEFAULT_MAX_PIXELS", "PSNR_CAP",
           "ImageTolerances", "VertexTolerances", "load_tolerances", "load_output_faps", "load_output_vertices",
           "compare_faps", "compare_vertices", "compare_images", "part_namer", "worst"]

DEFAULT_MAX_BYTES = 256 * 1024 * 1024  # cap of one output file, and of the decompressed arrays read from it
MAX_NPZ_MEMBERS = 64
DEFAULT_MAX_PIXELS = 64 * 1024 * 1024  # cap of width x height x channels of one image
PSNR_CAP = 100.0  # PSNR of identical images is infinite; recorded as this (JSON has no infinity)

FAPFRAMES_FORMAT = "fbaconf.FapFrames/1"
_INT32 = (-(2 ** 31), 2 ** 31 - 1)


class OutputError(FbaconfInputError):
    """A decoder's output file cannot be used: unreadable, too large, wrong arrays, shapes,
    dtypes or non-finite values. ``file`` names it; ``rule`` says which check failed."""

    rule = "output"


class ToleranceError(FbaconfInputError, ValueError):
    """A tolerance table (data file or a case's overrides) is invalid."""

    rule = "tolerance"


# ====================================================================================
# Outcomes
# ====================================================================================
def worst(outcomes: Iterable[Outcome]) -> Outcome:
    """The worst of some stage outcomes, in ``results.OUTCOME_ORDER`` (Crash > Timeout >
    Fail > Error > QualityWarning > NotSupported > Skipped > Pass). No outcomes: Pass."""
    rank = {o: i for i, o in enumerate(OUTCOME_ORDER)}
    best = Outcome.PASS
    for o in outcomes:
        o = Outcome(o)
        if rank[o] < rank[best]:
            best = o
    return best


# ====================================================================================
# Tolerances
# ====================================================================================
@lru_cache(maxsize=1)
def _tolerance_file() -> dict:
    text = resources.files("fbaconf.harness").joinpath("data", "tolerances.toml").read_text("utf-8")
    return tomllib.loads(text)


def load_tolerances() -> dict:
    """The parsed default tolerance file (a fresh copy): ``{"vertices": {...}, "images": {...}}``."""
    return {k: dict(v) for k, v in _tolerance_file().items()}


def _check_number(cls_name: str, key: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ToleranceError(f"{cls_name}.{key} must be a number, not {type(v).__name__}", rule="tolerance-type")
    v = float(v)
    if math.isnan(v) or v < 0:
        raise ToleranceError(f"{cls_name}.{key} must be >= 0 (got {v})", rule="tolerance-value")
    return v


class _Tolerances:
    _section = ""
    _order: tuple[tuple[str, str], ...] = ()  # (warn key, fail key) pairs that must be ordered

    @classmethod
    def defaults(cls):
        return cls.from_dict(None, None)

    @classmethod
    def from_dict(cls, defaults=None, overrides: Mapping[str, Any] | None = None):
        """Tolerances from ``defaults`` (an instance, a dict, or None for the data file)
        with the keys of ``overrides`` replacing them. Unknown keys, non-numbers, negative
        or NaN values and a warn limit above its fail limit raise :class:`ToleranceError`."""
        names = [f.name for f in fields(cls)]
        if defaults is None:
            base = dict(_tolerance_file().get(cls._section, {}))
        elif isinstance(defaults, cls):
            base = asdict(defaults)
        elif isinstance(defaults, Mapping):
            base = dict(defaults)
        else:
            raise ToleranceError(f"{cls.__name__} defaults must be a {cls.__name__}, a table or None",
                                 rule="tolerance-type")
        if overrides is not None and not isinstance(overrides, Mapping):
            raise ToleranceError(f"{cls.__name__} overrides must be a table", rule="tolerance-type")
        merged = {**base, **dict(overrides or {})}
        unknown = sorted(set(merged) - set(names))
        if unknown:
            raise ToleranceError(f"unknown {cls.__name__} key(s) {', '.join(map(str, unknown))} "
                                 f"(known: {', '.join(names)})", rule="tolerance-key")
        missing = [n for n in names if n not in merged]
        if missing:
            raise ToleranceError(f"{cls.__name__} misses {', '.join(missing)}", rule="tolerance-key")
        vals = {n: _check_number(cls.__name__, n, merged[n]) for n in names}
        for w, f in cls._order:
            if vals[w] > vals[f]:
                raise ToleranceError(f"{cls.__name__}: {w} ({vals[w]}) is above {f} ({vals[f]})",
                                     rule="tolerance-order")
        return cls(**vals)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


@dataclass(frozen=True)
class VertexTolerances(_Tolerances):
    """Vertex comparison limits in scene units: per-frame maximum euclidean error of any
    vertex and per-frame RMS over all vertices."""
    max_tol: float
    rms_tol: float
    _section = "vertices"


@dataclass(frozen=True)
class ImageTolerances(_Tolerances):
    """Image comparison limits. Thresholds are per channel on sRGB-encoded values in
    [0, 1]; ``fail_percent`` is a percentage of pixels; ΔE limits are CIEDE2000."""
    fail_threshold: float
    warn_threshold: float
    fail_percent: float
    hard_fail: float
    deltae_warn_mean: float
    deltae_warn_p95: float
    deltae_fail_mean: float
    deltae_fail_p95: float
    _section = "images"
    _order = (("warn_threshold", "fail_threshold"), ("deltae_warn_mean", "deltae_fail_mean"),
              ("deltae_warn_p95", "deltae_fail_p95"))


# ====================================================================================
# Untrusted output files
# ====================================================================================
def _check_size(path: Path, max_bytes: int) -> None:
    """A decoder's output must be a regular file (not a symlink the decoder points at any file,
    not a FIFO that would block the harness, not a device that streams forever) within the cap."""
    try:
        st = os.lstat(path)
    except OSError as e:
        raise OutputError(f"cannot read output: {e.strerror or e}", rule="output-missing", file=str(path)) from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a symbolic link" if stat.S_ISLNK(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode) else
                "a directory" if stat.S_ISDIR(st.st_mode) else "a device or socket")
        raise OutputError(f"output is {kind}; outputs must be regular files", rule="output-unsafe", file=str(path))
    if st.st_size > max_bytes:
        raise OutputError(f"output is {st.st_size} bytes, more than the limit of {max_bytes}",
                          rule="output-too-large", file=str(path))


# Exceptions a broken zip / npy can raise while we read it (all become OutputError).
_READ_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, OSError, EOFError, ValueError, KeyError,
                TypeError, OverflowError, NotImplementedError, RuntimeError, IndexError, MemoryError,
                UnicodeError, SyntaxError)


class _SafeNpz:
    """Read arrays from an untrusted ``.npz`` without pickles and without trusting sizes:
    each member's .npy header is checked (no object dtype, data size <= the member's
    declared size, total <= max_bytes) before its data is read."""

    def __init__(self, path: Path, max_bytes: int) -> None:
        self.path = path
        self.max_bytes = max_bytes
        self.read_bytes = 0
        self.zf = zipfile.ZipFile(path)
        infos = self.zf.infolist()
        if len(infos) > MAX_NPZ_MEMBERS:
            raise self.err(f"{len(infos)} zip members, more than {MAX_NPZ_MEMBERS}", rule="output-too-large")
        for i in infos:
            if i.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
                raise self.err(f"member {i.filename[:80]!r} uses zip compression type {i.compress_type}; .npz "
                               f"members must be stored or deflated", rule="output-npz")
        if sum(i.file_size for i in infos) > max_bytes:
            raise self.err(f"the members expand to {sum(i.file_size for i in infos)} bytes, more than the limit of "
                           f"{max_bytes}", rule="output-too-large")
        self.members = {i.filename[:-4]: i for i in infos if i.filename.endswith(".npy")}

    def __enter__(self) -> "_SafeNpz":
        return self

    def __exit__(self, *exc) -> None:
        self.zf.close()

    def err(self, msg: str, rule: str = "output-array") -> OutputError:
        return OutputError(msg, rule=rule, file=str(self.path))

    def __contains__(self, key: str) -> bool:
        return key in self.members

    def header(self, key: str) -> tuple[tuple[int, ...], np.dtype]:
        info = self.members[key]
        with self.zf.open(info) as f:
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, _fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif version in ((2, 0), (3, 0)):
                shape, _fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:  # pragma: no cover - read_magic accepts only the versions above
                raise self.err(f"array '{key}': unsupported .npy version {version}")
        return tuple(int(s) for s in shape), np.dtype(dtype)

    def get(self, key: str) -> np.ndarray:
        try:
            return self._get(key)
        except OutputError:
            raise
        except _READ_ERRORS as e:
            raise self.err(f"array '{key}' cannot be read ({type(e).__name__}: {e})", rule="output-npz") from None

    def _get(self, key: str) -> np.ndarray:
        if key not in self.members:
            raise self.err(f"array '{key}' is missing", rule="output-array-missing")
        info = self.members[key]
        shape, dtype = self.header(key)
        if dtype.hasobject or dtype.kind not in "biufU":
            raise self.err(f"array '{key}' has unsupported dtype {dtype}", rule="output-dtype")
        nbytes = math.prod(shape) * dtype.itemsize
        if nbytes > info.file_size or self.read_bytes + info.file_size > self.max_bytes:
            raise self.err(f"array '{key}' (shape {list(shape)}, {dtype}) is larger than its data or than "
                           f"the limit of {self.max_bytes} bytes", rule="output-too-large")
        self.read_bytes += info.file_size
        with self.zf.open(info) as f:
            a = np.lib.format.read_array(f, allow_pickle=False)
        return np.asarray(a)


def _open_npz(path: Path, max_bytes: int) -> _SafeNpz:
    try:
        return _SafeNpz(path, max_bytes)
    except _READ_ERRORS as e:
        raise OutputError(f"not a readable .npz (zip) file: {e}", rule="output-npz", file=str(path)) from None


def _want(z: _SafeNpz, key: str, *, kinds: str, shape: tuple, what: str = "") -> np.ndarray:
    """Array ``key`` with dtype kind in ``kinds`` and ``shape`` (None = any size on that axis)."""
    a = z.get(key)
    if a.dtype.kind not in kinds:
        raise z.err(f"array '{key}' has dtype {a.dtype}, expected {what or kinds}", rule="output-dtype")
    if a.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, a.shape)):
        want = "[" + ", ".join("n" if s is None else str(s) for s in shape) + "]"
        raise z.err(f"array '{key}' has shape {list(a.shape)}, expected {want}", rule="output-shape")
    return a


def _int_in(z: _SafeNpz, key: str, a: np.ndarray, lo: int, hi: int) -> np.ndarray:
    if a.size:
        amin, amax = int(a.min()), int(a.max())
        if amin < lo or amax > hi:
            bad = amin if amin < lo else amax
            raise z.err(f"array '{key}' holds {bad}, outside {lo}..{hi}", rule="output-range")
    return a


def _scalar(z: _SafeNpz, key: str, kinds: str) -> float:
    a = z.get(key)
    if a.size != 1 or a.dtype.kind not in kinds:
        raise z.err(f"'{key}' must be one number (got shape {list(a.shape)}, dtype {a.dtype})", rule="output-shape")
    v = a.reshape(()).item()
    if isinstance(v, float) and not math.isfinite(v):
        raise z.err(f"'{key}' is {v}", rule="output-nonfinite")
    return v


def _load_fapframes_npz(path: Path, max_bytes: int) -> FapFrames:
    with _open_npz(path, max_bytes) as z:
        if "format" not in z:
            raise z.err(f"not an {FAPFRAMES_FORMAT} .npz (no 'format' array)", rule="output-format")
        tag = z.get("format")
        if tag.dtype.kind != "U" or tag.shape != () or str(tag) != FAPFRAMES_FORMAT:
            raise z.err(f"format tag is not {FAPFRAMES_FORMAT!r}", rule="output-format")
        values = _want(z, "values", kinds="iu", shape=(None, NUM_FAPS), what="integers")
        n = values.shape[0]
        _int_in(z, "values", values, *_INT32)
        status = _int_in(z, "status", _want(z, "status", kinds="iu", shape=(n, NUM_FAPS), what="integers"),
                         0, max(STATUS_NAMES))
        high = _int_in(z, "high", _want(z, "high", kinds="iu", shape=(n, len(HIGH_LEVEL_FIELDS)),
                                        what="integers"), *_INT32)
        frame_number = _int_in(z, "frame_number", _want(z, "frame_number", kinds="iu", shape=(n,),
                                                        what="integers"), -(2 ** 63), 2 ** 63 - 1)
        time_ms = _want(z, "time_ms", kinds="iuf", shape=(n,), what="numbers").astype(np.float64)
        if not np.isfinite(time_ms).all():
            k = int(np.nonzero(~np.isfinite(time_ms))[0][0])
            raise z.err(f"time_ms of frame {k} is {time_ms[k]}", rule="output-nonfinite")
        kw: dict[str, Any] = {}
        for key, lo, hi in (("is_intra", 0, 1), ("fap_quant", -(2 ** 15), 2 ** 15 - 1),
                            ("coding_type", -128, 127), ("bit_offset", -(2 ** 63), 2 ** 63 - 1)):
            if key in z:
                kw[key] = _int_in(z, key, _want(z, key, kinds="biu", shape=(n,), what="integers"), lo, hi)
        frame_rate = float(_scalar(z, "frame_rate", "iuf")) if "frame_rate" in z else 25.0
        if not frame_rate > 0:
            raise z.err(f"frame_rate is {frame_rate}, must be > 0", rule="output-range")
        gender = int(_scalar(z, "gender", "biu")) if "gender" in z else 0
        return FapFrames(values=values, status=status, high=high, frame_number=frame_number, time_ms=time_ms,
                         frame_rate=frame_rate, gender=gender, **kw)


def _is_zip(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False


def load_output_faps(path, *, max_bytes: int = DEFAULT_MAX_BYTES) -> FapFrames:
    """A decoder's FAP output: ``.fap`` text or an fbaconf FapFrames ``.npz`` (chosen by the
    zip signature, so a mis-named file is still read as what it is).

    Raises :class:`OutputError` naming the file for anything unusable (missing, larger than
    ``max_bytes``, not text / not a zip, wrong format tag, missing arrays, wrong shapes or
    dtypes, out-of-range integers, non-finite times); never another exception. ``.fap``
    reader warnings (recoverable quirks) are accepted silently."""
    path = Path(path)
    try:
        _check_size(path, max_bytes)
        if _is_zip(path) or path.suffix.lower() == ".npz":
            return _load_fapframes_npz(path, max_bytes)
        from fbaconf.bitstreams.faptext import read_fap_file
        frames, _header, _warnings = read_fap_file(path)
        return frames
    except OutputError:
        raise
    except FbaconfInputError as e:
        raise OutputError(f"unreadable FAP output: {e.location() + ': ' if e.location() else ''}{e.message} "
                          f"[rule {e.rule}]", rule="output-fap-text", file=str(path)) from None
    except Exception as e:  # noqa: BLE001 - untrusted input: nothing else may escape
        raise OutputError(f"unreadable FAP output ({type(e).__name__}: {e})", rule="output-unreadable",
                          file=str(path)) from None


def load_output_vertices(path, *, key: str = "vertices", max_bytes: int = DEFAULT_MAX_BYTES) -> np.ndarray:
    """Array ``key`` (float[F, N, 3]) of a decoder's vertices ``.npz`` — the FaceState
    format of ``animation/stateio.py`` or any npz holding that array — as float64. Use
    ``key="extra_feature_points"`` for the feature points of a FaceState (calibration).

    Raises :class:`OutputError` naming the file for a missing/oversized/unreadable file, a
    missing array, a non-float dtype, a shape other than [F, N, 3], or NaN/inf (naming the
    first frame and vertex); never another exception."""
    path = Path(path)
    try:
        _check_size(path, max_bytes)
        with _open_npz(path, max_bytes) as z:
            if key not in z:
                raise z.err(f"no array '{key}' (arrays: {', '.join(sorted(z.members)) or 'none'})",
                            rule="output-array-missing")
            a = _want(z, key, kinds="f", shape=(None, None, 3), what="floats")
            a = a.astype(np.float64)
            bad = ~np.isfinite(a).all(axis=2)
            if bad.any():
                f, v = (int(x[0]) for x in np.nonzero(bad))
                raise z.err(f"array '{key}' is not finite at frame {f}, vertex {v}: {a[f, v].tolist()}",
                            rule="output-nonfinite")
            return a
    except OutputError:
        raise
    except Exception as e:  # noqa: BLE001 - untrusted input: nothing else may escape
        raise OutputError(f"unreadable vertices output ({type(e).__name__}: {e})", rule="output-unreadable",
                          file=str(path)) from None


# ====================================================================================
# FAPs
# ====================================================================================
def _fap_name(number: int) -> str:
    return fap_table()[number - 1].name


def compare_faps(expected: FapFrames, got: FapFrames, *, text_output: bool) -> StageResult:
    """Exact normative comparison of a decoder's FapFrames with the golden ones.

    Per frame (of the frames both have): frame number; every FAP whose expected status is
    not FREE must have the expected value (FAP 1/2: the viseme / expression fields); FREE
    FAPs are not compared. ``text_output=False`` (.npz): the status of every FAP must match
    too. ``text_output=True`` (.fap text carries no SET/RETAINED distinction): a non-FREE
    expected FAP that is FREE in ``got`` is a difference ("expected a value, got none").
    A different frame count fails (reported as the first difference unless an earlier
    frame already differs). With ``.npz`` output plane times must match within
    ``[faps] time_tol_ms`` of the tolerance file. With ``.fap`` output the header's frame
    rate must equal the coded rate within ``[faps] header_rate_tol_hz``, and frame numbers
    may count from 0 or from 1 (one offset for the whole file, reported in the metrics).

    ``first_difference``: frame (index), frame_number, fap, name, what ("value", "status",
    "missing", a high-level field name, "frame number", "frame count"), expected, got.
    ``series``: per compared frame ``faps_differing`` and ``max_abs_diff`` (over the
    compared FAPs/fields). ``metrics``: frames_compared, frames_differing, faps_differing,
    max_abs_diff, expected_frames, got_frames."""
    ne, ng = len(expected), len(got)
    n = min(ne, ng)
    e, g = expected.select(slice(0, n)), got.select(slice(0, n))
    norm = e.status != FREE
    nv = len(VISEME_FIELDS)
    vdiff = (e.values != g.values) & norm
    vdiff[:, :2] = False  # FAP 1/2 live in the high-level fields
    hdiff = e.high != g.high
    hnorm = np.concatenate([np.repeat(norm[:, [0]], nv, axis=1),
                            np.repeat(norm[:, [1]], len(HIGH_LEVEL_FIELDS) - nv, axis=1)], axis=1)
    hdiff &= hnorm
    vdiff[:, 0] |= hdiff[:, :nv].any(axis=1)
    vdiff[:, 1] |= hdiff[:, nv:].any(axis=1)
    if text_output:
        missing = norm & (g.status == FREE)
        sdiff = np.zeros_like(norm)
    else:
        missing = np.zeros_like(norm)
        sdiff = e.status != g.status
    offset = 0
    if text_output and n and np.array_equal(g.frame_number, e.frame_number + 1):
        offset = 1  # a player numbering frames from 1, as the .fap notes allow
    fndiff = e.frame_number + offset != g.frame_number
    rate_bad = False
    if text_output:
        rate_tol = float(load_tolerances().get("faps", {}).get("header_rate_tol_hz", 0.005))
        rate_bad = not abs(float(expected.frame_rate) - float(got.frame_rate)) <= rate_tol
    per_fap = vdiff | sdiff | missing
    # plane times (frame rate, skips, time codes, 1000/1001) are normative too (decision D6);
    # .fap text carries only frame numbers and one rate, so times are compared for .npz output
    time_tol = float(load_tolerances().get("faps", {}).get("time_tol_ms", 0.5))
    with np.errstate(invalid="ignore"):
        tdiff = ~(np.abs(np.asarray(e.time_ms, np.float64) - np.asarray(g.time_ms, np.float64)) <= time_tol)
    if text_output:
        tdiff[:] = False
    bad_frame = per_fap.any(axis=1) | fndiff | tdiff

    absd = np.where(norm, np.abs(e.values.astype(np.int64) - g.values.astype(np.int64)), 0)
    habs = np.where(hnorm, np.abs(e.high.astype(np.int64) - g.high.astype(np.int64)), 0)
    max_abs = np.maximum(absd.max(axis=1, initial=0), habs.max(axis=1, initial=0))
    series = {"faps_differing": [float(x) for x in per_fap.sum(axis=1)],
              "max_abs_diff": [float(x) for x in max_abs]}
    metrics = {"frames_compared": float(n), "frames_differing": float(bad_frame.sum()),
               "faps_differing": float(per_fap.sum()), "max_abs_diff": float(max_abs.max(initial=0)),
               "expected_frames": float(ne), "got_frames": float(ng), "frame_number_offset": float(offset)}

    first: dict[str, Any] | None = None
    detail = ""
    if bad_frame.any():
        k = int(np.nonzero(bad_frame)[0][0])
        fn = int(e.frame_number[k])
        where = f"frame {k} (frame_number {fn})"
        if fndiff[k]:
            first = {"frame": k, "frame_number": fn, "what": "frame number", "expected": fn,
                     "got": int(g.frame_number[k])}
            detail = f"{where}: frame number: expected {fn}, got {int(g.frame_number[k])}"
        elif not per_fap[k].any():
            et, gt = float(e.time_ms[k]), float(g.time_ms[k])
            first = {"frame": k, "frame_number": fn, "what": "time_ms", "expected": et, "got": gt}
            detail = f"{where}: time: expected {et:.3f} ms, got {gt:.3f} ms (tolerance {time_tol:g} ms)"
        else:
            j = int(np.nonzero(per_fap[k])[0][0])
            num, name = j + 1, _fap_name(j + 1)
            first = {"frame": k, "frame_number": fn, "fap": num, "name": name}
            if missing[k, j]:
                exp = _fap_value(e, k, j)
                first.update(what="missing", expected=exp, got=None)
                detail = f"{where}: FAP {num} {name}: expected a value ({exp}), got none"
            elif vdiff[k, j] and j >= 2:
                first.update(what="value", expected=int(e.values[k, j]), got=int(g.values[k, j]))
                detail = f"{where}: FAP {num} {name}: expected {int(e.values[k, j])}, got {int(g.values[k, j])}"
            elif vdiff[k, j]:
                cols = range(0, nv) if j == 0 else range(nv, len(HIGH_LEVEL_FIELDS))
                c = next(c for c in cols if hdiff[k, c])
                field_name = HIGH_LEVEL_FIELDS[c]
                first.update(what=field_name, expected=int(e.high[k, c]), got=int(g.high[k, c]))
                detail = (f"{where}: FAP {num} {name} {field_name}: expected {int(e.high[k, c])}, "
                          f"got {int(g.high[k, c])}")
            else:
                es, gs = int(e.status[k, j]), int(g.status[k, j])
                first.update(what="status", expected=STATUS_NAMES.get(es, str(es)),
                             got=STATUS_NAMES.get(gs, str(gs)))
                detail = (f"{where}: FAP {num} {name} status: expected {first['expected']}, "
                          f"got {first['got']}")
    if rate_bad:
        er, gr = float(expected.frame_rate), float(got.frame_rate)
        first = {"what": "frame rate", "expected": er, "got": gr}
        return StageResult("faps", Outcome.FAIL, f"header frame rate: expected {er:.6g} Hz (the coded rate), got "
                           f"{gr:.6g} Hz", first, metrics, series)
    count_msg = ""
    if ne != ng:
        count_msg = f"frame count: expected {ne}, got {ng}"
        if first is None:
            first = {"frame": n, "what": "frame count", "expected": ne, "got": ng}
    if first is None:
        note = " (frames numbered from 1)" if offset else ""
        return StageResult("faps", Outcome.PASS, f"{n} frame(s) match{note}", None, metrics, series)
    parts = [p for p in (count_msg,) if p]
    if detail:
        parts.append(f"{int(bad_frame.sum())} of {n} frame(s) differ; first at {detail}")
    return StageResult("faps", Outcome.FAIL, "; ".join(parts), first, metrics, series)


def _fap_value(f: FapFrames, k: int, j: int):
    if j >= 2:
        return int(f.values[k, j])
    nv = len(VISEME_FIELDS)
    cols = range(0, nv) if j == 0 else range(nv, len(HIGH_LEVEL_FIELDS))
    return {HIGH_LEVEL_FIELDS[c]: int(f.high[k, c]) for c in cols}


# ====================================================================================
# Vertices
# ====================================================================================
def part_namer(parts) -> Callable[[int], str | None]:
    """A ``part_of(vertex_index)`` callback from FaceState mesh parts (objects with
    ``name``, ``first_vertex``, ``vertex_count``) or ``(name, first, count)`` tuples."""
    rows = sorted((int(p[1]), int(p[2]), str(p[0])) if isinstance(p, (tuple, list))
                  else (int(p.first_vertex), int(p.vertex_count), str(p.name)) for p in parts)
    starts = [r[0] for r in rows]

    def part_of(i: int) -> str | None:
        k = bisect.bisect_right(starts, i) - 1
        if k >= 0 and rows[k][0] <= i < rows[k][0] + rows[k][1]:
            return rows[k][2]
        return None
    return part_of


def compare_vertices(expected: np.ndarray, got: np.ndarray, *, max_tol: float, rms_tol: float,
                     part_of: Callable[[int], str | None] | None = None, what: str = "vertices") -> StageResult:
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
        return StageResult(what, Outcome.ERROR, f"golden {what} are not a finite float[F, N, 3] array "
                                                f"(shape {list(exp.shape)}, dtype {exp.dtype})")
    if gt.dtype.kind not in "fiu":
        return StageResult(what, Outcome.FAIL, f"{what}: dtype {gt.dtype} is not numeric",
                           {"what": "dtype", "expected": "float", "got": str(gt.dtype)})
    if gt.ndim != 3:
        return StageResult(what, Outcome.FAIL, f"{what}: shape {list(gt.shape)}, expected {list(exp.shape)} "
                                               f"([frames, vertices, 3])",
                           {"what": "shape", "expected": list(exp.shape), "got": list(gt.shape)})
    for axis, label in enumerate(("frame count", "vertex count", "coordinate count")):
        if exp.shape[axis] != gt.shape[axis]:
            first = {"what": label, "axis": axis, "expected": int(exp.shape[axis]), "got": int(gt.shape[axis])}
            if axis == 0:
                first["frame"] = int(min(exp.shape[0], gt.shape[0]))
            return StageResult(what, Outcome.FAIL, f"{what}: {label} (axis {axis}): expected {exp.shape[axis]}, "
                                                   f"got {gt.shape[axis]}", first)
    exp = exp.astype(np.float64)
    gt = gt.astype(np.float64)
    F, N = exp.shape[:2]

    def locate(f: int, v: int, **extra) -> dict:
        d = {"frame": f, "vertex": v}
        if part_of is not None:
            d["part"] = part_of(v)
        d.update(expected=exp[f, v].tolist(), got=gt[f, v].tolist(), **extra)
        return d

    def part_txt(d: dict) -> str:
        return f" ({d['part']})" if d.get("part") else ""

    bad = ~np.isfinite(gt).all(axis=2)
    if bad.any():
        f, v = (int(x[0]) for x in np.nonzero(bad))
        first = locate(f, v, what="non-finite")
        return StageResult(what, Outcome.FAIL, f"{what}: frame {f}, vertex {v}{part_txt(first)} is not finite: "
                                               f"expected {first['expected']}, got {first['got']}", first,
                           {"frames_compared": float(F), "vertices": float(N),
                            "nonfinite_values": float((~np.isfinite(gt)).sum())})
    dist = np.sqrt(((gt - exp) ** 2).sum(axis=2)) if N else np.zeros((F, 0))
    fmax = dist.max(axis=1, initial=0.0)
    frms = np.sqrt((dist ** 2).mean(axis=1)) if N else np.zeros(F)
    series = {"max_error": [float(x) for x in fmax], "rms_error": [float(x) for x in frms]}
    over_max = fmax > max_tol
    over_rms = frms > rms_tol
    metrics = {"frames_compared": float(F), "vertices": float(N), "max_error": float(fmax.max(initial=0.0)),
               "rms_error": float(frms.max(initial=0.0)), "frames_over_max": float(over_max.sum()),
               "frames_over_rms": float(over_rms.sum()), "max_tol": float(max_tol), "rms_tol": float(rms_tol)}
    summary = (f"max error {metrics['max_error']:.6g} (tolerance {max_tol:g}), "
               f"rms {metrics['rms_error']:.6g} (tolerance {rms_tol:g}) over {F} frame(s) x {N} {what}")
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
    msg = (f"{what}: first at frame {f}, vertex {v}{part_txt(first)}: {why}: expected "
           f"{_fmt_xyz(first['expected'])}, got {_fmt_xyz(first['got'])}; {summary}")
    return StageResult(what, Outcome.FAIL, msg, first, metrics, series)


def _fmt_xyz(v: Sequence[float]) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


# ====================================================================================
# Images
# ====================================================================================
class _ImageUnreadable(Exception):
    pass




def _read_encoded(path: Path, max_bytes: int, max_pixels: int) -> np.ndarray:
    """An image as float64[H, W, C] sRGB-encoded values: integer formats as stored
    (normalised to [0, 1]), float formats (linear) clipped to [0, 1] and sRGB-encoded.
    Raises _ImageUnreadable with a reason."""
    try:
        _check_size(path, max_bytes)
    except OutputError as e:
        raise _ImageUnreadable(e.message) from None
    size = path.stat().st_size
    if size > max_bytes:
        raise _ImageUnreadable(f"image is {size} bytes, more than the limit of {max_bytes}")
    oiio = _oiio()
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
        px[:, :, :rgb] = np.asarray(_colour().cctf_encoding(np.clip(px[:, :, :rgb], 0.0, 1.0), function="sRGB"))
        px = np.clip(px, 0.0, 1.0)
    return px


def _rgb(px: np.ndarray) -> np.ndarray:
    return px[:, :, :3] if px.shape[2] >= 3 else np.repeat(px[:, :, :1], 3, axis=2)


def _delta_e(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """CIEDE2000 per pixel between two sRGB-encoded float images (RGB[H, W, 3])."""
    colour = _colour()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        la = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(a))
        lb = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(b))
        de = np.asarray(colour.difference.delta_E_CIE2000(la, lb), dtype=np.float64)
    return np.nan_to_num(de, nan=0.0)


def _buf(px: np.ndarray):
    oiio = _oiio()
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
        oiio = _oiio()
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
