"""Reading a decoder's output files defensively: regular files only, capped sizes, .npz without pickles
or zip bombs, .fap text."""

from __future__ import annotations

import math
import os
import stat
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import HIGH_LEVEL_FIELDS, STATUS_NAMES, FapFrames
from fbaconf.bitstreams.tables import NUM_FAPS
from fbaconf.errors import FbaconfInputError

from .base import _INT32, DEFAULT_MAX_BYTES, FAPFRAMES_FORMAT, MAX_NPZ_MEMBERS, OutputError


def check_output_file(path: Path, max_bytes: int) -> None:
    """A decoder's output must be a regular file (not a symlink the decoder points at any file,
    not a FIFO that would block the harness, not a device that streams forever) within the cap."""
    try:
        st = os.lstat(path)
    except OSError as e:
        raise OutputError(f"cannot read output: {e.strerror or e}", rule="output-missing", file=str(path)) from None
    if not stat.S_ISREG(st.st_mode):
        kind = (
            "a symbolic link"
            if stat.S_ISLNK(st.st_mode)
            else "a FIFO"
            if stat.S_ISFIFO(st.st_mode)
            else "a directory"
            if stat.S_ISDIR(st.st_mode)
            else "a device or socket"
        )
        raise OutputError(f"output is {kind}; outputs must be regular files", rule="output-unsafe", file=str(path))
    if st.st_size > max_bytes:
        raise OutputError(
            f"output is {st.st_size} bytes, more than the limit of {max_bytes}", rule="output-too-large", file=str(path)
        )


# Exceptions a broken zip / npy can raise while we read it (all become OutputError).
_READ_ERRORS = (
    zipfile.BadZipFile,
    zipfile.LargeZipFile,
    zlib.error,
    OSError,
    EOFError,
    ValueError,
    KeyError,
    TypeError,
    OverflowError,
    NotImplementedError,
    RuntimeError,
    IndexError,
    MemoryError,
    UnicodeError,
    SyntaxError,
)


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
                raise self.err(
                    f"member {i.filename[:80]!r} uses zip compression type {i.compress_type}; .npz "
                    f"members must be stored or deflated",
                    rule="output-npz",
                )
        if sum(i.file_size for i in infos) > max_bytes:
            raise self.err(
                f"the members expand to {sum(i.file_size for i in infos)} bytes, more than the limit of {max_bytes}",
                rule="output-too-large",
            )
        self.members = {i.filename[:-4]: i for i in infos if i.filename.endswith(".npy")}

    def __enter__(self) -> _SafeNpz:
        return self

    def __exit__(self, *exc: object) -> None:
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
            raise self.err(
                f"array '{key}' (shape {list(shape)}, {dtype}) is larger than its data or than "
                f"the limit of {self.max_bytes} bytes",
                rule="output-too-large",
            )
        self.read_bytes += info.file_size
        with self.zf.open(info) as f:
            a = np.lib.format.read_array(f, allow_pickle=False)
        return np.asarray(a)


def open_npz(path: Path, max_bytes: int) -> _SafeNpz:
    try:
        return _SafeNpz(path, max_bytes)
    except _READ_ERRORS as e:
        raise OutputError(f"not a readable .npz (zip) file: {e}", rule="output-npz", file=str(path)) from None


def _want(z: _SafeNpz, key: str, *, kinds: str, shape: tuple[int | None, ...], what: str = "") -> np.ndarray:
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
    return float(v)


def _load_fapframes_npz(path: Path, max_bytes: int) -> FapFrames:
    with open_npz(path, max_bytes) as z:
        if "format" not in z:
            raise z.err(f"not an {FAPFRAMES_FORMAT} .npz (no 'format' array)", rule="output-format")
        tag = z.get("format")
        if tag.dtype.kind != "U" or tag.shape != () or str(tag) != FAPFRAMES_FORMAT:
            raise z.err(f"format tag is not {FAPFRAMES_FORMAT!r}", rule="output-format")
        values = _want(z, "values", kinds="iu", shape=(None, NUM_FAPS), what="integers")
        n = values.shape[0]
        _int_in(z, "values", values, *_INT32)
        status = _int_in(
            z, "status", _want(z, "status", kinds="iu", shape=(n, NUM_FAPS), what="integers"), 0, max(STATUS_NAMES)
        )
        high = _int_in(
            z, "high", _want(z, "high", kinds="iu", shape=(n, len(HIGH_LEVEL_FIELDS)), what="integers"), *_INT32
        )
        frame_number = _int_in(
            z, "frame_number", _want(z, "frame_number", kinds="iu", shape=(n,), what="integers"), -(2**63), 2**63 - 1
        )
        time_ms = _want(z, "time_ms", kinds="iuf", shape=(n,), what="numbers").astype(np.float64)
        if not np.isfinite(time_ms).all():
            k = int(np.nonzero(~np.isfinite(time_ms))[0][0])
            raise z.err(f"time_ms of frame {k} is {time_ms[k]}", rule="output-nonfinite")
        kw: dict[str, Any] = {}
        for key, lo, hi in (
            ("is_intra", 0, 1),
            ("fap_quant", -(2**15), 2**15 - 1),
            ("coding_type", -128, 127),
            ("bit_offset", -(2**63), 2**63 - 1),
        ):
            if key in z:
                kw[key] = _int_in(z, key, _want(z, key, kinds="biu", shape=(n,), what="integers"), lo, hi)
        frame_rate = float(_scalar(z, "frame_rate", "iuf")) if "frame_rate" in z else 25.0
        if not frame_rate > 0:
            raise z.err(f"frame_rate is {frame_rate}, must be > 0", rule="output-range")
        gender = int(_scalar(z, "gender", "biu")) if "gender" in z else 0
        return FapFrames(
            values=values,
            status=status,
            high=high,
            frame_number=frame_number,
            time_ms=time_ms,
            frame_rate=frame_rate,
            gender=gender,
            **kw,
        )


