"""Fork server: one long-lived process per fuzzing worker, started once inside the worker's
sandbox, that starts the decoder for each input (fork, limits, exec) and reports how it ended.

Starting bubblewrap, joining cgroups and starting a Python launcher cost about 6 ms per
input, several times the decoder's own run; AFL's fork server showed the way: pay the
sandbox once per worker, keep only fork + exec per input. The client is
:class:`fbaconf.isolation.forkclient.ForkServer`.

Run as ``python -I -S forkserver.py --fds OUT ERR [OUT ERR ...] [--reap-namespace]`` with
the decoder's stdout and stderr files open as descriptor pairs, one pair per slot (opened by
the harness outside the sandbox: the decoder can write them, never find them by path; with
several slots the harness reads one input's while the next ones run). Kept to the standard
library's ``os``, ``resource``, ``select``, ``signal``, ``struct``, ``sys`` and ``time``, so it
starts in milliseconds.

Protocol on stdin/stdout (the same for ``forkserver.c``, the server in C the harness uses when
it can compile it): each message is a 4-byte big-endian length and that many bytes. A request
is NUL-terminated fields: ``nonce`` (the client's, echoed in the reply), ``slot`` (which
descriptor pair), ``as`` (address-space bytes, 0 = none), ``fsize`` (bytes), ``cpu``
(seconds), ``timeout`` (seconds), ``rss_mb`` (0 = not sampled), ``cwd``, ``argc``, the
arguments, ``envc``, the ``NAME=value`` entries. A reply is ASCII ``nonce status utime stime
maxrss_kb elapsed timed_out mem_hit exec_errno`` (``status`` the raw wait status,
``exec_errno`` non-zero when the program could not be executed: the server's own knowledge;
``fbaconf-limit: cannot execute …`` is then on its stderr). The server's first message is
``ready``, once it runs inside its sandbox.

The channel: no decoder inherits the server's stdin or stdout, and the server makes itself
non-dumpable (``prctl(PR_SET_DUMPABLE, 0)``), so a decoder without ``CAP_SYS_PTRACE`` (the
sandbox drops every capability) cannot open them through ``/proc/<ppid>/fd``; a reply that
is garbled or does not echo its request's nonce is the running decoder's finding
(:mod:`.forkclient`).

``--reap-namespace`` (only inside the sandbox's own PID namespace, where ``/proc`` lists the
sandbox's processes alone): after each input every process but the sandbox's init and the
server itself is killed — a decoder that forked away or left its session dies with its input.
"""

from __future__ import annotations

import ctypes
import os
import resource
import select
import signal
import struct
import sys
import time

SLOTS = [(3, 4)]  # (stdout, stderr) descriptor pairs, from --fds OUT ERR [OUT ERR ...]
NOFILE = 1024  # descriptors per decoder process (isolation/seccomp.py)


