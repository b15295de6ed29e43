"""Run one untrusted decoder invocation: argv list (never a shell), own directory, limits,
and — where bubblewrap is installed — its own sandbox.

Isolation (``bwrap``, Debian package ``bubblewrap``): the decoder sees the system's
``/usr`` and ``/etc`` read-only, the folders of its program and of the files its command
names and its manifest's folder read-only (each judged by content first, :mod:`.view`), its
case folder (inputs read-only, outputs writable, :mod:`.staging`), an empty ``/tmp`` — and
nothing of the project: not the goldens, the suites, the run folder, the venv or the harness's code
(decoders started through ``{python}`` see the Python installation and the fbaconf package
read-only, with the goldens, suites and run folder hidden). It gets its own PID, network,
IPC and UTS namespaces: no network, and every process it starts dies with the case.
Without bubblewrap (:func:`isolation` says ``"none"``) decoders run unisolated; ``run``
warns once and ``certify`` refuses unless told ``--allow-unisolated``.

Limits per invocation:

* wall-clock ``timeout_s`` — the whole process group is killed (SIGKILL) when it expires;
* memory (``memory_kind``): ``"tree"`` (the default) — ``memory_mb`` over the whole process
  tree, as a cgroup memory limit where the machine's cgroups are writable (what the tree
  really uses: a Go or Java runtime's address-space reservation does not count), else as an
  address-space rlimit per process (the fallback, :mod:`.report` says so);
  ``"address-space"`` — the rlimit per process always (and the cgroup limit too);
  ``"rss"`` — the resident set of the whole tree, sampled every 10 ms (and the cgroup limit);
  ``"none"`` (the harness's own use: a manifest may not ask for it, :mod:`.bounds`).
  ``processes`` caps the number of processes (pids.max). A runtime that dies reserving its
  address space under an address-space limit is a set-up problem (:mod:`.endings` names the
  runtime's message and the fix; :mod:`.setup` proves it before a run's cases);
* output: ``output_mb`` per file (RLIMIT_FSIZE: a write beyond it raises SIGXFSZ in the
  decoder) and in total over the working directory, measured while the decoder runs
  (:mod:`.watch`: the tree is killed once past the limit) and after;
* CPU seconds (RLIMIT_CPU, a backstop at twice the timeout); 1024 descriptors per process;
  no core dumps; no inotify or fanotify instances and no new namespaces (:mod:`.seccomp`: a
  decoder cannot take the host user's).

The limits are applied by a launcher, so nothing runs between fork and exec in this (threaded)
process: util-linux's ``prlimit`` (about 1.5 ms), which sets the rlimits and execs bubblewrap
(or the program); with cgroups, ``/bin/sh`` holds the launch until the harness has moved it
into the case's cgroups, so everything the decoder starts is counted; a long-lived server's (a
fork server, a persistent decoder: its stdin is its protocol's) moves itself into them before
it execs ``prlimit``. Without ``prlimit``, a Python launcher (``launcher.py``, about 13 ms)
joins the cgroups and sets the rlimits itself. stdout and stderr go to files outside the
decoder's view; only their tails are kept, read without following links or blocking.

Set-up failures are the harness's own knowledge, never read from the decoder's output: the
program is checked before the start (:mod:`.preflight`: found, a regular executable file,
its ``#!`` interpreter present), and bubblewrap reports on a status descriptor whether the
program ran (``--json-status-fd``: an ``exit-code`` only when it did) — an ending without
one is the sandbox's or the exec's failure, whatever the decoder could have printed.

The result names what happened — exit code, signal name, timeout, output limit, memory
limit — and :mod:`.endings` turns it into an outcome with a useful message.
"""

from __future__ import annotations

import functools
import importlib.util
import math
import os
import pkgutil
import resource
import select
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import fbaconf

from . import preflight, seccomp
from .cgroups import Cgroups

