"""Spawn decoders fast: one sandbox per worker, one fork + exec per input.

:func:`fbaconf.isolation.sandbox.run` builds a fresh sandbox for every invocation (a Python
launcher, cgroups, bubblewrap's namespaces): right for a conformance case, about 6 ms of
overhead per input for a fuzzer whose decoder runs in 1 ms. :class:`ForkServer` pays that once:
it starts :mod:`.forkserver` inside one sandbox whose view is fixed (the decoder's folders
read-only, the worker's folder writable with its ``in/`` read-only, the goldens, suites and
run folder hidden), in one cgroup (process and memory limits over the tree), and asks it to
run each input. The per-process limits (address space, file size, CPU, time, sampled RSS)
are set in each child as the one-shot launcher sets them; the results are the same
:class:`~fbaconf.isolation.sandbox.ProcResult`, judged by the same :mod:`.endings`.

What differs from a one-shot case: the sandbox (its ``/tmp``, its PID namespace) lives for the
worker, not for one input; after each input the server kills every process the decoder left
in the namespace (without bubblewrap: the decoder's session; the cgroup's processes die when
the server stops), and the harness empties the worker's folder. A server that dies or stops
answering is restarted; the input it was running is reported as the decoder's ending.

The reply channel is the server's, not the decoder's: no decoder inherits it, the server is
non-dumpable (no ``/proc/<ppid>/fd`` way in), every request carries a fresh random nonce the
reply must echo, and a reply is at most :data:`MAX_REPLY` bytes of nine fields. Anything else
read from the channel — garbled bytes, a reply with another nonce (a forged "exit 0"), a
length past the bound — is a ``protocol-error`` of the input then running (the decoder wrote
into its parent's descriptors), the server is restarted, and no reply is ever taken for a
later input's. While an input runs its folder's size is watched (:mod:`.watch`): past
``output_mb`` the server is stopped and the input's ending is the output limit.
"""

from __future__ import annotations

import collections
import os
import secrets
import select
import shutil
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO

from . import forkserver_build, sandbox
from .cgroups import OOM_FILES, Cgroups, oom_events
from .process import Finish, Note, ProcResult, result
from .sandbox import Limits, View
from .watch import Watch

SERVER_SCRIPT = Path(__file__).with_name("forkserver.py")
GRACE_S = 5.0  # how long past the decoder's timeout the server may take to answer
MAX_REPLY = 512  # bytes of one reply
FORGED = (
    "protocol-error: the fork server's reply channel held {what} — the decoder (or a process it started) "
    "wrote into its parent's descriptors; a decoder must not touch processes it did not start"
)


class ForkServerError(RuntimeError):
    """The fork server cannot be started (a harness problem, not the decoder's)."""