def _read_exact(n: int) -> bytes | None:
    buf = b""
    while len(buf) < n:
        chunk = os.read(0, n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return buf


def _send(nonce: str, reply: Reply) -> None:
    data = (
        f"{nonce} {reply['status']:d} {reply['utime']:.6f} {reply['stime']:.6f} {reply['maxrss_kb']:d} "
        f"{reply['elapsed']:.6f} {reply['timed_out']:d} {reply['mem_hit']:d} "
        f"{reply.get('exec_errno', 0):d}"
    ).encode()
    data = struct.pack(">I", len(data)) + data
    while data:
        data = data[os.write(1, data) :]


def _set(which: int, value: int) -> None:
    if value > 0:
        _soft, hard = resource.getrlimit(which)
        if hard != resource.RLIM_INFINITY:
            value = min(value, hard)
        resource.setrlimit(which, (value, value if hard == resource.RLIM_INFINITY else hard))


def _find(prog: str, env: dict[str, str]) -> str:
    if "/" in prog:
        return prog
    for d in env.get("PATH", "/usr/bin:/bin").split(":"):
        p = os.path.join(d or ".", prog)
        if os.access(p, os.X_OK) and not os.path.isdir(p):
            return p
    return prog


def _child(req: Request, out_fd: int, err_fd: int, status_fd: int) -> None:
    """In the forked child: own session, limits, descriptors, folder; then exec (its error, if
    any, on ``status_fd``, which closes at the exec)."""
    argv = req.argv
    try:
        os.setsid()
        null = os.open("/dev/null", os.O_RDONLY)
        os.dup2(null, 0)
        os.dup2(out_fd, 1)
        os.dup2(err_fd, 2)
        os.dup2(status_fd, 3)
        os.set_inheritable(3, False)
        os.closerange(4, 1 << 16)
        for s in (signal.SIGPIPE, signal.SIGINT, signal.SIGTERM):
            signal.signal(s, signal.SIG_DFL)
        _set(resource.RLIMIT_AS, req.as_bytes)
        _set(resource.RLIMIT_FSIZE, req.fsize)
        _set(resource.RLIMIT_CPU, req.cpu)
        _set(resource.RLIMIT_NOFILE, NOFILE)
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
        os.chdir(req.cwd)
        os.execve(_find(argv[0], req.env), argv, req.env)
    except OSError as e:
        os.write(3, str(e.errno or 8).encode())
        os.write(2, f"fbaconf-limit: cannot execute {argv[0]!r}: {e.strerror}\n".encode())
    except BaseException:  # noqa: BLE001 - never return into the server's loop
        os.write(3, b"8")
        os.write(2, f"fbaconf-limit: cannot execute {argv[0]!r}\n".encode())
    finally:
        os._exit(127)


def _rss_one(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/statm", "rb") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _rss_mb(pid: int, reap: bool) -> float:
    """The decoder's resident memory: its whole tree inside the sandbox's PID namespace (every
    process but its init and this server), else its own."""
    if not reap:
        return _rss_one(pid)
    me = os.getpid()
    return sum(_rss_one(int(n)) for n in os.listdir("/proc") if n.isdigit() and int(n) not in (1, me))


def _reap_namespace() -> None:
    keep = {1, os.getpid(), os.getppid()}
    for _ in range(50):
        others = [int(n) for n in os.listdir("/proc") if n.isdigit() and int(n) not in keep]
        if not others:
            return
        for pid in others:
            try:
                os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        time.sleep(0.001)


SPAWN_MIN_AS = 256 << 20  # below this address-space limit the server forks (it cannot lower its own)
_LIMITS = (resource.RLIMIT_AS, resource.RLIMIT_FSIZE, resource.RLIMIT_CPU, resource.RLIMIT_NOFILE)


# what the server last set for itself before a posix_spawn: the children's rlimits, its folder
_applied: dict[str, object] = {"limits": None, "cwd": None}


def _spawn(req: Request, out_fd: int, err_fd: int) -> int:
    """posix_spawn (vfork + exec: ~0.1 ms, against ~0.5 ms for forking this process) with the
    child's limits as the server's own soft limits (set once per set of limits: the server
    itself stays far below them, ignores SIGXCPU and writes no file) and the child's signal
    dispositions reset. Returns the pid, or the exec error (an errno, negated) after writing it."""
    argv, env = req.argv, req.env
    limits = (req.as_bytes, req.fsize, req.cpu, NOFILE)
    if _applied["limits"] != limits:
        for which, value in zip(_LIMITS, limits):
            _set_soft(which, value)
        _applied["limits"] = limits
    if _applied["cwd"] != req.cwd:
        os.chdir(req.cwd)
        _applied["cwd"] = req.cwd
    try:
        return os.posix_spawn(
            _find(argv[0], env),
            argv,
            env,
            setsid=True,
            setsigdef=(signal.SIGPIPE, signal.SIGXCPU, signal.SIGXFSZ, signal.SIGINT, signal.SIGTERM),
            file_actions=[
                (os.POSIX_SPAWN_OPEN, 0, "/dev/null", os.O_RDONLY, 0),
                (os.POSIX_SPAWN_DUP2, out_fd, 1),
                (os.POSIX_SPAWN_DUP2, err_fd, 2),
            ],
        )
    except OSError as e:
        os.write(err_fd, f"fbaconf-limit: cannot execute {argv[0]!r}: {e.strerror}\n".encode())
        return -(e.errno or 8)


def _set_soft(which: int, value: int) -> None:
    """The soft limit only (the hard one stays, so a later request can raise it again);
    0 = no limit."""
    _soft, hard = resource.getrlimit(which)
    if value <= 0:
        value = hard
    elif hard != resource.RLIM_INFINITY:
        value = min(value, hard)
    resource.setrlimit(which, (value, hard))


class Request:
    """One request's fields (see the protocol above)."""

    def __init__(  # noqa: PLR0913 - the protocol's fields
        self,
        slot: int,
        as_bytes: int,
        fsize: int,
        cpu: int,
        timeout: float,
        rss_mb: float,
        cwd: str,
        argv: list[str],
        env: dict[str, str],
    ) -> None:
        self.slot, self.as_bytes, self.fsize, self.cpu = slot, as_bytes, fsize, cpu
        self.timeout, self.rss_mb, self.cwd, self.argv, self.env = timeout, rss_mb, cwd, argv, env


# the reply's fields (see the protocol above): numbers, the flags as 0 or 1
Reply = dict[str, float]


def _request(body: bytes) -> Request:
    """The request's fields (see the protocol above)."""
    f = body.split(b"\0")[1:-1]  # (the nonce is the first field)
    argc = int(f[7])
    envc = int(f[8 + argc])
    env = dict(e.decode("utf-8", "surrogateescape").partition("=")[::2] for e in f[9 + argc : 9 + argc + envc])
    return Request(
        slot=int(f[0]),
        as_bytes=int(f[1]),
        fsize=int(f[2]),
        cpu=int(f[3]),
        timeout=float(f[4]),
        rss_mb=float(f[5]),
        cwd=f[6].decode("utf-8", "surrogateescape"),
        argv=[a.decode("utf-8", "surrogateescape") for a in f[8 : 8 + argc]],
        env=env,
    )


def _fork(req: Request, out_fd: int, err_fd: int) -> int:
    """Fork and exec in the child; the pid, or the exec error (an errno, negated)."""
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        _child(req, out_fd, err_fd, w)
    os.close(w)
    why = b""
    while True:  # the exec error, or nothing once the exec closed the child's end
        chunk = os.read(r, 16)
        if not chunk:
            break
        why += chunk
    os.close(r)
    if not why:
        return pid
    os.waitpid(pid, 0)
    return -int(why) if why.isdigit() else -8


def serve(req: Request, reap: bool) -> Reply:
    out_fd, err_fd = SLOTS[req.slot]
    for fd in (out_fd, err_fd):
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
    t0 = time.monotonic()
    if 0 < req.as_bytes < SPAWN_MIN_AS:
        pid = _fork(req, out_fd, err_fd)
    else:
        pid = _spawn(req, out_fd, err_fd)
    if pid < 0:
        return {
            "status": 127 << 8,
            "utime": 0.0,
            "stime": 0.0,
            "maxrss_kb": 0,
            "elapsed": time.monotonic() - t0,
            "timed_out": False,
            "mem_hit": False,
            "exec_errno": -pid,
        }
    try:
        pfd = os.pidfd_open(pid)
    except (AttributeError, OSError):
        pfd = None
    deadline = t0 + req.timeout
    rss_mb = req.rss_mb
    timed_out = mem_hit = False
    while True:
        wpid, status, ru = os.wait4(pid, os.WNOHANG)
        if wpid:
            break
        left = deadline - time.monotonic()
        if left <= 0:
            timed_out = True
        elif rss_mb and _rss_mb(pid, reap) > rss_mb:
            mem_hit = True
        if timed_out or mem_hit:
            try:
                os.killpg(pid, signal.SIGKILL)
            except OSError:
                os.kill(pid, signal.SIGKILL)
            _wpid, status, ru = os.wait4(pid, 0)
            break
        wait = min(left, 0.005) if rss_mb else left
        if pfd is not None:
            select.select([pfd], [], [], wait)
        else:
            time.sleep(min(wait, 0.0005))
    elapsed = time.monotonic() - t0
    if pfd is not None:
        os.close(pfd)
    try:
        os.killpg(pid, signal.SIGKILL)  # what the decoder left behind in its session
    except OSError:
        pass
    if reap:
        _reap_namespace()
    return {
        "status": status,
        "utime": ru.ru_utime,
        "stime": ru.ru_stime,
        "maxrss_kb": ru.ru_maxrss,
        "elapsed": elapsed,
        "timed_out": timed_out,
        "mem_hit": mem_hit,
    }


def main() -> None:
    args = sys.argv[1:]
    reap = "--reap-namespace" in args
    if "--fds" in args:
        nums = []
        for a in args[args.index("--fds") + 1 :]:
            if not a.isdigit():
                break
            nums.append(int(a))
        SLOTS[:] = list(zip(nums[0::2], nums[1::2]))
    for pair in SLOTS:
        for fd in pair:
            os.set_inheritable(fd, False)  # children get one pair as 1 and 2 only
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    try:  # its descriptors and memory closed to /proc (see the top)
        ctypes.CDLL(None, use_errno=True).prctl(4, 0, 0, 0, 0)  # PR_SET_DUMPABLE
    except (OSError, AttributeError):
        pass
    signal.signal(signal.SIGXCPU, signal.SIG_IGN)  # the server's own CPU time may pass a child's limit
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    os.write(1, struct.pack(">I", 5) + b"ready")  # the hello: started inside the sandbox
    while True:
        head = _read_exact(4)
        if head is None:
            return
        body = _read_exact(struct.unpack(">I", head)[0])
        if body is None:
            return
        _send(body.split(b"\0", 1)[0].decode("ascii", "replace"), serve(_request(body), reap))


if __name__ == "__main__":
    main()
