"""Processes the harness starts for decoders, below the sandbox's policy: the launcher command
that sets the limits, long-lived servers (a fork server, a persistent decoder), the result of
a finished process, and the registry that kills every running decoder on an interruption.

:mod:`.sandbox` decides what a decoder sees and runs one invocation; this module is what it,
the fork server's client and the persistent protocol share.
"""

from __future__ import annotations

import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import IO, TYPE_CHECKING

from fbaconf.safefs import tree_size

from .cgroups import Cgroups
from .seccomp import NOFILE

if TYPE_CHECKING:
    from .sandbox import Limits

LIMIT_LAUNCHER = Path(__file__).with_name("launcher.py")
_SIGNALS = {int(s) for s in signal.Signals}
TAIL_BYTES = 4000


class Note(StrEnum):
    """What the harness knows of a decoder process's ending beyond its status: the one
    classifier (:mod:`.endings`) reads these, never the decoder's own words."""

    HARNESS_START_FAILED = "harness-start-failed"  # the harness could not start it (or is stopping)
    SANDBOX_FAILED = "sandbox-failed"  # bubblewrap never ran the program
    EXEC_FAILED = "exec-failed"  # the program could not be executed
    AS_LIMIT = "as-limit"  # it ran under an address-space limit
    CPU_LIMIT = "cpu-limit"  # its CPU-time limit ended it
    TREE_MEMORY_LIMIT = "tree-memory-limit"  # the cgroup's memory limit killed a process of its tree
    PROCESS_LIMIT = "process-limit"  # its tree hit the cgroup's process limit
    SUPERVISOR_LOST = "supervisor-lost"  # the fork server died under it
    PROTOCOL_ERROR = "protocol-error"  # it broke the fork-server or persistent protocol
    NOT_REPRODUCED_ALONE = "not-reproduced-alone"  # a persistent ending no input reproduces alone
    NO_ANSWER = "no-answer"  # a persistent process ended (or was stopped) before the input's answer


@dataclass
class ProcResult:
    argv: list[str]
    returncode: int | None  # None when killed by the harness before it exited on its own
    signal: str | None = None  # e.g. "SIGSEGV"
    timed_out: bool = False
    elapsed_s: float = 0.0
    cpu_s: float = 0.0
    maxrss_mb: float = 0.0  # the waited process's own peak (the launcher's when a tree was killed)
    rss_sampled_mb: float = 0.0  # the largest resident set of the decoder's tree the harness sampled
    stdout_tail: str = ""
    stderr_tail: str = ""
    output_limit_hit: bool = False
    memory_limit_hit: bool = False
    output_bytes: int = 0
    # what the harness knows of the ending (Note)
    notes: list[Note] = field(default_factory=list)
    detail: str = ""  # the harness's own words on what it saw (a protocol error, a forged reply)


@dataclass
class Finish:
    """How one decoder process finished, as the harness saw it: its raw wait status and rusage
    (a ``resource.struct_rusage`` or a (utime, stime, maxrss_kb) tuple), and the limits the
    harness (or the kernel, for the cgroup's) enforced."""

    status: int
    rusage: resource.struct_rusage | tuple[float, float, int] | None = None
    elapsed: float = 0.0
    timed_out: bool = False
    mem_hit: bool = False  # resident-set limit (sampled)
    out_hit: bool = False  # output limit, while it ran
    oom: bool = False  # the cgroup's OOM events
    pids_hit: bool = False
    rss_sampled_mb: float = 0.0  # the watch's largest sample of the tree's resident set
    bwrap_status: bool = False  # the status is bubblewrap's (a signal N reads as exit 128 + N)
    notes: tuple[Note, ...] = ()


# what runtimes print when an allocation fails (lower case)
MEMORY_TEXT = (
    "memoryerror",
    "bad_alloc",
    "out of memory",
    "cannot allocate memory",
    "outofmemoryerror",
    "memory allocation of",
    "failed to allocate",
)


