"""Description of the machine and software a run happened on, for every report, and the
machine's state while a speed measurement runs.

Deliberately free of personal data: no host name, user name, home folder, environment
variables or network addresses — only what explains a speed figure or a numeric
difference (CPU, OS and kernel, Python, versions of the libraries the comparison uses).

Machine state (Linux; every reader returns None where its source is missing): the CPU time
the whole machine spent busy (``/proc/stat``), the time some task waited for a CPU (pressure
stall information, ``/proc/pressure/cpu`` "some"), this process's and its reaped children's
CPU time (``getrusage``), a thread's CPU time and run-queue wait (``schedstat``), those of a
process tree while it lives (:class:`TreeWatch`), the load average. :func:`machine_sample` takes
the ones a window needs; the speed measurement (:mod:`.speed.load`) turns two of them into what
others used meanwhile.
"""

from __future__ import annotations

import os
import platform
import resource
import subprocess
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from importlib import metadata
from typing import Any

# Distributions whose versions can change a verdict (numerics, image I/O, colour maths).
DISTRIBUTIONS = ("fbaconf", "numpy", "OpenImageIO", "colour-science")


def _cpu_model() -> str:
    """The CPU model name (Linux /proc/cpuinfo, macOS sysctl, else ``platform``)."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() in ("model name", "Hardware", "cpu model", "Processor") and value.strip():
                    return value.strip()
    except OSError:
        pass
    if sys.platform == "darwin":
        try:
            out = subprocess.run(
                ["sysctl", "-n", "machdep.cpu.brand_string"],  # noqa: S607 - the macOS system tool, found where the system puts it
                capture_output=True,
                text=True,
                timeout=5,
                check=False,
            ).stdout.strip()
            if out:
                return out
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.machine() or "unknown"  # not platform.processor(): it starts `uname -p`


def _platform_name() -> str:
    """``platform.platform()``'s words (system-release-machine-libc) without the `uname -p` child
    process it starts: writing a report starts no program."""
    libc = "".join(platform.libc_ver())
    return "-".join(p for p in (platform.system(), platform.release(), platform.machine(), libc) if p)


def _usable_cpus() -> int | None:
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count()


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def system_info(extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """A JSON-ready description of this machine and software, with a UTC timestamp.

    ``extra`` entries (e.g. ``{"jobs": 4}``) are added last and may override keys.
    A library that is not installed has the version ``None``.
    """
    info: dict[str, Any] = {
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_usable": _usable_cpus(),
        "machine": platform.machine(),
        "os": platform.system(),
        "kernel": platform.release(),
        "platform": _platform_name(),
        "python_version": platform.python_version(),
        "python_implementation": platform.python_implementation(),
        "versions": {d: _version(d) for d in DISTRIBUTIONS},
        "timestamp_utc": datetime.now(UTC).isoformat(timespec="seconds").replace("+00:00", "Z"),
    }
    if extra:
        info.update(extra)
    return info


# --------------------------------------------------------------------------- machine state


def _read(path: str) -> str | None:
    try:
        with open(path, encoding="ascii", errors="replace") as f:
            return f.read()
    except OSError:
        return None


def usable_cpus() -> int:
    """CPUs this process may run on (at least 1)."""
    return max(1, _usable_cpus() or 1)


def busy_cpu_s() -> float | None:
    """CPU seconds the whole machine has spent busy since boot, all CPUs together: user, nice,
    system, irq, softirq and steal time (``/proc/stat``; steal is time a hypervisor gave to
    others, so it counts as taken)."""
    text = _read("/proc/stat")
    if not text or not text.startswith("cpu "):
        return None
    try:
        v = [int(x) for x in text.split("\n", 1)[0].split()[1:]]
        busy = v[0] + v[1] + v[2] + sum(v[5:8])
    except (ValueError, IndexError):
        return None
    return busy / os.sysconf("SC_CLK_TCK")


def cpu_pressure_some_s(path: str = "/proc/pressure/cpu") -> float | None:
    """Seconds during which at least one task waited for a CPU (PSI "some" total of ``path``:
    the machine's, or a cgroup's ``cpu.pressure``)."""
    text = _read(path)
    if not text:
        return None
    for line in text.splitlines():
        if line.startswith("some "):
            for field in line.split()[1:]:
                k, _, v = field.partition("=")
                if k == "total":
                    try:
                        return int(v) / 1e6
                    except ValueError:
                        return None
    return None


def _schedstat(path: str) -> tuple[float, float] | None:
    text = _read(path)
    try:
        on_cpu, wait = (int(x) for x in text.split()[:2])  # type: ignore[union-attr]
    except (AttributeError, ValueError):
        return None
    return on_cpu / 1e9, wait / 1e9


def thread_cpu_wait() -> tuple[float, float] | None:
    """(CPU seconds, seconds waiting on a run queue) of the calling thread (``schedstat``)."""
    return _schedstat("/proc/thread-self/schedstat")


@dataclass(frozen=True)
class MachineSample:
    """The machine's counters at one instant (None: not readable here)."""

    t: float  # time.perf_counter()
    busy_s: float | None  # busy_cpu_s()
    pressure_s: float | None  # cpu_pressure_some_s()
    own_s: float  # this process's CPU time plus its reaped children's
    load: float | None  # 1-minute load average


def machine_sample() -> MachineSample:
    """The counters now (a few reads of /proc: cheap enough around every run)."""
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    try:
        load = os.getloadavg()[0]
    except OSError:
        load = None
    return MachineSample(
        t=time.perf_counter(),
        busy_s=busy_cpu_s(),
        pressure_s=cpu_pressure_some_s(),
        own_s=s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime,
        load=load,
    )


class TreeWatch:
    """The run-queue wait and CPU time of the processes under ``pid`` while they live: a thread
    reads every thread's ``schedstat`` each ``interval`` seconds and keeps each one's last
    reading (a process that ends between two readings keeps its last one; one that lives less
    than an interval may be missed), less what the threads already there at the start had.
    ``pid`` itself is left out unless ``include_root``."""

    def __init__(self, pid: int, *, interval: float = 0.02, include_root: bool = False) -> None:
        import threading  # noqa: PLC0415 (only watches need it)

        self.pid, self.interval, self.include_root = pid, interval, include_root
        self._last: dict[tuple[int, int], tuple[float, float]] = {}
        self._base: dict[tuple[int, int], tuple[float, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="fbaconf-treewatch", daemon=True)

    def __enter__(self) -> TreeWatch:
        self.poll()
        self._base = dict(self._last)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _loop(self) -> None:
        while True:
            self.poll()
            if self._stop.wait(self.interval):
                return

    def poll(self) -> None:
        todo, seen = [self.pid], set()
        while todo:
            p = todo.pop()
            if p in seen:
                continue
            seen.add(p)
            try:
                tids = os.listdir(f"/proc/{p}/task")
            except OSError:
                continue
            for t in tids:
                if p != self.pid or self.include_root:
                    s = _schedstat(f"/proc/{p}/task/{t}/schedstat")
                    if s is not None:
                        self._last[(p, int(t))] = s
                kids = _read(f"/proc/{p}/task/{t}/children") or ""
                todo += [int(k) for k in kids.split() if k.isdigit()]

    def _total(self, i: int) -> float:
        return sum(v[i] - self._base.get(k, (0.0, 0.0))[i] for k, v in list(self._last.items()))

    @property
    def cpu_s(self) -> float:
        """CPU seconds of the watched threads since the start."""
        return self._total(0)

    @property
    def wait_s(self) -> float:
        """Seconds the watched threads waited on a run queue since the start."""
        return self._total(1)