class ForkServer:
    """A long-lived fork server for one worker folder; :meth:`run` has the signature and the
    result of :func:`fbaconf.isolation.sandbox.run` for decoders run in that folder."""

    def __init__(
        self,
        root: Path,
        view: View,
        limits: Limits,
        env: dict[str, str] | None = None,
        sum_outputs_every: int = 1,
        slots: int = 1,
    ) -> None:
        self.root = Path(root).resolve()
        self.view = view
        self.limits = limits
        self.env = env
        self.proc: subprocess.Popen[bytes] | None = None
        self.cg: Cgroups | None = None
        self.ready = False
        self.starts = 0
        self._reqs: dict[tuple[object, ...], tuple[bytes, Path]] = {}  # request bytes and workdir by request
        self._events: list[tuple[str, int]] | None = None
        self._answers = 0
        self._rbuf = b""
        self._last_done = 0.0
        self.sum_outputs_every = sum_outputs_every
        self.slots = slots  # stdout/stderr file pairs: an input's are read while the next one runs
        self._files: list[tuple[IO[bytes], IO[bytes]]] = []
        self._queue: collections.deque[Pending] = collections.deque()
        # The server in C when it can be built (isolation/forkserver_build.py), else the Python one.
        self.native = forkserver_build.forkserver_binary()
        self.io = self.root / ".io"  # the decoder's stdout/stderr files: outside its view
        self.srv = self.root / ".srv"  # the server script, read-only in the sandbox

    # ---------------------------------------------------------------- lifecycle
    def _start(self) -> None:
        for d in (self.io, self.srv):
            d.mkdir(parents=True, exist_ok=True)
        py = os.path.realpath(sys.executable)
        if self.native is not None:
            script = self.srv / self.native.name
            if not script.exists():
                shutil.copy2(self.native, script)
            if not os.access(script, os.X_OK):  # the worker's folder is on a noexec mount
                self.native = None
        if self.native is not None:
            head, runtime = [str(script)], []
        else:
            script = self.srv / SERVER_SCRIPT.name
            if not script.exists():
                shutil.copyfile(SERVER_SCRIPT, script)
            head, runtime = [py, "-I", "-S", str(script)], [Path(sys.base_prefix).resolve(), Path(py).parent]
        self._files = [
            (open(self.io / f"stdout{i}", "wb+"), open(self.io / f"stderr{i}", "wb+")) for i in range(self.slots)
        ]
        fds = [os.dup(f.fileno()) for pair in self._files for f in pair]
        inner = [*head, "--fds", *map(str, fds)]
        sandbox_fds: list[int] = []
        if sandbox.isolation() == "bwrap":
            v = View(
                read_only=[*self.view.read_only, self.srv, *runtime],
                writable=list(self.view.writable),
                hidden=list(self.view.hidden),
                read_only_inside=list(self.view.read_only_inside),
            )
            head, _status = sandbox.sandbox_argv(v, self.root, sandbox_fds, status=False)
            inner = head + inner + ["--reap-namespace"]
        try:  # the server gets the decoder's output files as descriptors (--fds)
            self.proc, self.cg = sandbox.launch_server(
                inner,
                self.limits,
                cwd=self.root,
                pass_fds=tuple(fds + sandbox_fds),
                env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LC_ALL": "C.UTF-8"},
            )
        except OSError as e:
            raise ForkServerError(f"cannot start the fork server: {e}") from e
        finally:
            for fd in fds + sandbox_fds:
                os.close(fd)
        self._rbuf = b""
        self.ready = False  # the server's hello has been read: it started inside its sandbox
        self.starts += 1

    def close(self) -> None:
        p, self.proc = self.proc, None
        for _name, fd in self._events or ():
            os.close(fd)
        self._events = None
        sandbox.stop_server(p, self.cg)
        self.cg = None
        for pair in self._files:
            for f in pair:
                f.close()
        self._files = []

    def __enter__(self) -> ForkServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- one input
    def run(
        self,
        argv: list[str],
        workdir: Path,
        limits: Limits | None = None,
        *,
        env: dict[str, str] | None = None,
        measure_dirs: list[Path] | None = None,
    ) -> ProcResult:
        """Run ``argv`` in ``workdir`` (inside this server's root) and return how it ended."""
        return self.start(argv, workdir, limits, env=env, measure_dirs=measure_dirs).result()

    def start(
        self,
        argv: list[str],
        workdir: Path,
        limits: Limits | None = None,
        *,
        env: dict[str, str] | None = None,
        measure_dirs: list[Path] | None = None,
        slot: int = 0,
    ) -> Pending:
        """Send one input to the server; the :class:`Pending` waits for it (``wait``: the
        decoder has ended) and judges it (``result``: reads its stdout/stderr, which stay until
        the next input in the same ``slot``). An input sent while another runs waits in the
        server's pipe and starts the moment the other ends — one decoder at a time, no gap;
        inputs are waited for in the order they were sent."""
        if not argv or not all(isinstance(a, str) and "\0" not in a for a in argv):
            raise ValueError("argv must be a non-empty list of strings without NUL")
        limits = limits or self.limits
        if sandbox.stopping():
            p = Pending(self, argv, Path(workdir), limits, measure_dirs, slot)
            p.res = ProcResult(argv, None, stderr_tail="harness stopping", notes=[Note.HARNESS_START_FAILED])
            return p
        if self._queue and self._queue[-1].slot == slot:
            raise RuntimeError(f"slot {slot} is still in use by the previous input")
        if not self._queue and (self.proc is None or self.proc.poll() is not None):
            self.close()
            self._start()
        as_bytes = sandbox.as_bytes_for(limits, self.cg)
        key = (tuple(argv), os.fspath(workdir), tuple(sorted(env.items())) if env else (), limits, slot, as_bytes)
        cached = self._reqs.get(key)  # a fuzzing worker sends the same requests every time
        if cached is None:
            real = os.path.realpath(workdir)
            os.makedirs(os.path.join(real, "tmp"), exist_ok=True)
            env_ = sandbox.decoder_env(Path(real), {**(self.env or {}), **(env or {})})
            fields = [
                slot,
                as_bytes,
                limits.output_mb * 2**20,
                int(max(1, limits.timeout_s * 2 + 1)),
                repr(float(limits.timeout_s)),
                repr(float(limits.memory_mb if limits.memory_kind == "rss" else 0)),
                real,
                len(argv),
                *argv,
                len(env_),
                *(f"{k}={v}" for k, v in env_.items()),
            ]
            if any("\0" in str(f) for f in fields):
                raise ValueError("a NUL in the decoder's environment or folder")
            data = b"".join(os.fsencode(str(f)) + b"\0" for f in fields)
            if len(self._reqs) > 64:
                self._reqs.clear()
            cached = self._reqs[key] = (data, Path(real))
        body, wd = cached
        try:
            os.mkdir(wd / "tmp")  # the decoder's TMPDIR, if a caller emptied the folder
        except FileExistsError:
            pass
        p = Pending(self, argv, wd, limits, measure_dirs, slot)
        p.as_limit = as_bytes > 0
        p.t0 = time.perf_counter()
        p.body = body
        p.sent = self.proc is not None and self._send(p)
        p.files = self._files[slot] if self._files else None
        self._queue.append(p)
        return p

    def _cgroup_events(self) -> tuple[bool, bool]:
        """(OOM events, process limit hit) in this server's cgroups since it started: the
        kernel's counters (:func:`~.cgroups.oom_events`), read through descriptors kept open."""
        if self._events is None:
            self._events = []
            for kind, d in self.cg.dirs if self.cg is not None else ():
                for name in (OOM_FILES.get(kind), "pids.events"):
                    if name is None:  # a controller with no OOM counter
                        continue
                    try:
                        self._events.append((kind if name != "pids.events" else "pids", os.open(d / name, os.O_RDONLY)))
                    except OSError:
                        pass
        oom = pids = False
        for kind, fd in self._events:
            if kind != "pids":
                oom |= oom_events(fd, kind)
                continue
            try:
                text = os.pread(fd, 4096, 0).decode("ascii", "replace")
            except OSError:
                continue
            pids |= any(ln.split()[:1] == ["max"] and ln.split()[1:2] != ["0"] for ln in text.splitlines())
        return oom, pids

    def _send(self, p: Pending) -> bool:
        p.nonce = secrets.token_hex(12)
        data = p.nonce.encode() + b"\0" + p.body
        stdin = self.proc.stdin if self.proc is not None else None
        if stdin is None:
            return False
        try:
            stdin.write(struct.pack(">I", len(data)) + data)
            stdin.flush()
            return True
        except (BrokenPipeError, OSError):
            return False

    def _receive(self, deadline: float, nonce: str, watch: Watch | None = None) -> Reply | str | None:
        """The reply to the request sent with ``nonce`` (the server answers in order; bytes past
        it stay for the next); None when the server died or hung; "output" when the watched
        folder passed the output limit; a sentence starting "protocol-error" when what the
        channel holds is not that reply. The server's first message is its hello (``ready``):
        a server that dies before it never started; one that dies after it was ended by what it
        was running."""
        stdout = self.proc.stdout if self.proc is not None else None
        if stdout is None:
            return None
        fd = stdout.fileno()
        need = 4
        while True:
            while len(self._rbuf) < need:
                now = time.perf_counter()
                left = deadline - now
                if left <= 0:
                    return None
                wait = min(left, watch.next_in(now)) if watch is not None else left
                if not select.select([fd], [], [], wait)[0]:
                    if watch is not None and watch.check(time.perf_counter()) == "output":
                        return "output"
                    continue
                chunk = os.read(fd, 65536)
                if not chunk:
                    return None
                self._rbuf += chunk
            if need == 4:
                size = struct.unpack(">I", self._rbuf[:4])[0]
                if not 0 < size <= MAX_REPLY:
                    return FORGED.format(what=f"a reply of {size} bytes (at most {MAX_REPLY})")
                need = 4 + size
                continue
            reply, self._rbuf = self._rbuf[4:need], self._rbuf[need:]
            if not self.ready:
                self.ready = reply == b"ready"
                if not self.ready:
                    return FORGED.format(what=f"{reply[:40]!r} where the server's hello belongs")
                need = 4
                continue
            return _parse_reply(reply, nonce)


