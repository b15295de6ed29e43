"""Run one untrusted decoder invocation: argv list (never a shell), own directory, limits,
and — where bubblewrap is installed — its own sandbox.

Isolation (``bwrap``, Debian package ``bubblewrap``): the decoder sees the system's
``/usr`` and ``/etc`` read-only, its own program's folder and manifest folder read-only,
its case folder (inputs read-only, outputs writable), an empty ``/tmp`` — and nothing of the
project: not the goldens, the suites, the run folder, the venv or the harness's code
(decoders started through ``{python}`` see the Python installation and the fbaconf package
read-only, with the goldens, suites and run folder hidden). It gets its own PID, network,
IPC and UTS namespaces: no network, and every process it starts dies with the case.
Without bubblewrap (:func:`isolation` says ``"none"``) decoders run unisolated; ``run``
warns once and ``certify`` refuses unless told ``--allow-unisolated``.

Limits per invocation:

* wall-clock ``timeout_s`` — the whole process group is killed (SIGKILL) when it expires;
* memory: ``memory_mb`` as an address-space rlimit per process (``memory_kind =
  "address-space"``, the default), or for runtimes that reserve large virtual ranges up
  front (JVM, some Go/JS runtimes) ``"rss"``: the resident set; ``"none"``. Where the
  machine's cgroups are writable, the limit also holds for the whole process tree together
  (a cgroup memory limit), and ``processes`` caps the number of processes (pids.max);
* output: ``output_mb`` per file (RLIMIT_FSIZE: a write beyond it raises SIGXFSZ in the
  decoder) and in total over the working directory (checked after the run);
* CPU seconds (RLIMIT_CPU, a backstop at twice the timeout); no core dumps.

The limits are applied by a launcher, so nothing runs between fork and exec in this
(threaded) process: util-linux's ``prlimit`` (about 1.5 ms), which sets the rlimits and execs
bubblewrap (or the program); with cgroups, ``/bin/sh`` holds the launch until the harness
has moved it into the case's cgroups, so everything the decoder starts is counted. Without
``prlimit``, a Python launcher (``launcher.py``, about 13 ms) joins the cgroups and sets the
rlimits itself. stdout and stderr go to files outside the decoder's view; only
their tails are kept, read without following links or blocking.

The result names what happened — exit code, signal name, timeout, output limit, memory
limit — and :mod:`.endings` turns it into an outcome with a useful message.
"""
from __future__ import annotations

import functools
import importlib.util
import math
import os
import pkgutil
import select
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import fbaconf
from fbaconf.safefs import tree_size

from .cgroups import Cgroups

LIMIT_LAUNCHER = Path(__file__).with_name("launcher.py")
_SIGNALS = {int(s) for s in signal.Signals}
MEMORY_KINDS = ("address-space", "rss", "none")
TAIL_BYTES = 4000


# Sane bounds of every limit: a limit outside them is a manifest error, never a disabled check.
MAX_TIMEOUT_S = 24 * 3600.0
MAX_MEMORY_MB = 1 << 20
MAX_OUTPUT_MB = 1 << 20
MAX_PROCESSES = 4096


@dataclass(frozen=True)
class Limits:
    timeout_s: float = 60.0
    memory_mb: int = 2048
    memory_kind: str = "address-space"
    output_mb: int = 256
    processes: int = 64

    def __post_init__(self) -> None:
        if self.memory_kind not in MEMORY_KINDS:
            raise ValueError(f"memory_kind must be one of {', '.join(MEMORY_KINDS)}, not {self.memory_kind!r}")
        t = self.timeout_s
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or \
                not 0 < t <= MAX_TIMEOUT_S:
            raise ValueError(f"timeout_s must be a number of seconds in (0, {MAX_TIMEOUT_S:g}], not {t!r}")
        for name, v, lo, hi in (("memory_mb", self.memory_mb, 0, MAX_MEMORY_MB),
                                ("output_mb", self.output_mb, 1, MAX_OUTPUT_MB),
                                ("processes", self.processes, 1, MAX_PROCESSES)):
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"{name} must be a whole number in [{lo}, {hi}], not {v!r}")


