"""What is watched while a decoder runs: the size of its folder (the output limit holds while
it writes, not only after it ended) and, for ``memory_kind = "rss"``, the resident memory of
its whole process tree (not the launcher's, not only the first process's).

Output. Each file is capped by ``RLIMIT_FSIZE`` (a write past ``output_mb`` raises SIGXFSZ);
the folder's total is measured while the decoder runs — 20 ms after its start, then at an
interval ten times what the last measurement took (at least 20 ms), so a fast decoder is
never measured and a deep tree does not eat the decoder's CPU — and the process tree is
killed the moment the total passes ``output_mb``. A decoder writing at disk speed (2 GB/s)
overshoots the limit by at most what it writes in one interval; a 1.2 GB flood under
``output_mb = 256`` stops a few tens of megabytes past it, long before the disk fills.

Resident memory. The processes of the tree are the case's cgroup's (where cgroups are
writable), else the launcher's descendants (``/proc/PID/task/TID/children``); their
resident sets are summed every 10 ms.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from fbaconf.safefs import tree_size

if TYPE_CHECKING:
    from .sandbox import Limits

FIRST_S = 0.02  # the first output measurement, after the start
RSS_EVERY_S = 0.01
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def descendants(pid: int) -> list[int]:
    """``pid`` and every process below it (the kernel's children lists, no /proc scan)."""
    out, todo, seen = [], [pid], set()
    while todo:
        p = todo.pop()
        if p in seen:
            continue
        seen.add(p)
        out.append(p)
        try:
            tids = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for t in tids:
            try:
                with open(f"/proc/{p}/task/{t}/children", "rb") as f:
                    todo += [int(x) for x in f.read().split()]
            except (OSError, ValueError):
                pass
    return out


def rss_mb(pids: list[int]) -> float:
    """The summed resident sets of ``pids`` (MB)."""
    total = 0
    for pid in pids:
        try:
            with open(f"/proc/{pid}/statm", "rb") as f:
                total += int(f.read().split()[1])
        except (OSError, ValueError, IndexError):
            pass
    return total * _PAGE / 2**20


class Watch:
    """Limits checked while one decoder (or one input of a server) runs; :meth:`check` says
    which one it passed ("output" or "memory"), :meth:`next_in` when to look again."""

    def __init__(
        self,
        limits: Limits,
        dirs: list[Path],
        *,
        pid: int | None = None,
        procs: Callable[[], list[int]] | None = None,
        t0: float | None = None,
    ) -> None:
        self.limit = limits.output_mb * 2**20
        self.dirs = [Path(d) for d in dirs]
        self.rss_limit = (
            limits.memory_mb
            if (limits.memory_kind == "rss" and limits.memory_mb and (pid is not None or procs is not None))
            else 0
        )
        self.pid, self.procs = pid, procs
        t0 = time.perf_counter() if t0 is None else t0
        self.next_output = t0 + FIRST_S
        self.next_rss = t0 + RSS_EVERY_S if self.rss_limit else float("inf")
        self.bytes = 0
        self.rss_peak_mb = 0.0  # the largest resident set of the tree sampled so far

    def next_in(self, now: float) -> float:
        return max(0.0, min(self.next_output, self.next_rss) - now)

    def check(self, now: float) -> str | None:
        if now >= self.next_rss:
            self.next_rss = now + RSS_EVERY_S
            pids = (self.procs() if self.procs else []) or (descendants(self.pid) if self.pid else [])
            rss = rss_mb(pids)
            self.rss_peak_mb = max(self.rss_peak_mb, rss)
            if rss > self.rss_limit:
                return "memory"
        if now >= self.next_output and self.dirs:
            t = time.perf_counter()
            self.bytes = sum(tree_size(d, stop_at=self.limit) for d in self.dirs)
            took = time.perf_counter() - t
            self.next_output = time.perf_counter() + max(FIRST_S, 10 * took)
            if self.bytes > self.limit:
                return "output"
        return None