# the names callers import from here, re-exported (`X as X`)
from .process import (
    _RUNNING as _RUNNING,
    _STOP as _STOP,
    LIMIT_LAUNCHER as LIMIT_LAUNCHER,
    TAIL_BYTES as TAIL_BYTES,
    Finish as Finish,
    Note as Note,
    ProcResult as ProcResult,
    exit_reported as exit_reported,
    kill_group as kill_group,
    launch_argv as launch_argv,
    launch_server as launch_server,
    pidfd as pidfd,
    read_tail as read_tail,
    release as release,
    reset_stop as reset_stop,
    result as result,
    stop_all as stop_all,
    stop_server as stop_server,
    stopping as stopping,
    tempfile_dir as tempfile_dir,
)
from .watch import Watch

MEMORY_KINDS = ("tree", "address-space", "rss", "none")


# Sane bounds of every limit: a limit outside them is a manifest error, never a disabled check.
MAX_TIMEOUT_S = 24 * 3600.0
MAX_MEMORY_MB = 1 << 20
MAX_OUTPUT_MB = 1 << 20
MAX_PROCESSES = 4096


@dataclass(frozen=True)
class Limits:
    timeout_s: float = 60.0
    memory_mb: int = 2048
    memory_kind: str = "tree"
    output_mb: int = 256
    processes: int = 64

    def __post_init__(self) -> None:
        if self.memory_kind not in MEMORY_KINDS:
            raise ValueError(f"memory_kind must be one of {', '.join(MEMORY_KINDS)}, not {self.memory_kind!r}")
        t = self.timeout_s
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or not 0 < t <= MAX_TIMEOUT_S:
            raise ValueError(f"timeout_s must be a number of seconds in (0, {MAX_TIMEOUT_S:g}], not {t!r}")
        for name, v, lo, hi in (
            ("memory_mb", self.memory_mb, 0, MAX_MEMORY_MB),
            ("output_mb", self.output_mb, 1, MAX_OUTPUT_MB),
            ("processes", self.processes, 1, MAX_PROCESSES),
        ):
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
                    r = subprocess.run(
                        [exe, "--unshare-all", "--die-with-parent", "--ro-bind", "/", "/", "--", "/bin/true"],
                        capture_output=True,
                        timeout=10,
                    )
                    if r.returncode == 0:
                        _ISOLATION = "bwrap"
                except (OSError, subprocess.SubprocessError):
                    pass
        return _ISOLATION


def _under_any(p: Path, roots: list[Path]) -> bool:
    return any(p == r or r in p.parents for r in roots)


def _bwrap_argv(view: View, workdir: Path) -> list[str]:
    out = [shutil.which("bwrap") or "bwrap", "--die-with-parent", "--new-session", "--unshare-all", "--cap-drop", "ALL"]
    for top in SYSTEM_TOPS:
        p = Path(top)
        if p.is_symlink():
            out += ["--symlink", os.readlink(p), top]
        elif p.is_dir():
            out += ["--ro-bind", top, top]
    # the sandbox's own /proc (its PID namespace: none of the host's processes), /dev, /tmp
    out += ["--proc", "/proc", "--dev", "/dev", "--tmpfs", "/tmp"]  # noqa: S108 - the sandbox mounts a fresh tmpfs of its own there
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


def default_view(argv: list[str], workdir: Path) -> View:
    """The program's folder read-only, the working folder writable (its ``in/`` read-only); for
    the running Python interpreter, its whole installation (an interpreter linked to a shared
    libpython finds it in the installation's ``lib/``, not beside itself)."""
    ro = []
    prog = argv[0] if "/" in argv[0] else shutil.which(argv[0])
    if prog:
        ro += [Path(prog).parent, Path(prog).resolve().parent]
        if Path(prog).resolve() == Path(sys.executable).resolve():
            ro.append(Path(sys.base_prefix).resolve())
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


def view_problem(path: Path, hidden: Iterable[Path | str] = ()) -> str | None:
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
        if any(k.parent == q or q in k.parents for k in _SECRETS):
            return "it holds the signing key (keep the key outside every folder a decoder sees)"
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
    out = {
        "PATH": os.environ.get("PATH", "/usr/bin:/bin"),
        "LANG": "C.UTF-8",
        "LC_ALL": "C.UTF-8",
        "HOME": str(workdir),
        "TMPDIR": str(tmp),
        "TMP": str(tmp),
        "TEMP": str(tmp),
    }
    for keep in ("SYSTEMROOT", "LD_LIBRARY_PATH", "JAVA_HOME", "PYTHONPATH", "VIRTUAL_ENV"):
        if keep in os.environ:
            out[keep] = os.environ[keep]
    out.update(env or {})
    return out


