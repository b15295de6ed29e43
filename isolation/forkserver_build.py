"""The fork server in C (``forkserver.c``), compiled on first use.

A decoder that runs in a millisecond spends a fifth of its fork-server round trip in the
Python server's own work (parsing the request, ``posix_spawn`` through the interpreter,
waiting, replying); the same loop in C costs a few microseconds. It is built once per
harness process with the machine's C compiler (``$CC``, else ``cc``, ``gcc`` or ``clang``)
into a private temporary folder, removed at exit. Without a compiler, or with
``FBACONF_PURE_PYTHON=1`` or ``FBACONF_FORKSERVER=python``, the harness uses ``forkserver.py``,
which speaks the same protocol
and behaves the same (``tests/integration/test_spawner.py`` runs its cases through both).
"""

from __future__ import annotations

import atexit
import os
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

SOURCE = Path(__file__).with_name("forkserver.c")
NAME = "fbaconf-forkserver"

_lock = threading.Lock()
_built: dict[str, Path | None] = {}


def compiler() -> str | None:
    for name in (os.environ.get("CC"), "cc", "gcc", "clang"):
        if name:
            path = shutil.which(name)
            if path:
                return path
    return None


def forkserver_binary() -> Path | None:
    """The compiled fork server, or None (no compiler, the build failed, or the Python one asked
    for: ``FBACONF_FORKSERVER=python``, as ``benchmarks/bench_fuzz.py`` does to compare them)."""
    if os.environ.get("FBACONF_FORKSERVER", "").lower() == "python" or os.environ.get("FBACONF_PURE_PYTHON") == "1":
        return None
    with _lock:
        if "forkserver" not in _built:
            _built["forkserver"] = _build()
        return _built["forkserver"]


def server_kind() -> str:
    """Which fork server the harness runs: "C" (forkserver.c, built here) or "Python"."""
    return "C" if forkserver_binary() is not None else "Python"


def _build() -> Path | None:
    cc = compiler()
    if cc is None or not SOURCE.is_file():
        return None
    folder = Path(tempfile.mkdtemp(prefix="fbaconf-native-"))
    atexit.register(shutil.rmtree, folder, True)
    exe = folder / NAME
    try:
        r = subprocess.run(
            [cc, "-O2", "-o", str(exe), str(SOURCE)], stdin=subprocess.DEVNULL, capture_output=True, timeout=120
        )
        if r.returncode != 0 or not exe.is_file():
            return None
        # it must run here (a temporary folder mounted noexec, a cross compiler): with its
        # input closed it says its hello and ends
        r = subprocess.run([str(exe)], stdin=subprocess.DEVNULL, capture_output=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return exe if r.returncode == 0 and r.stdout == b"\0\0\0\x05ready" else None
