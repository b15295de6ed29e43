"""cgroups for one case (or one long-lived server): the whole process tree's memory limit and
process count, and a way to kill every process in it, whatever session or group it moved to.

Works on a v2 unified hierarchy or on v1 ``pids``/``memory`` hierarchies, where the
machine's cgroups are writable (as root, or with a delegated subtree); elsewhere
:func:`cgroup_bases` is empty and the per-process rlimits are the only limits.

Memory. The limit (``memory.max`` on v2, ``memory.limit_in_bytes`` on v1; swap held to the
same total where the swap controls exist) counts what the tree really uses — its resident
pages and the page cache it fills — not the address space a runtime reserves up front (Go
reserves hundreds of megabytes of address space at start, a JVM its whole heap). Page cache
is reclaimed at the limit, so a decoder that writes and reads back 400 MB of scratch files
under a 256 MB limit is slowed, not killed: the memory ending is read from the kernel's
count of OOM events (``memory.events`` ``oom``/``oom_kill`` on v2, ``memory.oom_control``
``oom_kill`` on v1), never from ``memory.failcnt`` or ``memory.events`` ``max``, which count
every time reclaim ran at the limit.
"""

from __future__ import annotations

import os
import signal
import threading
import time
import uuid
from pathlib import Path

_CG_LOCK = threading.Lock()
_CG_BASES: list[tuple[str, Path]] | None = None


def cgroup_bases() -> list[tuple[str, Path]]:
    """Writable cgroup parents for "pids" and "memory": v1 hierarchies or a v2 unified one."""
    global _CG_BASES
    with _CG_LOCK:
        if _CG_BASES is not None:
            return _CG_BASES
        bases: list[tuple[str, Path]] = []
        root = Path("/sys/fs/cgroup")
        for ctrl in ("pids", "memory"):
            v1 = root / ctrl
            if (v1 / "cgroup.procs").exists() and not (v1 / "cgroup.controllers").exists():
                bases.append((ctrl, v1 / "fbaconf"))
        if not bases:
            for v2 in (root, root / "unified"):
                try:
                    ctrls = (v2 / "cgroup.controllers").read_text().split()
                except OSError:
                    continue
                if "pids" in ctrls or "memory" in ctrls:
                    bases.append(("v2", v2 / "fbaconf"))
                    break
        ok = []
        for kind, base in bases:
            try:
                base.mkdir(exist_ok=True)
                if kind == "v2":
                    have = (base.parent / "cgroup.controllers").read_text().split()
                    (base / "cgroup.subtree_control").write_text(
                        " ".join(f"+{c}" for c in ("pids", "memory") if c in have)
                    )
                probe = base / f"probe-{uuid.uuid4().hex[:8]}"
                probe.mkdir()
                probe.rmdir()
                ok.append((kind, base))
            except OSError:
                pass
        _CG_BASES = ok
        return ok


def controllers() -> set[str]:
    """Which of "pids" and "memory" the harness can limit a process tree with here."""
    out: set[str] = set()
    for kind, base in cgroup_bases():
        if kind != "v2":
            out.add(kind)
            continue
        try:
            out |= {"pids", "memory"} & set((base / "cgroup.subtree_control").read_text().split())
        except OSError:
            pass
    return out


class Cgroups:
    """One case's cgroups: a process-count and a memory limit over the whole tree, and a way
    to kill every process in it, whatever session or group it moved to."""

    def __init__(self, *, processes: int, memory_mb: int = 0) -> None:
        """``memory_mb``: the tree's memory limit (0: none)."""
        self.dirs: list[tuple[str, Path]] = []
        self.memory_mb = memory_mb
        name = f"case-{uuid.uuid4().hex[:12]}"
        for kind, base in cgroup_bases():
            d = base / name
            try:
                d.mkdir()
                if kind in ("pids", "v2") and (d / "pids.max").exists():
                    (d / "pids.max").write_text(str(processes))
                if memory_mb:
                    _limit_memory(kind, d, memory_mb * 2**20)
                self.dirs.append((kind, d))
            except OSError:
                _rmdir(d)

    def folders(self) -> list[Path]:
        """The case's cgroup folders (a launcher joins each)."""
        return [d for _k, d in self.dirs]

    def kill_all(self) -> None:
        for _kind, d in self.dirs:
            for _ in range(200):
                try:
                    pids = [int(x) for x in (d / "cgroup.procs").read_text().split()]
                except (OSError, ValueError):
                    break
                if not pids:
                    break
                for pid in pids:
                    try:
                        os.kill(pid, signal.SIGKILL)
                    except OSError:
                        pass
                time.sleep(0.005)

    @property
    def has_memory(self) -> bool:
        """Whether this tree has a memory limit (a memory controller was writable)."""
        return any(k in ("memory", "v2") for k, _d in self.dirs) and self.memory_mb > 0

    def procs(self) -> list[int]:
        """The processes in the tree now (empty when unknown)."""
        for _kind, d in self.dirs:
            try:
                return [int(x) for x in (d / "cgroup.procs").read_text().split()]
            except (OSError, ValueError):
                continue
        return []

    def oom_killed(self) -> bool:
        """Whether the kernel's OOM handling hit this tree (see the module doc: OOM events,
        never the count of times reclaim ran at the limit)."""
        return any(oom_events(d, kind) for kind, d in self.dirs)

    def pids_exhausted(self) -> bool:
        for kind, d in self.dirs:
            try:
                if kind in ("pids", "v2") and int((d / "pids.events").read_text().split()[1]) > 0:
                    return True
            except (OSError, ValueError, IndexError):
                pass
        return False

    def close(self) -> None:
        self.kill_all()
        for _kind, d in self.dirs:
            _rmdir(d)


def _limit_memory(kind: str, d: Path, n: int) -> None:
    if kind == "memory":
        (d / "memory.limit_in_bytes").write_text(str(n))
        _try_write(d / "memory.memsw.limit_in_bytes", str(n))  # no swapping past the limit
    elif kind == "v2" and (d / "memory.max").exists():
        (d / "memory.max").write_text(str(n))
        _try_write(d / "memory.swap.max", "0")


def _try_write(path: Path, text: str) -> None:
    try:
        path.write_text(text)
    except OSError:
        pass  # no swap accounting here


OOM_FILES = {"memory": "memory.oom_control", "v2": "memory.events"}


def oom_events(d: Path | int, kind: str) -> bool:
    """Whether the OOM counters of cgroup ``d`` (a folder, or a descriptor open on its
    ``memory.oom_control``/``memory.events``) are past zero: v2 ``oom``/``oom_kill``, v1
    ``oom_kill`` (kernel 4.13 and later)."""
    if kind not in OOM_FILES:
        return False
    try:
        if isinstance(d, int):
            text = os.pread(d, 4096, 0).decode("ascii", "replace")
        else:
            text = (d / OOM_FILES[kind]).read_text()
    except OSError:
        return False
    wanted = ("oom", "oom_kill") if kind == "v2" else ("oom_kill",)
    for line in text.splitlines():
        k, _, v = line.partition(" ")
        if k in wanted and v.strip().isdigit() and int(v) > 0:
            return True
    return False


def _rmdir(d: Path) -> None:
    for _ in range(50):
        try:
            d.rmdir()
            return
        except FileNotFoundError:
            return
        except OSError:
            time.sleep(0.01)