# ------------------------------------------------------------------ one invocation


def as_bytes_for(limits: Limits, cg: Cgroups | None) -> int:
    """The address-space rlimit (bytes, 0 = none) a decoder process gets: always for
    ``memory_kind = "address-space"``; for ``"tree"`` only where no cgroup holds the tree's
    memory (``cg`` has no memory limit), the fallback."""
    if not limits.memory_mb:
        return 0
    if limits.memory_kind == "address-space" or (
        limits.memory_kind == "tree" and not (cg is not None and cg.has_memory)
    ):
        return limits.memory_mb * 2**20
    return 0


def sandbox_argv(view: View, workdir: Path, fds: list[int], *, status: bool = True) -> tuple[list[str], int | None]:
    """bubblewrap's command for ``view``, with the seccomp filter (:mod:`.seccomp`) and, when
    ``status``, a status descriptor: returns (argv, the descriptor to read bubblewrap's status
    from). The descriptors bubblewrap reads are added to ``fds`` (pass them to the start,
    close them after)."""
    argv = _bwrap_argv(view, workdir)
    extra: list[str] = []
    if seccomp.supported():
        sfd = seccomp.program_fd()
        fds.append(sfd)
        extra += ["--seccomp", str(sfd)]
    status_r = None
    if status:
        status_r, w = os.pipe()
        fds.append(w)
        extra += ["--json-status-fd", str(w)]
    return argv[:1] + extra + argv[1:], status_r


def run(
    argv: list[str],
    workdir: Path,
    limits: Limits,
    *,
    env: dict[str, str] | None = None,
    measure_dirs: list[Path] | None = None,
    view: View | None = None,
    keep_io: Path | None = None,
) -> ProcResult:
    """Run ``argv`` in ``workdir`` under ``limits`` (sandboxed when :func:`isolation` allows);
    never raises for the decoder's behaviour. ``keep_io``: a folder to keep the whole stdout and
    stderr in (``stdout.txt``, ``stderr.txt``; ``--keep-workdirs``), written once the decoder's
    tree is gone."""
    if not argv or not all(isinstance(a, str) for a in argv):
        raise ValueError("argv must be a non-empty list of strings")
    workdir = Path(workdir).resolve()
    (workdir / "tmp").mkdir(parents=True, exist_ok=True)
    base_env = decoder_env(workdir, env)
    why = preflight.exec_problem(argv, base_env)
    if why is not None:  # known before the start: nothing runs
        return ProcResult(argv, None, stderr_tail=why, notes=[Note.EXEC_FAILED])
    measure = measure_dirs or [workdir]
    cg = Cgroups(processes=limits.processes, memory_mb=limits.memory_mb if limits.memory_kind != "none" else 0)
    as_bytes = as_bytes_for(limits, cg)
    fds: list[int] = []
    status_r = None
    sandboxed = isolation() == "bwrap"
    inner = list(argv)
    if sandboxed:
        head, status_r = sandbox_argv(view or default_view(argv, workdir), workdir, fds)
        inner = head + inner
    cg_dirs = [d for _k, d in cg.dirs]
    full, held = launch_argv(as_bytes, limits.output_mb * 2**20, int(max(1, limits.timeout_s * 2 + 1)), cg_dirs, inner)
    io_dir = Path(tempfile_dir())
    out_path, err_path = io_dir / "stdout", io_dir / "stderr"
    t0 = time.perf_counter()
    try:
        with open(out_path, "wb") as fo, open(err_path, "wb") as fe:
            try:
                proc = subprocess.Popen(
                    full,
                    cwd=workdir,
                    stdin=subprocess.PIPE if held else subprocess.DEVNULL,
                    stdout=fo,
                    stderr=fe,
                    env=base_env,
                    start_new_session=True,
                    close_fds=True,
                    pass_fds=tuple(fds),
                )
            except OSError as e:  # the launcher itself could not start: a harness problem
                cg.close()
                return ProcResult(argv, None, stderr_tail=f"cannot start: {e}", notes=[Note.HARNESS_START_FAILED])
            finally:
                for fd in fds:
                    os.close(fd)
            why = release(proc, cg_dirs) if held else None
            if why is not None:
                cg.close()
                return ProcResult(argv, None, stderr_tail=why, notes=[Note.HARNESS_START_FAILED])
            _RUNNING.add(proc.pid)
            try:
                watch = Watch(limits, measure, pid=proc.pid, procs=cg.procs if cg.dirs else None, t0=t0)
                status, rusage, hit = _wait(proc, t0, limits, watch)
            finally:
                _RUNNING.discard(proc.pid)
                kill_group(proc.pid)  # leftover children of the decoder
                oom, pids_hit = cg.oom_killed(), cg.pids_exhausted()
                cg.close()
        notes = [Note.AS_LIMIT] if as_bytes else []
        ran, status_r = exit_reported(status_r), None
        if not ran and hit is None and not oom and not stopping():
            notes.append(Note.SANDBOX_FAILED)  # bubblewrap never saw the program run: its set-up or exec failed
        fin = Finish(
            status,
            rusage,
            time.perf_counter() - t0,
            timed_out=hit == "timeout",
            mem_hit=hit == "memory",
            out_hit=hit == "output",
            oom=oom,
            pids_hit=pids_hit,
            rss_sampled_mb=watch.rss_peak_mb,
            bwrap_status=sandboxed,
            notes=tuple(notes),
        )
        res = result(
            argv, limits, fin, stdout_tail=read_tail(out_path), stderr_tail=read_tail(err_path), measure_dirs=measure
        )
        if keep_io is not None:
            for src in (out_path, err_path):
                keep_file(src, Path(keep_io) / f"{src.name}.txt")
        return res
    finally:
        if status_r is not None:
            os.close(status_r)
        shutil.rmtree(io_dir, ignore_errors=True)


