"""Description of the machine and software a run happened on, for every report.

Deliberately free of personal data: no host name, user name, home folder, environment
variables or network addresses — only what explains a speed figure or a numeric
difference (CPU, OS and kernel, Python, versions of the libraries the comparison uses).
"""
from __future__ import annotations

import os
import platform
import subprocess
import sys
from datetime import datetime, timezone
from importlib import metadata

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
            out = subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True,
                                 text=True, timeout=5, check=False).stdout.strip()
            if out:
                return out
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.processor() or platform.machine() or "unknown"


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


def system_info(extra: dict | None = None) -> dict:
    """A JSON-ready description of this machine and software, with a UTC timestamp.

    ``extra`` entries (e.g. ``{"jobs": 4}``) are added last and may override keys.
    A library that is not installed has the version ``None``.
    """
    info: dict = {
        "cpu_model": _cpu_model(),
        "cpu_count": os.cpu_count(),
        "cpu_usable": _usable_cpus(),
        "machine": platform.machine(),
        "os": platform.system(),
        "kernel": platform.release(),
        "platform": platform.platform(),
        "python_version": platform.python_version(),
        "python_implementation": platform.python_implementation(),
        "versions": {d: _version(d) for d in DISTRIBUTIONS},
        "timestamp_utc": datetime.now(timezone.utc).isoformat(timespec="seconds").replace("+00:00", "Z"),
    }
    if extra:
        info.update(extra)
    return info
