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
"""
from __future__ import annotations

import collections
import os
import select
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

from . import forkserver_build, sandbox
from .sandbox import Limits, ProcResult, View

SERVER_SCRIPT = Path(__file__).with_name("forkserver.py")
GRACE_S = 5.0  # how long past the decoder's timeout the server may take to answer


class ForkServerError(RuntimeError):
    """The fork server cannot be started (a harness problem, not the decoder's)."""


class ForkServer:
    """A long-lived fork server for one worker folder; :meth:`run` has the signature and the
    result of :func:`fbaconf.isolation.sandbox.run` for decoders run in that folder."""

    def __init__(self, root: Path, view: View, limits: Limits, env: dict[str, str] | None = None,
                 sum_outputs_every: int = 1, slots: int = 1) -> None:
        self.root = Path(root).resolve()
        self.view = view
        self.limits = limits
        self.env = env
        self.proc: subprocess.Popen | None = None
        self.cg = None
        self.starts = 0
        self._reqs: dict[tuple, tuple[bytes, Path]] = {}  # request bytes and workdir by request
        self._events: list[tuple[str, int]] | None = None
        self._answers = 0
        self._rbuf = b""
        self._last_done = 0.0
        self.sum_outputs_every = sum_outputs_every
        self.slots = slots  # stdout/stderr file pairs: an input's are read while the next one runs
        self._files: list[tuple] = []
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
        self._files = [(open(self.io / f"stdout{i}", "wb+"), open(self.io / f"stderr{i}", "wb+"))
                       for i in range(self.slots)]
        fds = [os.dup(f.fileno()) for pair in self._files for f in pair]
        inner = [*head, "--fds", *map(str, fds)]
        if sandbox.isolation() == "bwrap":
            v = View(read_only=[*self.view.read_only, self.srv, *runtime],
                     writable=list(self.view.writable), hidden=list(self.view.hidden),
                     read_only_inside=list(self.view.read_only_inside))
            inner = sandbox._bwrap_argv(v, self.root) + inner + ["--reap-namespace"]
        try:  # the server gets the decoder's output files as descriptors (--fds)
            self.proc, self.cg = sandbox.launch_server(
                inner, self.limits, cwd=self.root, pass_fds=tuple(fds),
                env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LC_ALL": "C.UTF-8"})
        except OSError as e:
            raise ForkServerError(f"cannot start the fork server: {e}") from e
        finally:
            for fd in fds:
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

    def __enter__(self) -> "ForkServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- one input
    def run(self, argv: list[str], workdir: Path, limits: Limits | None = None, *,
            env: dict[str, str] | None = None, measure_dirs: list[Path] | None = None) -> ProcResult:
        """Run ``argv`` in ``workdir`` (inside this server's root) and return how it ended."""
        return self.start(argv, workdir, limits, env=env, measure_dirs=measure_dirs).result()

    def start(self, argv: list[str], workdir: Path, limits: Limits | None = None, *,
              env: dict[str, str] | None = None, measure_dirs: list[Path] | None = None,
              slot: int = 0) -> "Pending":
        """Send one input to the server; the :class:`Pending` waits for it (``wait``: the
        decoder has ended) and judges it (``result``: reads its stdout/stderr, which stay until
        the next input in the same ``slot``). An input sent while another runs waits in the
        server's pipe and starts the moment the other ends — one decoder at a time, no gap;
        inputs are waited for in the order they were sent."""
        if not argv or not all(isinstance(a, str) and "\0" not in a for a in argv):
            raise ValueError("argv must be a non-empty list of strings without NUL")
        limits = limits or self.limits
        key = (tuple(argv), os.fspath(workdir), tuple(sorted(env.items())) if env else (), limits, slot)
        cached = self._reqs.get(key)  # a fuzzing worker sends the same requests every time
        if cached is None:
            wd = os.path.realpath(workdir)
            os.makedirs(os.path.join(wd, "tmp"), exist_ok=True)
            env_ = sandbox.decoder_env(Path(wd), {**(self.env or {}), **(env or {})})
            fields = [slot, limits.memory_mb * 2**20 if limits.memory_kind == "address-space" else 0,
                      limits.output_mb * 2**20, int(max(1, limits.timeout_s * 2 + 1)), repr(float(limits.timeout_s)),
                      repr(float(limits.memory_mb if limits.memory_kind == "rss" else 0)), wd, len(argv), *argv,
                      len(env_), *(f"{k}={v}" for k, v in env_.items())]
            if any("\0" in str(f) for f in fields):
                raise ValueError("a NUL in the decoder's environment or folder")
            data = b"".join(os.fsencode(str(f)) + b"\0" for f in fields)
            if len(self._reqs) > 64:
                self._reqs.clear()
            cached = self._reqs[key] = (struct.pack(">I", len(data)) + data, Path(wd))
        message, wd = cached
        try:
            os.mkdir(wd / "tmp")  # the decoder's TMPDIR, if a caller emptied the folder
        except FileExistsError:
            pass
        p = Pending(self, argv, wd, limits, measure_dirs, slot)
        if sandbox.stopping():
            p.res = ProcResult(argv, None, stderr_tail="harness stopping", notes=["harness-start-failed"])
            return p
        if self._queue and self._queue[-1].slot == slot:
            raise RuntimeError(f"slot {slot} is still in use by the previous input")
        if not self._queue and (self.proc is None or self.proc.poll() is not None):
            self.close()
            self._start()
        p.t0 = time.perf_counter()
        p.req = message
        p.sent = self.proc is not None and self._send(message)
        p.files = self._files[slot] if self._files else None
        self._queue.append(p)
        return p

    def _cgroup_events(self) -> tuple[bool, bool]:
        """(memory limit hit, process limit hit) in this server's cgroups since it started:
        the event counters, read through descriptors kept open (no open per input)."""
        if self._events is None:
            self._events = []
            for _kind, d in self.cg.dirs:
                for name in ("memory.events", "memory.oom_control", "memory.failcnt", "pids.events"):
                    try:
                        self._events.append((name, os.open(d / name, os.O_RDONLY)))
                    except OSError:
                        pass
        oom = pids = False
        for name, fd in self._events:
            try:
                text = os.pread(fd, 4096, 0).decode("ascii", "replace")
            except OSError:
                continue
            if name == "memory.failcnt":
                oom |= text.strip() not in ("", "0")
                continue
            for line in text.splitlines():
                k, _, v = line.partition(" ")
                if v.strip().isdigit() and int(v) > 0:
                    if name == "pids.events" and k == "max":
                        pids = True
                    elif (name, k) in (("memory.events", "oom_kill"), ("memory.events", "max"),
                                       ("memory.oom_control", "oom_kill")):
                        oom = True
        return oom, pids

    def _send(self, message: bytes) -> bool:
        try:
            self.proc.stdin.write(message)
            self.proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError):
            return False

    def _receive(self, deadline: float) -> dict | None:
        """The next reply (replies of queued inputs may arrive in one read: the rest is kept).
        The server's first message is its hello (``ready``): a server that dies before it
        never started; one that dies after it was ended by what it was running."""
        fd = self.proc.stdout.fileno()
        need = 4
        while True:
            while len(self._rbuf) < need:
                left = deadline - time.perf_counter()
                if left <= 0 or not select.select([fd], [], [], left)[0]:
                    return None
                chunk = os.read(fd, 65536)
                if not chunk:
                    return None
                self._rbuf += chunk
            if need == 4:
                need = 4 + struct.unpack(">I", self._rbuf[:4])[0]
                continue
            reply, self._rbuf = self._rbuf[4:need], self._rbuf[need:]
            if not self.ready:
                self.ready = reply == b"ready"
                need = 4
                continue
            status, utime, stime, maxrss, elapsed, timed_out, mem_hit = reply.split()
            return {"status": int(status), "utime": float(utime), "stime": float(stime), "maxrss_kb": int(maxrss),
                    "elapsed": float(elapsed), "timed_out": timed_out == b"1", "mem_hit": mem_hit == b"1"}

def _tail_fd(fd: int) -> str:
    """The last ``TAIL_BYTES`` the decoder wrote to one of its output files (kept open)."""
    size = os.fstat(fd).st_size
    data = os.pread(fd, sandbox.TAIL_BYTES, max(0, size - sandbox.TAIL_BYTES))
    return ("…" if size > sandbox.TAIL_BYTES else "") + data.decode("utf-8", "replace")


class Pending:
    """One input sent to a :class:`ForkServer`."""

    def __init__(self, server: ForkServer, argv, workdir: Path, limits: Limits, measure_dirs, slot: int) -> None:
        self.server, self.argv, self.workdir, self.limits = server, argv, workdir, limits
        self.measure_dirs, self.slot = measure_dirs, slot
        self.t0 = 0.0
        self.req = b""
        self.sent = False
        self.files = None
        self.reply: dict | None = None
        self.res: ProcResult | None = None
        self._waited = False

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
                p.sent = srv._send(p.req)
                p.files = srv._files[p.slot]
            if not self.sent:
                self.res = ProcResult(self.argv, None, stderr_tail="cannot start the fork server",
                                      notes=["harness-start-failed"])
                return
        begun = max(self.t0, srv._last_done)
        self.reply = srv._receive(begun + self.limits.timeout_s + GRACE_S)
        srv._last_done = time.perf_counter()
        self.elapsed = srv._last_done - begun
        if self.reply is None:  # the server died or hung: judge this input, restart next time
            err = _tail_fd(self.files[1].fileno()) if self.files else ""
            timed_out = self.elapsed >= self.limits.timeout_s
            oom, pids = srv._cgroup_events() if srv.cg is not None else (False, False)
            # a server that said hello and died under this input was ended by it (a decoder that
            # killed its parent, a tree memory or process limit): the input's ending, not set-up
            notes = ([] if timed_out else ["supervisor-lost"] if srv.ready else ["harness-start-failed"])
            notes += ["tree-memory-limit"] * oom + ["process-limit"] * pids
            self._close_server()
            self.res = ProcResult(self.argv, None, timed_out=timed_out, memory_limit_hit=oom,
                                  elapsed_s=self.elapsed, stderr_tail=err, notes=notes)
            return
        self.oom, self.pids_hit = srv._cgroup_events()
        if self.oom or self.pids_hit:  # the cgroup's counters are per server: start afresh after a hit
            self.out_tail, self.err_tail = (_tail_fd(f.fileno()) for f in self.files)
            self._close_server()

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
        if not hasattr(self, "err_tail"):
            self.out_tail, self.err_tail = (_tail_fd(f.fileno()) for f in self.files)
        srv._answers += 1
        # Each file is capped by RLIMIT_FSIZE; the folder's total is summed after a decode
        # (exit 0) and every n-th input otherwise — fuzzing inputs take ~1 ms each.
        dirs = self.measure_dirs or [self.workdir]
        if srv.sum_outputs_every > 1 and reply["status"] != 0 and srv._answers % srv.sum_outputs_every:
            dirs = []
        self.res = sandbox.result(self.argv, self.limits, reply["status"],
                                  (reply["utime"], reply["stime"], reply["maxrss_kb"]), reply["elapsed"],
                                  timed_out=reply["timed_out"], mem_hit=reply["mem_hit"], oom=self.oom,
                                  pids_hit=self.pids_hit, bwrap_status=False, stdout_tail=self.out_tail,
                                  stderr_tail=self.err_tail, measure_dirs=dirs)
        return self.res