@dataclass
class View:
    """What a sandboxed decoder sees: read-only paths, writable paths, and paths hidden (an
    empty tmpfs) inside the read-only ones. Paths that do not exist are skipped."""
    read_only: list[Path] = field(default_factory=list)
    writable: list[Path] = field(default_factory=list)
    hidden: list[Path] = field(default_factory=list)
    read_only_inside: list[Path] = field(default_factory=list)  # re-bound read-only inside writable ones


# The system folders every sandbox shows read-only (a link among them is recreated as the link).
SYSTEM_TOPS = ("/usr", "/etc", "/bin", "/sbin", "/lib", "/lib32", "/lib64", "/libx32")

_ISOLATION: str | None = None
_ISO_LOCK = threading.Lock()


def isolation() -> str:
    """``"bwrap"`` when bubblewrap can make a sandbox on this machine, else ``"none"``
    (``FBACONF_SANDBOX=none`` forces it off, for debugging a decoder)."""
    global _ISOLATION
    with _ISO_LOCK:
        if _ISOLATION is None:
            _ISOLATION = "none"
            exe = shutil.which("bwrap")
            if exe and os.environ.get("FBACONF_SANDBOX", "") != "none":
                try:
                    r = subprocess.run([exe, "--unshare-all", "--die-with-parent", "--ro-bind", "/", "/", "--",
                                        "/bin/true"], capture_output=True, timeout=10)
                    if r.returncode == 0:
                        _ISOLATION = "bwrap"
                except (OSError, subprocess.SubprocessError):
                    pass
        return _ISOLATION


def _under_any(p: Path, roots: list[Path]) -> bool:
    return any(p == r or r in p.parents for r in roots)


def _bwrap_argv(view: View, workdir: Path) -> list[str]:
    out = [shutil.which("bwrap") or "bwrap", "--die-with-parent", "--new-session", "--unshare-all",
           "--cap-drop", "ALL"]
    for top in SYSTEM_TOPS:
        p = Path(top)
        if p.is_symlink():
            out += ["--symlink", os.readlink(p), top]
        elif p.is_dir():
            out += ["--ro-bind", top, top]
    # the sandbox's own /proc (its PID namespace: none of the host's processes), /dev, /tmp
    out += ["--proc", "/proc", "--dev", "/dev", "--tmpfs", "/tmp"]
    seen = set()
    for p in view.read_only:
        p = Path(p)
        if p.exists() and str(p) not in seen:
            seen.add(str(p))
            out += ["--ro-bind", str(p), str(p)]
    shown = [Path(x) for x in seen] + [Path(p) for p in view.writable] + [Path(t) for t in SYSTEM_TOPS]
    for p in [*view.hidden, *sorted(_SECRETS)]:  # only what would otherwise show: no mount point for the rest
        p = Path(p)
        if not _under_any(p, shown) or p.is_symlink():
            continue
        if p.is_dir():
            out += ["--tmpfs", str(p)]
        elif p.exists():
            out += ["--ro-bind", "/dev/null", str(p)]  # a hidden file: opening it fails (nodev)
    for p in view.writable:
        if Path(p).exists():
            out += ["--bind", str(p), str(p)]
    for p in view.read_only_inside:
        if Path(p).exists():
            out += ["--ro-bind", str(p), str(p)]
    out += ["--chdir", str(workdir), "--"]
    return out


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
    text = data.decode("utf-8", "replace")
    return ("…" if size > TAIL_BYTES else "") + text