def result(
    argv: list[str], limits: Limits, fin: Finish, *, stdout_tail: str, stderr_tail: str, measure_dirs: list[Path]
) -> ProcResult:
    """The :class:`ProcResult` of one finished decoder process: signal names, the limit that
    ended it, the output it left — shared by the one-shot launcher, the fork server and the
    persistent protocol."""
    rc = os.waitstatus_to_exitcode(fin.status)
    if fin.bwrap_status and 128 < rc < 128 + 65 and rc - 128 in _SIGNALS:
        rc = -(rc - 128)  # bubblewrap reports a decoder killed by signal N as exit code 128 + N
    ru = fin.rusage
    if ru is not None and not isinstance(ru, tuple):
        ru = (ru.ru_utime, ru.ru_stime, ru.ru_maxrss)
    killed = fin.timed_out or fin.mem_hit or fin.out_hit
    res = ProcResult(
        argv,
        None if killed else (rc if rc >= 0 else None),
        elapsed_s=fin.elapsed,
        timed_out=fin.timed_out,
        memory_limit_hit=fin.mem_hit or fin.oom,
        output_limit_hit=fin.out_hit,
        cpu_s=(ru[0] + ru[1]) if ru else 0.0,
        maxrss_mb=(ru[2] / 1024.0) if ru else 0.0,
        rss_sampled_mb=fin.rss_sampled_mb,
        stdout_tail=stdout_tail,
        stderr_tail=stderr_tail,
        notes=list(fin.notes),
    )
    if fin.pids_hit:
        res.notes.append(Note.PROCESS_LIMIT)
    if fin.oom:
        res.notes.append(Note.TREE_MEMORY_LIMIT)  # a process of the tree was killed at the cgroup memory limit
    if rc < 0 and not killed:
        try:
            res.signal = signal.Signals(-rc).name
        except ValueError:
            res.signal = f"signal {-rc}"
        if res.signal == "SIGXFSZ":
            res.output_limit_hit = True
        if res.signal == "SIGXCPU":
            res.timed_out = True
            res.notes.append(Note.CPU_LIMIT)
    if Note.AS_LIMIT in res.notes and not res.timed_out and any(s in res.stderr_tail.lower() for s in MEMORY_TEXT):
        res.memory_limit_hit = True
    total = sum(tree_size(d, stop_at=limits.output_mb * 2**20 * 4) for d in measure_dirs)
    res.output_bytes = total
    if total > limits.output_mb * 2**20:
        res.output_limit_hit = True
    return res


