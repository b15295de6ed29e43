"""cgroups for one case (or one long-lived server): the whole process tree's memory limit and
process count, and a way to kill every process in it, whatever session or group it moved to.

Works on a v2 unified hierarchy or on v1 ``pids``/``memory`` hierarchies, where the
machine's cgroups are writable (as root, or with a delegated subtree); elsewhere
:func:`cgroup_bases` is empty and the per-process rlimits are the only limits.
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
                        " ".join(f"+{c}" for c in ("pids", "memory") if c in have))
                probe = base / f"probe-{uuid.uuid4().hex[:8]}"
                probe.mkdir()
                probe.rmdir()
                ok.append((kind, base))
            except OSError:
                pass
        _CG_BASES = ok
        return ok


class Cgroups:
    """One case's cgroups: a process-count and a memory limit over the whole tree, and a way
    to kill every process in it, whatever session or group it moved to."""

    def __init__(self, *, processes: int, memory_mb: int = 0) -> None:
        """``memory_mb``: the tree's memory limit (0: none)."""
        self.dirs: list[tuple[str, Path]] = []
        name = f"case-{uuid.uuid4().hex[:12]}"
        for kind, base in cgroup_bases():
            d = base / name
            try:
                d.mkdir()
                if kind in ("pids", "v2") and (d / "pids.max").exists():
                    (d / "pids.max").write_text(str(processes))
                if memory_mb:
                    n = str(memory_mb * 2**20)
                    if kind == "memory":
                        (d / "memory.limit_in_bytes").write_text(n)
                    elif kind == "v2" and (d / "memory.max").exists():
                        (d / "memory.max").write_text(n)
                self.dirs.append((kind, d))
            except OSError:
                _rmdir(d)

    def launcher_args(self) -> list[str]:
        return [x for _k, d in self.dirs for x in ("--cgroup", str(d))]

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

    def oom_killed(self) -> bool:
        for kind, d in self.dirs:
            try:
                if kind == "memory":
                    txt = (d / "memory.oom_control").read_text()
                    if any(ln.split()[:1] == ["oom_kill"] and int(ln.split()[1]) > 0 for ln in txt.splitlines()):
                        return True
                    if int((d / "memory.failcnt").read_text() or 0) > 0:
                        return True
                elif kind == "v2" and (d / "memory.events").exists():
                    for ln in (d / "memory.events").read_text().splitlines():
                        k, v = ln.split()
                        if k in ("oom_kill", "max") and int(v) > 0:
                            return True
            except (OSError, ValueError, IndexError):
                pass
        return False

    def pids_exhausted(self) -> bool:
        for kind, d in self.dirs:
            try:
                if kind == "pids" and int((d / "pids.events").read_text().split()[1]) > 0:
                    return True
            except (OSError, ValueError, IndexError):
                pass
        return False

    def close(self) -> None:
        self.kill_all()
        for _kind, d in self.dirs:
            _rmdir(d)


def _rmdir(d: Path) -> None:
    for _ in range(50):
        try:
            d.rmdir()
            return
        except FileNotFoundError:
            return
        except OSError:
            time.sleep(0.01)