def _is_zip(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(4) == b"PK\x03\x04"
    except OSError:
        return False


def load_output_faps(path: str | os.PathLike[str], *, max_bytes: int = DEFAULT_MAX_BYTES) -> FapFrames:
    """A decoder's FAP output: ``.fap`` text or an fbaconf FapFrames ``.npz`` (chosen by the
    zip signature, so a mis-named file is still read as what it is).

    Raises :class:`OutputError` naming the file for anything unusable (missing, larger than
    ``max_bytes``, not text / not a zip, wrong format tag, missing arrays, wrong shapes or
    dtypes, out-of-range integers, non-finite times); never another exception. ``.fap``
    reader warnings (recoverable quirks) are accepted silently, except a header frame count
    that is not the number of frames written: readers size their buffers by it (Xface 1.0
    crashes on a frame past it), so a decoder writing it wrong writes a broken file."""
    path = Path(path)
    try:
        check_output_file(path, max_bytes)
        if _is_zip(path) or path.suffix.lower() == ".npz":
            return _load_fapframes_npz(path, max_bytes)
        frames, header, _warnings = read_fap_file(path)
        if header.declared_frames != len(frames):
            raise OutputError(
                f"unusable FAP output: the header says {header.declared_frames} frame(s), the file holds {len(frames)}",
                rule="output-fap-count",
                file=str(path),
            )
        return frames
    except OutputError:
        raise
    except FbaconfInputError as e:
        raise OutputError(
            f"unreadable FAP output: {e.location() + ': ' if e.location() else ''}{e.message} [rule {e.rule}]",
            rule="output-fap-text",
            file=str(path),
        ) from None
    except Exception as e:  # noqa: BLE001 - untrusted input: nothing else may escape
        raise OutputError(
            f"unreadable FAP output ({type(e).__name__}: {e})", rule="output-unreadable", file=str(path)
        ) from None


def load_output_vertices(
    path: str | os.PathLike[str], *, key: str = "vertices", max_bytes: int = DEFAULT_MAX_BYTES
) -> np.ndarray:
    """Array ``key`` (float[F, N, 3]) of a decoder's vertices ``.npz`` — the FaceState
    format of ``animation/stateio.py`` or any npz holding that array — as float64. Use
    ``key="extra_feature_points"`` for the feature points of a FaceState (calibration).

    Raises :class:`OutputError` naming the file for a missing/oversized/unreadable file, a
    missing array, a non-float dtype, a shape other than [F, N, 3], or NaN/inf (naming the
    first frame and vertex); never another exception."""
    path = Path(path)
    try:
        check_output_file(path, max_bytes)
        with open_npz(path, max_bytes) as z:
            if key not in z:
                raise z.err(
                    f"no array '{key}' (arrays: {', '.join(sorted(z.members)) or 'none'})", rule="output-array-missing"
                )
            a = _want(z, key, kinds="f", shape=(None, None, 3), what="floats")
            a = a.astype(np.float64)
            bad = ~np.isfinite(a).all(axis=2)
            if bad.any():
                f, v = (int(x[0]) for x in np.nonzero(bad))
                raise z.err(
                    f"array '{key}' is not finite at frame {f}, vertex {v}: {a[f, v].tolist()}", rule="output-nonfinite"
                )
            return a
    except OutputError:
        raise
    except Exception as e:  # noqa: BLE001 - untrusted input: nothing else may escape
        raise OutputError(
            f"unreadable vertices output ({type(e).__name__}: {e})", rule="output-unreadable", file=str(path)
        ) from None