def keep_file(src: Path, dst: Path) -> None:
    """Copy the harness's file ``src`` to ``dst`` in a folder a decoder wrote: whatever the
    decoder left at that name (a link, a FIFO, a folder) is replaced, never followed."""
    try:
        if dst.is_dir() and not dst.is_symlink():
            shutil.rmtree(dst, ignore_errors=True)
        elif os.path.lexists(dst):
            dst.unlink()
        fd = os.open(dst, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
    except OSError:
        return
    try:
        with open(src, "rb") as f, os.fdopen(fd, "wb") as out:
            fd = -1
            shutil.copyfileobj(f, out)
    except OSError:
        pass
    finally:
        if fd >= 0:
            os.close(fd)


def _wait(
    proc: subprocess.Popen[bytes], t0: float, limits: Limits, watch: Watch
) -> tuple[int, resource.struct_rusage | None, str | None]:
    """Wait for the decoder to end, its deadline, a limit the :class:`~.watch.Watch` sees passed
    (output, sampled resident memory) or a stop: blocked on a pidfd where the kernel has them
    (no polling delay added to a fast decoder's run), else polled with a backoff up to 10 ms.
    Returns (wait status, rusage, "timeout" | "memory" | "output" | None)."""
    deadline = t0 + limits.timeout_s
    delay = 0.0005
    fd = pidfd(proc.pid)
    try:
        while True:
            pid, st, ru = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                return st, ru, None
            now = time.perf_counter()
            hit = "timeout" if now >= deadline else watch.check(now)
            if hit or _STOP.is_set():
                kill_group(proc.pid)
                _pid, status, rusage = os.wait4(proc.pid, 0)
                return status, rusage, hit
            left = max(0.0, min(deadline - now, watch.next_in(time.perf_counter()), 0.1))
            if fd is not None:
                select.select([fd], [], [], left)  # stop_all() kills the group, which wakes this
            else:
                time.sleep(min(left, delay))
                delay = min(delay * 2, 0.01)
    finally:
        if fd is not None:
            os.close(fd)