def _rss_mb(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            pages = int(f.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def default_view(argv: list[str], workdir: Path) -> View:
    """The program's folder read-only, the working folder writable (its ``in/`` read-only)."""
    ro = []
    prog = argv[0] if "/" in argv[0] else shutil.which(argv[0])
    if prog:
        ro += [Path(prog).parent, Path(prog).resolve().parent]
    return View(read_only=ro, writable=[Path(workdir)], read_only_inside=[Path(workdir) / "in"])


_SECRETS: set[Path] = set()


def keep_secret(path: Path) -> None:
    """Hide ``path`` (a signing key read before any decoder starts) from every decoder view
    from now on, wherever a view would show it: a device node is mounted over it, which the
    sandbox's nodev mounts refuse to open (EACCES)."""
    p = Path(os.path.abspath(path))
    _SECRETS.update({p, p.resolve()})


# Folders no view may show, nor any folder below them: the kernel's and the runtime's.
_NEVER_SHOWN = ("/proc", "/sys", "/dev", "/run")


def view_problem(path: Path, hidden=()) -> str | None:
    """Why a folder must not be shown to a decoder read-only, or None: the whole file system,
    a top-level folder other than the system ones (``/tmp``, ``/home``, ``/root``: every user's
    and every run's files), anything under /proc, /sys, /dev or /run (the host's processes), a
    folder holding the fbaconf project or the user's home (goldens' build copies, keys, other
    runs), or a folder inside one that is ``hidden``. Checked as given and with links resolved."""
    pkg_root = Path(fbaconf.__file__).resolve().parent.parent
    guarded = [pkg_root, Path.home().resolve()]
    given = Path(os.path.abspath(path))
    never = [Path(t) for t in _NEVER_SHOWN]
    if _under_any(given, never):
        return "that is the kernel's or the runtime's (the host's processes)"
    try:
        forms = {given, given.resolve()}
    except OSError as e:
        return f"it cannot be resolved ({e.strerror})"
    for q in forms:
        if q == Path("/"):
            return "that is the whole file system"
        if _under_any(q, never):
            return "that is the kernel's or the runtime's (the host's processes)"
        if len(q.parts) == 2 and str(q) not in SYSTEM_TOPS:
            return "a top-level folder holds every user's and every run's files"
        for g in guarded:
            if q == g or q in g.parents:
                return f"it holds {g} (the fbaconf project or the home folder)"
        for h in hidden:
            h = Path(h).resolve()
            if q == h or h in q.parents:
                return f"it lies inside {h}, which decoders never see"
    return None


def python_view() -> list[Path]:
    """What a decoder started through ``{python}`` needs read-only: the Python installation,
    the venv and the folders the fbaconf package is imported from — not the project folder
    around them (tests, build copies, keys, other runs). The caller hides the goldens, the
    suites and the run folder inside them."""
    return [Path(sys.base_prefix).resolve(), Path(sys.prefix).resolve(), Path(sys.prefix), *package_dirs()]


@functools.lru_cache(maxsize=1)
def package_dirs() -> tuple[Path, ...]:
    """The folders ``import fbaconf`` reads: one folder for an installed wheel; for an editable
    install, ``fbaconf/`` and one folder per stage (``harness/``, ``bitstreams/``...) — never
    the project root, and never the goldens' package (``fbaconf.golden``)."""
    top = Path(fbaconf.__file__).resolve().parent
    names = {m.name for m in pkgutil.iter_modules([str(top)]) if m.ispkg}
    names |= {d.name for d in top.parent.iterdir() if (d / "__init__.py").is_file() and d.name.isidentifier()}
    dirs = {top}
    for name in sorted(names - {"golden"}):
        try:
            spec = importlib.util.find_spec(f"fbaconf.{name}")
        except (ImportError, ValueError):
            continue
        for loc in (spec.submodule_search_locations or []) if spec is not None else []:
            dirs.add(Path(loc).resolve())
    return tuple(sorted(d for d in dirs if not any(o in d.parents for o in dirs)))


def decoder_env(workdir: Path, env: dict[str, str] | None) -> dict[str, str]:
    """The minimal environment a decoder gets: PATH, a UTF-8 C locale, HOME and TMPDIR in its
    folder, a few runtime variables kept from the harness's, and the manifest's ``[env]``."""
    tmp = Path(workdir) / "tmp"
    out = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LANG": "C.UTF-8", "LC_ALL": "C.UTF-8",
           "HOME": str(workdir), "TMPDIR": str(tmp), "TMP": str(tmp), "TEMP": str(tmp)}
    for keep in ("SYSTEMROOT", "LD_LIBRARY_PATH", "JAVA_HOME", "PYTHONPATH", "VIRTUAL_ENV"):
        if keep in os.environ:
            out[keep] = os.environ[keep]
    out.update(env or {})
    return out



# The shell waits for the harness's go (a line on stdin) once it has been moved into the
# case's cgroups, then execs the launcher with stdin from /dev/null.
_HOLD = 'read -r _ || exit 126; exec "$@" </dev/null'


def _rlimit_arg(which: int, value: int) -> str:
    """prlimit's SOFT:HARD for ``value`` as ``launcher._set`` sets it: capped by the current
    hard limit, which it lowers to the value only when it was unlimited."""
    import resource  # noqa: PLC0415 (POSIX only)
    _soft, hard = resource.getrlimit(which)
    if hard == resource.RLIM_INFINITY:
        return f"{value}:{value}"
    return f"{min(value, hard)}:{hard}"


def launch_argv(as_bytes: int, fsize: int, cpu: int, cgroups: list[Path], inner: list[str]) -> tuple[list[str], bool]:
    """The launcher command that applies the limits and execs ``inner``, and whether it waits
    for the harness to move it into ``cgroups`` (then write a line to its stdin)."""
    import resource  # noqa: PLC0415 (POSIX only)
    # FBACONF_LAUNCHER=python: always the Python launcher (benchmarks/bench_run.py compares the two)
    prlimit = None if os.environ.get("FBACONF_LAUNCHER", "").lower() == "python" else shutil.which("prlimit")
    if prlimit is None:
        cg = [x for d in cgroups for x in ("--cgroup", str(d))]
        return [os.path.realpath(sys.executable), "-I", "-S", str(LIMIT_LAUNCHER), str(as_bytes), str(fsize),
                str(cpu), *cg, "--", *inner], False
    lim = [f"--{name}={_rlimit_arg(which, v)}" for name, which, v in
           (("as", resource.RLIMIT_AS, as_bytes), ("fsize", resource.RLIMIT_FSIZE, fsize),
            ("cpu", resource.RLIMIT_CPU, cpu)) if v > 0]
    argv = [prlimit, *lim, "--core=0:0", "--", *inner]
    if cgroups:
        return ["/bin/sh", "-c", _HOLD, "fbaconf-launch", *argv], True
    return argv, False


def _release(proc, cgroups: list[Path]) -> str | None:
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
        proc.stdin.write(b"go\n")
        proc.stdin.close()
    except OSError:
        pass  # the shell died: its ending is the result
    return None


def run(argv: list[str], workdir: Path, limits: Limits, *, env: dict[str, str] | None = None,
        measure_dirs: list[Path] | None = None, view: View | None = None) -> ProcResult:
    """Run ``argv`` in ``workdir`` under ``limits`` (sandboxed when :func:`isolation` allows);
    never raises for the decoder's behaviour."""
    if not argv or not all(isinstance(a, str) for a in argv):
        raise ValueError("argv must be a non-empty list of strings")
    workdir = Path(workdir).resolve()
    tmp = workdir / "tmp"
    tmp.mkdir(parents=True, exist_ok=True)
    io_dir = Path(tempfile_dir())
    out_path, err_path = io_dir / "stdout", io_dir / "stderr"
    as_bytes = limits.memory_mb * 2**20 if limits.memory_kind == "address-space" else 0
    fsize = limits.output_mb * 2**20
    cpu = int(max(1, limits.timeout_s * 2 + 1))
    cg = Cgroups(processes=limits.processes,
                 memory_mb=limits.memory_mb if limits.memory_kind != "none" else 0)
    inner = list(argv)
    sandboxed = isolation() == "bwrap"
    if sandboxed:
        inner = _bwrap_argv(view or default_view(argv, workdir), workdir) + inner
    cg_dirs = [d for _k, d in cg.dirs]
    full, held = launch_argv(as_bytes, fsize, cpu, cg_dirs, inner)
    base_env = decoder_env(workdir, env)
    t0 = time.perf_counter()
    try:
        with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
            try:
                proc = subprocess.Popen(full, cwd=workdir, stdin=subprocess.PIPE if held else subprocess.DEVNULL,
                                        stdout=fo, stderr=fe, env=base_env, start_new_session=True, close_fds=True)
            except OSError as e:  # the launcher itself could not start: a harness problem
                cg.close()
                return ProcResult(argv, None, elapsed_s=0.0, stderr_tail=f"cannot start: {e}",
                                  notes=["harness-start-failed"])
            why = _release(proc, cg_dirs) if held else None
            if why is not None:
                cg.close()
                return ProcResult(argv, None, elapsed_s=0.0, stderr_tail=why, notes=["harness-start-failed"])
            _RUNNING.add(proc.pid)
            try:
                status, rusage, timed_out, mem_hit = _wait(proc, t0, limits)
            finally:
                _RUNNING.discard(proc.pid)
                _kill_group(proc.pid)  # leftover children of the decoder
                oom = cg.oom_killed()
                pids_hit = cg.pids_exhausted()
                cg.close()
        elapsed = time.perf_counter() - t0
        res = result(argv, limits, status, rusage, elapsed, timed_out=timed_out, mem_hit=mem_hit, oom=oom,
                     pids_hit=pids_hit, bwrap_status=sandboxed, stdout_tail=_tail(out_path),
                     stderr_tail=_tail(err_path), measure_dirs=measure_dirs or [workdir])
    finally:
        shutil.rmtree(io_dir, ignore_errors=True)
    return res


def result(argv: list[str], limits: Limits, status: int, rusage, elapsed: float, *, timed_out: bool,  # noqa: PLR0913
           mem_hit: bool, oom: bool, pids_hit: bool, bwrap_status: bool, stdout_tail: str, stderr_tail: str,
           measure_dirs: list[Path]) -> ProcResult:
    """The :class:`ProcResult` of one finished decoder process (its raw wait status and
    rusage): signal names, the limit that ended it, the output it left — shared by the
    one-shot launcher (:func:`run`) and the fork server (:mod:`.spawner`).
    ``rusage`` is a ``resource.struct_rusage`` or a (utime, stime, maxrss_kb) tuple."""
    rc = os.waitstatus_to_exitcode(status)
    if bwrap_status and 128 < rc < 128 + 65 and rc - 128 in _SIGNALS:
        rc = -(rc - 128)  # bubblewrap reports a decoder killed by signal N as exit code 128 + N
    if rusage is not None and not isinstance(rusage, tuple):
        rusage = (rusage.ru_utime, rusage.ru_stime, rusage.ru_maxrss)
    res = ProcResult(argv, None if (timed_out or mem_hit) else (rc if rc >= 0 else None), elapsed_s=elapsed,
                     timed_out=timed_out, memory_limit_hit=mem_hit or oom,
                     cpu_s=(rusage[0] + rusage[1]) if rusage else 0.0,
                     maxrss_mb=(rusage[2] / 1024.0) if rusage else 0.0,
                     stdout_tail=stdout_tail, stderr_tail=stderr_tail)
    if pids_hit:
        res.notes.append("process-limit")
    if oom:
        res.notes.append("tree-memory-limit")  # a process of the tree was killed at the cgroup memory limit
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
    for d in measure_dirs:
        total += tree_size(d, stop_at=limits.output_mb * 2**20 * 4)
    res.output_bytes = total
    if total > limits.output_mb * 2**20:
        res.output_limit_hit = True
    return res


def launch_server(inner: list[str], limits: Limits, *, cwd: Path, env: dict[str, str], stderr=None,
                  pass_fds: tuple[int, ...] = (), as_bytes: int = 0, fsize: int = 0) -> tuple[subprocess.Popen, "Cgroups"]:  # noqa: E501
    """Start a long-lived process (a fork server, a persistent decoder) through the limit
    launcher, in its own cgroups and session, with stdin/stdout as pipes; registered so
    :func:`stop_all` kills it. ``as_bytes``/``fsize``: rlimits for the whole process (0 = none;
    never a CPU-time limit, which would add up over inputs). Raises OSError."""
    cg = Cgroups(processes=limits.processes,
                 memory_mb=limits.memory_mb if limits.memory_kind != "none" else 0)
    full = [os.path.realpath(sys.executable), "-I", "-S", str(LIMIT_LAUNCHER), str(as_bytes), str(fsize), "0",
            *cg.launcher_args(), "--", *inner]
    try:
        proc = subprocess.Popen(full, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=stderr, cwd=cwd,
                                start_new_session=True, close_fds=True, pass_fds=pass_fds, env=env)
    except OSError:
        cg.close()
        raise
    _RUNNING.add(proc.pid)
    return proc, cg


def stop_server(proc: subprocess.Popen | None, cg: "Cgroups | None", *, grace_s: float = 0.0) -> None:
    """Stop what :func:`launch_server` started: close its stdin (a well-behaved server exits;
    ``grace_s`` to let it), kill its process group, reap it, close its pipes and cgroups."""
    if proc is not None:
        _RUNNING.discard(proc.pid)
        try:
            proc.stdin.close()
        except OSError:
            pass
        if grace_s:
            try:
                proc.wait(timeout=grace_s)
            except subprocess.TimeoutExpired:
                pass
        _kill_group(proc.pid)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass
        try:
            proc.stdout.close()
        except OSError:
            pass
    if cg is not None:
        cg.close()


def tempfile_dir() -> str:
    return tempfile.mkdtemp(prefix="fbaconf-io-")


def _wait(proc, t0: float, limits: Limits):
    """Wait for the decoder to end, its deadline, its resident-memory limit (sampled every
    10 ms) or a stop: blocked on a pidfd where the kernel has them (no polling delay added
    to a fast decoder's run), else polled with a backoff up to 10 ms."""
    deadline = t0 + limits.timeout_s
    status, rusage, timed_out, mem_hit = None, None, False, False
    delay = 0.0005
    pidfd = _pidfd(proc.pid)
    sample_rss = limits.memory_kind == "rss" and bool(limits.memory_mb)
    try:
        while True:
            pid, st, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                return st, ru, timed_out, mem_hit
            now = time.perf_counter()
            if now >= deadline:
                timed_out = True
            elif sample_rss and _rss_mb(proc.pid) > limits.memory_mb:
                mem_hit = True
            if timed_out or mem_hit or _STOP.is_set():
                _kill_group(proc.pid)
                _pid, status, rusage = os.wait4(proc.pid, 0)
                return status, rusage, timed_out, mem_hit
            if pidfd is not None:
                # stop_all() kills the group, which wakes this; 0.1 s bounds a missed wake-up
                select.select([pidfd], [], [], max(0.0, min(deadline - now, 0.01 if sample_rss else 0.1)))
            else:
                time.sleep(delay)
                delay = min(delay * 2, 0.01)
    finally:
        if pidfd is not None:
            os.close(pidfd)


def _pidfd(pid: int) -> int | None:
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):  # no pidfd_open (kernel < 5.3, not Linux)
        return None


# ------------------------------------------------------------------ interruption
_RUNNING: set[int] = set()
_STOP = threading.Event()


def stop_all() -> None:
    """Kill every decoder process group this harness is running (Ctrl-C, SIGTERM): each
    running :func:`run` returns at once; no new decoder starts until :func:`reset_stop`."""
    _STOP.set()
    for pid in list(_RUNNING):
        _kill_group(pid)


def reset_stop() -> None:
    _STOP.clear()


def stopping() -> bool:
    return _STOP.is_set()


def _kill_group(pid: int) -> None:
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