def read_tail(path: Path) -> str:
    """The last ``TAIL_BYTES`` of a regular file, read without following a link and without
    blocking (a FIFO or device put in its place reads as empty)."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError:
        return ""
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            return ""
        size = st.st_size
        os.lseek(fd, max(0, size - TAIL_BYTES), os.SEEK_SET)
        data = os.read(fd, TAIL_BYTES)
    except OSError:
        return ""
    finally:
        os.close(fd)
    return ("…" if size > TAIL_BYTES else "") + data.decode("utf-8", "replace")


def tail_from(fd: int, start: int, end: int | None = None) -> str:
    """The last ``TAIL_BYTES`` of what a file open on ``fd`` holds between ``start`` and ``end``."""
    size = os.fstat(fd).st_size if end is None else end
    at = max(start, size - TAIL_BYTES)
    data = os.pread(fd, size - at, at) if size > at else b""
    return ("…" if at > start else "") + data.decode("utf-8", "replace")


# ------------------------------------------------------------------ the launcher

# The shell waits for the harness's go (a line on stdin) once it has been moved into the
# case's cgroups, then execs the launcher with stdin from /dev/null.
_HOLD = 'read -r _ || exit 126; exec "$@" </dev/null'
# A long-lived server's stdin is its protocol's pipe, so nothing can hold it: the shell moves
# itself into the cgroups (its first argument: how many folders follow), then execs the launcher.
_JOIN = (
    'n=$1; shift; while [ "$n" -gt 0 ]; do '
    'echo $$ 2>/dev/null > "$1/cgroup.procs" || { echo "fbaconf-limit: cannot join cgroup $1" >&2; exit 127; }; '
    'shift; n=$((n - 1)); done; exec "$@"'
)


def _rlimit_arg(which: int, value: int) -> str:
    """prlimit's SOFT:HARD for ``value`` as ``launcher._set`` sets it: capped by the current
    hard limit, which it lowers to the value only when it was unlimited."""
    import resource  # noqa: PLC0415 (POSIX only)

    _soft, hard = resource.getrlimit(which)
    if hard == resource.RLIM_INFINITY:
        return f"{value}:{value}"
    return f"{min(value, hard)}:{hard}"


def launch_argv(
    as_bytes: int, fsize: int, cpu: int, cgroups: list[Path], inner: list[str], *, join: bool = False
) -> tuple[list[str], bool]:
    """The launcher command that applies the limits (and ``RLIMIT_NOFILE``) and execs
    ``inner``, and whether it waits for the harness to move it into ``cgroups`` (then write a
    line to its stdin). ``join``: it moves itself into them instead and never reads its stdin
    (a server's, which its protocol owns)."""
    import resource  # noqa: PLC0415 (POSIX only)

    # FBACONF_LAUNCHER=python: always the Python launcher (benchmarks/bench_run.py compares the two)
    prlimit = None if os.environ.get("FBACONF_LAUNCHER", "").lower() == "python" else shutil.which("prlimit")
    if prlimit is None:
        cg = [x for d in cgroups for x in ("--cgroup", str(d))]
        return [
            os.path.realpath(sys.executable),
            "-I",
            "-S",
            str(LIMIT_LAUNCHER),
            str(as_bytes),
            str(fsize),
            str(cpu),
            *cg,
            "--",
            *inner,
        ], False
    lim = [
        f"--{name}={_rlimit_arg(which, v)}"
        for name, which, v in (
            ("as", resource.RLIMIT_AS, as_bytes),
            ("fsize", resource.RLIMIT_FSIZE, fsize),
            ("cpu", resource.RLIMIT_CPU, cpu),
            ("nofile", resource.RLIMIT_NOFILE, NOFILE),
        )
        if v > 0
    ]
    argv = [prlimit, *lim, "--core=0:0", "--", *inner]
    if cgroups and join:
        return ["/bin/sh", "-c", _JOIN, "fbaconf-launch", str(len(cgroups)), *map(str, cgroups), *argv], False
    if cgroups:
        return ["/bin/sh", "-c", _HOLD, "fbaconf-launch", *argv], True
    return argv, False


def release(proc: subprocess.Popen[bytes], cgroups: list[Path]) -> str | None:
    """Move the held launcher into ``cgroups`` and let it go; the reason when it cannot be."""
    try:
        for d in cgroups:
            with open(d / "cgroup.procs", "w") as f:
                f.write(str(proc.pid))
    except OSError as e:
        proc.kill()
        proc.wait()
        return f"fbaconf-limit: cannot join cgroup {d}: {e.strerror}"
    try:
        if proc.stdin is not None:
            proc.stdin.write(b"go\n")
            proc.stdin.close()
    except OSError:
        pass  # the shell died: its ending is the result
    return None


def launch_server(  # noqa: PLR0913 - what starts a server, as sandbox.run takes it
    inner: list[str],
    limits: Limits,
    *,
    cwd: Path,
    env: dict[str, str],
    stderr: int | IO[bytes] | None = None,
    pass_fds: tuple[int, ...] = (),
    as_bytes: int = 0,
    fsize: int = 0,
    cg: Cgroups | None = None,
) -> tuple[subprocess.Popen[bytes], Cgroups]:
    """Start a long-lived process (a fork server, a persistent decoder) through the limit
    launcher, in its own cgroups (``cg``, or new ones for ``limits``) and session, with
    stdin/stdout as pipes; registered so :func:`stop_all` kills it. ``as_bytes``/``fsize``:
    rlimits for the whole process (0 = none; never a CPU-time limit, which would add up over
    inputs). Raises OSError."""
    if cg is None:
        cg = Cgroups(processes=limits.processes, memory_mb=limits.memory_mb if limits.memory_kind != "none" else 0)
    full, _held = launch_argv(as_bytes, fsize, 0, cg.folders(), inner, join=True)
    try:
        proc = subprocess.Popen(
            full,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=stderr,
            cwd=cwd,
            start_new_session=True,
            close_fds=True,
            pass_fds=pass_fds,
            env=env,
        )
    except OSError:
        cg.close()
        raise
    _RUNNING.add(proc.pid)
    return proc, cg


def stop_server(proc: subprocess.Popen[bytes] | None, cg: Cgroups | None, *, grace_s: float = 0.0) -> None:
    """Stop what :func:`launch_server` started: close its stdin (a well-behaved server exits;
    ``grace_s`` to let it), kill its process group, reap it, close its pipes and cgroups."""
    if proc is not None:
        _RUNNING.discard(proc.pid)
        try:
            if proc.stdin is not None:
                proc.stdin.close()
        except OSError:
            pass
        if grace_s:
            try:
                proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                pass
        kill_group(proc.pid)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        try:
            if proc.stdout is not None:
                proc.stdout.close()
        except OSError:
            pass
    if cg is not None:
        cg.close()


def tempfile_dir() -> str:
    return tempfile.mkdtemp(prefix="fbaconf-io-")


def pidfd(pid: int) -> int | None:
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):  # no pidfd_open (kernel < 5.3, not Linux)
        return None


def exit_reported(fd: int | None) -> bool:
    """Whether bubblewrap wrote the sandboxed program's ``exit-code`` on its status descriptor
    (``--json-status-fd``): it does when the program ran and ended, never when the sandbox or
    the exec failed. Reads what is there without blocking and closes ``fd``."""
    if fd is None:
        return True
    data = b""
    try:
        os.set_blocking(fd, False)
        while len(data) < 1 << 16:
            chunk = os.read(fd, 4096)
            if not chunk:
                break
            data += chunk
    except OSError:
        pass
    finally:
        os.close(fd)
    return b'"exit-code"' in data


# ------------------------------------------------------------------ interruption
_RUNNING: set[int] = set()
_STOP = threading.Event()


def stop_all() -> None:
    """Kill every decoder process group this harness is running (Ctrl-C, SIGTERM): each
    running :func:`~fbaconf.isolation.sandbox.run` returns at once; no new decoder starts until
    :func:`reset_stop`."""
    _STOP.set()
    for pid in list(_RUNNING):
        kill_group(pid)


def reset_stop() -> None:
    _STOP.clear()


def stopping() -> bool:
    return _STOP.is_set()


def kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
