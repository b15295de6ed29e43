"""Run one untrusted decoder invocation: argv list (never a shell), own directory, limits.

Limits per invocation:

* wall-clock ``timeout_s`` — the whole process group is killed (SIGKILL) when it expires;
* memory: ``memory_mb`` as an address-space rlimit (``memory_kind = "address-space"``,
  the default; allocations beyond it fail inside the decoder), or, for runtimes that
  reserve large virtual ranges up front (JVM, some Go/JS runtimes), ``"rss"``: the harness
  samples the child's resident set and kills it when it exceeds the limit; ``"none"``;
* output: ``output_mb`` per file (RLIMIT_FSIZE: a write beyond it raises SIGXFSZ in the
  decoder) and in total over the working directory (checked after the run);
* CPU seconds (RLIMIT_CPU, a backstop at twice the timeout); no core dumps.

The limits are applied by a tiny launcher (``_limit.py``) that sets the rlimits and execs
the program, so nothing runs between fork and exec in this (threaded) process. stdout and
stderr go to files in the working directory; only their tails are kept.

The result names what happened — exit code, signal name, timeout, output limit, memory
limit — and :func:`classify` turns it into a harness outcome with a useful message.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path


LIMIT_LAUNCHER = Path(__file__).with_name("_limit.py")
MEMORY_KINDS = ("address-space", "rss", "none")
TAIL_BYTES = 4000


@dataclass(frozen=True)
class Limits:
    timeout_s: float = 60.0
    memory_mb: int = 2048
    memory_kind: str = "address-space"
    output_mb: int = 256

    def __post_init__(self) -> None:
        if self.memory_kind not in MEMORY_KINDS:
            raise ValueError(f"memory_kind must be one of {', '.join(MEMORY_KINDS)}, not {self.memory_kind!r}")
        if not (self.timeout_s > 0 and self.memory_mb >= 0 and self.output_mb > 0):
            raise ValueError("limits must be positive")


@dataclass
class ProcResult:
    argv: list[str]
    returncode: int | None  # None when killed by the harness before it exited on its own
    signal: str | None = None  # e.g. "SIGSEGV"
    timed_out: bool = False
    elapsed_s: float = 0.0
    cpu_s: float = 0.0
    maxrss_mb: float = 0.0
    stdout_tail: str = ""
    stderr_tail: str = ""
    output_limit_hit: bool = False
    memory_limit_hit: bool = False
    output_bytes: int = 0
    notes: list[str] = field(default_factory=list)


def _tail(path: Path) -> str:
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - TAIL_BYTES))
            data = f.read()
    except OSError:
        return ""
    text = data.decode("utf-8", "replace")
    return ("…" if size > TAIL_BYTES else "") + text


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _dir_bytes(root: Path, stop_at: int) -> int:
    total = 0
    for dirpath, _dirs, files in os.walk(root):
        for name in files:
            try:
                total += os.lstat(os.path.join(dirpath, name)).st_size
            except OSError:
                pass
            if total > stop_at:
                return total
    return total


def run(argv: list[str], workdir: Path, limits: Limits, *, env: dict[str, str] | None = None,
        measure_dirs: list[Path] | None = None) -> ProcResult:
    """Run ``argv`` in ``workdir`` under ``limits``; never raises for the decoder's behaviour."""
    if not argv or not all(isinstance(a, str) for a in argv):
        raise ValueError("argv must be a non-empty list of strings")
    workdir = Path(workdir)
    tmp = workdir / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    out_path, err_path = workdir / ".stdout", workdir / ".stderr"
    as_bytes = limits.memory_mb * 2**20 if limits.memory_kind == "address-space" else 0
    fsize = limits.output_mb * 2**20
    cpu = int(max(1, limits.timeout_s * 2 + 1))
    full = [sys.executable, "-I", "-S", str(LIMIT_LAUNCHER), str(as_bytes), str(fsize), str(cpu), "--", *argv]
    base_env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LANG": "C.UTF-8", "LC_ALL": "C.UTF-8",
                "HOME": str(workdir), "TMPDIR": str(tmp), "TMP": str(tmp), "TEMP": str(tmp)}
    for keep in ("SYSTEMROOT", "LD_LIBRARY_PATH", "JAVA_HOME", "PYTHONPATH", "VIRTUAL_ENV"):
        if keep in os.environ:
            base_env[keep] = os.environ[keep]
    base_env.update(env or {})
    t0 = time.perf_counter()
    with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
        try:
            proc = subprocess.Popen(full, cwd=workdir, stdin=subprocess.DEVNULL, stdout=fo, stderr=fe,
                                    env=base_env, start_new_session=True, close_fds=True)
        except OSError as e:  # the launcher itself could not start: a harness problem
            return ProcResult(argv, None, elapsed_s=0.0, stderr_tail=f"cannot start: {e}",
                              notes=["harness-start-failed"])
        deadline = t0 + limits.timeout_s
        status, rusage, timed_out, mem_hit = None, None, False, False
        delay = 0.0005
        while True:
            pid, st, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                status, rusage = st, ru
                break
            now = time.perf_counter()
            if now >= deadline:
                timed_out = True
            elif limits.memory_kind == "rss" and limits.memory_mb and _rss_mb(proc.pid) > limits.memory_mb:
                mem_hit = True
            if timed_out or mem_hit:
                _kill_group(proc.pid)
                _pid, status, rusage = os.wait4(proc.pid, 0)
                break
            time.sleep(delay)
            delay = min(delay * 2, 0.01)
        proc.returncode = os.waitstatus_to_exitcode(status)
        _kill_group(proc.pid)  # leftover children of the decoder
    elapsed = time.perf_counter() - t0
    rc = proc.returncode
    res = ProcResult(argv, None if (timed_out or mem_hit) else (rc if rc >= 0 else None), elapsed_s=elapsed,
                     timed_out=timed_out, memory_limit_hit=mem_hit,
                     cpu_s=(rusage.ru_utime + rusage.ru_stime) if rusage else 0.0,
                     maxrss_mb=(rusage.ru_maxrss / 1024.0) if rusage else 0.0,
                     stdout_tail=_tail(out_path), stderr_tail=_tail(err_path))
    if rc < 0 and not (timed_out or mem_hit):
        try:
            res.signal = signal.Signals(-rc).name
        except ValueError:
            res.signal = f"signal {-rc}"
        if res.signal == "SIGXFSZ":
            res.output_limit_hit = True
        if res.signal == "SIGXCPU":
            res.timed_out = True
            res.notes.append("cpu-limit")
    if limits.memory_kind == "address-space" and limits.memory_mb and not res.timed_out:
        err = res.stderr_tail.lower()
        if any(s in err for s in ("memoryerror", "bad_alloc", "out of memory", "cannot allocate memory",
                                  "outofmemoryerror", "memory allocation of", "failed to allocate")):
            res.memory_limit_hit = True
    total = 0
    for d in measure_dirs or [workdir]:
        total += _dir_bytes(Path(d), stop_at=limits.output_mb * 2**20 * 4)
    res.output_bytes = total
    if total > limits.output_mb * 2**20:
        res.output_limit_hit = True
    return res


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
