"""fbaconf's structure-aware mutator in C (``fba_mutator.c``), loaded into the fuzzing loop.

The mutator libFuzzer and AFL++ get from ``fbaconf fuzz export`` is the one ``fbaconf fuzz`` uses:
it parses a face object stream as a decoder does (every plane's header, the symbols of every
arithmetic block), mutates that structure and writes it again through the arithmetic coder, in
microseconds — where the Python mutators (``mutators.py``) first need the reference decoder's parse
of the parent (about a millisecond). It is compiled once per process with the machine's C compiler
(as the fork server is) into a private temporary folder; without one, or with
``FBACONF_PURE_PYTHON=1``, the loop uses the Python mutators (``mutate_stream`` says which ran in
each input's origin).
"""

from __future__ import annotations

import atexit
import ctypes
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

from fbaconf.isolation.forkserver_build import compiler

SOURCE = Path(__file__).with_name("fba_mutator.c")
ROOM = 1 << 16  # bytes a mutation may add (a long skip chain, a duplicated plane)

_lock = threading.Lock()
_lib: list[ctypes.CDLL | None] = []


def _build() -> ctypes.CDLL | None:
    cc = compiler()
    if cc is None or not SOURCE.is_file():
        return None
    folder = Path(tempfile.mkdtemp(prefix="fbaconf-native-"))
    atexit.register(shutil.rmtree, folder, True)
    so = folder / "fba_mutator.so"
    try:
        r = subprocess.run(
            [cc, "-O2", "-shared", "-fPIC", "-o", str(so), str(SOURCE)],
            stdin=subprocess.DEVNULL,
            capture_output=True,
            timeout=120,
        )
        if r.returncode != 0:
            return None
        lib = ctypes.CDLL(str(so))
    except (OSError, subprocess.TimeoutExpired):
        return None
    size, buf, cbuf = ctypes.c_size_t, ctypes.c_char_p, ctypes.c_char_p
    lib.fba_mutate.restype = size
    lib.fba_mutate.argtypes = [buf, size, size, ctypes.c_uint]
    lib.fba_cross.restype = size
    lib.fba_cross.argtypes = [cbuf, size, cbuf, size, buf, size, ctypes.c_uint]
    lib.fba_rewrite.restype = size
    lib.fba_rewrite.argtypes = [cbuf, size, buf, size]
    lib.fba_edit_symbol.restype = size
    lib.fba_edit_symbol.argtypes = [cbuf, size, buf, size, size, ctypes.c_int, ctypes.c_int32]
    return lib


def library() -> ctypes.CDLL | None:
    """The loaded mutator, or None (no compiler, the build failed, or ``FBACONF_PURE_PYTHON=1``)."""
    if os.environ.get("FBACONF_PURE_PYTHON") == "1":
        return None
    with _lock:
        if not _lib:
            _lib.append(_build())
        return _lib[0]


_buffers = threading.local()


def _buffer(size: int) -> ctypes.Array[ctypes.c_char]:
    """This thread's buffer for the mutator's output, at least ``size`` bytes (kept between
    calls: a fresh one per call cost a 64 KiB allocation and clearing, 2-3 % of the loop)."""
    buf = getattr(_buffers, "buf", None)
    if buf is None or len(buf) < size:
        buf = _buffers.buf = ctypes.create_string_buffer(max(size, 2 * ROOM))
    return buf


def mutate(lib: ctypes.CDLL, data: bytes, seed: int) -> bytes:
    """One mutation of ``data`` (the same bytes for the same seed)."""
    buf = _buffer(len(data) + ROOM)
    ctypes.memmove(buf, data, len(data))
    n = lib.fba_mutate(buf, len(data), len(data) + ROOM, seed & 0xFFFFFFFF)
    return ctypes.string_at(buf, n)


def cross(lib: ctypes.CDLL, a: bytes, b: bytes, seed: int) -> bytes:
    """The planes of ``a`` up to one of them, then those of ``b`` from one of them."""
    cap = len(a) + len(b) + ROOM
    out = _buffer(cap)
    n = lib.fba_cross(a, len(a), b, len(b), out, cap, seed & 0xFFFFFFFF)
    return ctypes.string_at(out, n)


def rewrite(lib: ctypes.CDLL, data: bytes) -> bytes | None:
    """``data`` parsed and written again unmutated (None: no plane of it decodes)."""
    cap = len(data) + ROOM
    out = ctypes.create_string_buffer(cap)
    n = lib.fba_rewrite(data, len(data), out, cap)
    return ctypes.string_at(out, n) if n else None


def edit_symbol(lib: ctypes.CDLL, data: bytes, plane: int, which: int, value: int) -> bytes | None:
    """``data`` with one symbol of plane ``plane`` set to ``value`` and written again: ``which`` 0-2
    the viseme block's, 3-6 the expression block's, ``7 + i - 2`` low-level FAP ``i`` (0-based)."""
    cap = len(data) + ROOM
    out = ctypes.create_string_buffer(cap)
    n = lib.fba_edit_symbol(data, len(data), out, cap, plane, which, value)
    return ctypes.string_at(out, n) if n else None