@dataclass(frozen=True)
class Reply:
    """The server's report of one decoder process: its wait status, CPU times, peak memory,
    time, whether the server's timeout or sampled memory limit ended it, and exec's errno."""

    status: int
    utime: float
    stime: float
    maxrss_kb: int
    elapsed: float
    timed_out: bool
    mem_hit: bool
    exec_errno: int


def _parse_reply(reply: bytes, nonce: str) -> Reply | str:
    """A reply's fields, or the sentence saying why it is not the reply to ``nonce``."""
    f = reply.split()
    if len(f) != 9 or f[0] != nonce.encode():
        what = "a reply for another request (a forged reply)" if len(f) == 9 else f"garbled bytes {reply[:40]!r}"
        return FORGED.format(what=what)
    try:
        return Reply(
            status=int(f[1]),
            utime=float(f[2]),
            stime=float(f[3]),
            maxrss_kb=int(f[4]),
            elapsed=float(f[5]),
            timed_out=f[6] == b"1",
            mem_hit=f[7] == b"1",
            exec_errno=int(f[8]),
        )
    except ValueError:
        return FORGED.format(what=f"garbled bytes {reply[:40]!r}")


def _tail_fd(fd: int) -> str:
    """The last ``TAIL_BYTES`` the decoder wrote to one of its output files (kept open)."""
    size = os.fstat(fd).st_size
    data = os.pread(fd, sandbox.TAIL_BYTES, max(0, size - sandbox.TAIL_BYTES))
    return ("…" if size > sandbox.TAIL_BYTES else "") + data.decode("utf-8", "replace")


class Pending:
    """One input sent to a :class:`ForkServer`."""

    def __init__(
        self,
        server: ForkServer,
        argv: list[str],
        workdir: Path,
        limits: Limits,
        measure_dirs: list[Path] | None,
        slot: int,
    ) -> None:
        self.server, self.argv, self.workdir, self.limits = server, argv, workdir, limits
        self.measure_dirs, self.slot = measure_dirs, slot
        self.t0 = 0.0
        self.body = b""
        self.nonce = ""
        self.as_limit = False
        self.sent = False
        self.files: tuple[IO[bytes], IO[bytes]] | None = None
        self.reply: Reply | str | None = None
        self.res: ProcResult | None = None
        self._waited = False
        self.elapsed = 0.0
        self.oom = self.pids_hit = False
        self.out_tail: str | None = None
        self.err_tail: str | None = None

    def wait(self) -> None:
        """Until the decoder has ended (its reply is in); the server is free after this."""
        if self._waited or self.res is not None:
            return
        srv = self.server
        while srv._queue and srv._queue[0] is not self:
            srv._queue[0].wait()  # the inputs sent before this one answer first
        if srv._queue and srv._queue[0] is self:
            srv._queue.popleft()
        self._waited = True
        if not self.sent or srv.proc is None or srv.proc.poll() is not None:
            # sent to a server that stopped under an earlier input: send it to a fresh one
            srv.close()
            srv._start()
            for p in (self, *srv._queue):
                p.t0 = time.perf_counter()
                p.sent = srv._send(p)
                p.files = srv._files[p.slot]
            if not self.sent:
                self.res = ProcResult(
                    self.argv, None, stderr_tail="cannot start the fork server", notes=[Note.HARNESS_START_FAILED]
                )
                return
        begun = max(self.t0, srv._last_done)
        watch = Watch(self.limits, self.measure_dirs or [self.workdir], t0=begun)
        self.reply = srv._receive(begun + self.limits.timeout_s + GRACE_S, self.nonce, watch)
        srv._last_done = time.perf_counter()
        self.elapsed = srv._last_done - begun
        if isinstance(self.reply, str):  # a forged or garbled reply, or the output limit passed: restart
            err = _tail_fd(self.files[1].fileno()) if self.files else ""
            out = self.reply == "output"
            self._close_server()
            self.res = ProcResult(
                self.argv,
                None,
                elapsed_s=self.elapsed,
                stderr_tail=err,
                output_limit_hit=out,
                output_bytes=watch.bytes,
                notes=[] if out else [Note.PROTOCOL_ERROR],
                detail="" if out else self.reply,
            )
            return
        if self.reply is None:  # the server died or hung: judge this input, restart next time
            err = _tail_fd(self.files[1].fileno()) if self.files else ""
            timed_out = self.elapsed >= self.limits.timeout_s
            oom, pids = srv._cgroup_events() if srv.cg is not None else (False, False)
            # a server that said hello and died under this input was ended by it (a decoder that
            # killed its parent, a tree memory or process limit): the input's ending, not set-up
            notes = [] if timed_out else [Note.SUPERVISOR_LOST] if srv.ready else [Note.HARNESS_START_FAILED]
            notes += [Note.TREE_MEMORY_LIMIT] * oom + [Note.PROCESS_LIMIT] * pids
            self._close_server()
            self.res = ProcResult(
                self.argv,
                None,
                timed_out=timed_out,
                memory_limit_hit=oom,
                elapsed_s=self.elapsed,
                stderr_tail=err,
                notes=notes,
            )
            return
        self.oom, self.pids_hit = srv._cgroup_events()
        if self.oom or self.pids_hit:  # the cgroup's counters are per server: start afresh after a hit
            self._read_tails()
            self._close_server()

    def _read_tails(self) -> None:
        if self.files is not None:
            self.out_tail, self.err_tail = (_tail_fd(f.fileno()) for f in self.files)

    def _close_server(self) -> None:
        """Stop the server; inputs queued behind this one are sent again to the next one."""
        srv = self.server
        for p in srv._queue:
            p.sent = False
        srv.close()

    def result(self) -> ProcResult:
        """How the input ended (reads its output files: before the slot's next input)."""
        self.wait()
        if self.res is not None:
            return self.res
        srv, reply = self.server, self.reply
        if not isinstance(reply, Reply):  # wait() sets a result for every other reply
            raise RuntimeError("an input without its reply or result")
        if self.err_tail is None:
            self._read_tails()
        srv._answers += 1
        # Each file is capped by RLIMIT_FSIZE; the folder's total is summed after a decode
        # (exit 0) and every n-th input otherwise — fuzzing inputs take ~1 ms each.
        dirs = self.measure_dirs or [self.workdir]
        if srv.sum_outputs_every > 1 and reply.status != 0 and srv._answers % srv.sum_outputs_every:
            dirs = []
        notes = ([Note.EXEC_FAILED] if reply.exec_errno else []) + ([Note.AS_LIMIT] if self.as_limit else [])
        fin = Finish(
            reply.status,
            (reply.utime, reply.stime, reply.maxrss_kb),
            reply.elapsed,
            timed_out=reply.timed_out,
            mem_hit=reply.mem_hit,
            oom=self.oom,
            pids_hit=self.pids_hit,
            notes=tuple(notes),
        )
        self.res = result(
            self.argv,
            self.limits,
            fin,
            stdout_tail=self.out_tail or "",
            stderr_tail=self.err_tail or "",
            measure_dirs=dirs,
        )
        return self.res
