"""Spawn decoders fast: one sandbox per worker, one fork + exec per input.

:func:`fbaconf.harness.sandbox.run` builds a fresh sandbox for every invocation (a Python
launcher, cgroups, bubblewrap's namespaces): right for a conformance case, about 6 ms of
overhead per input for a fuzzer whose decoder runs in 1 ms. :class:`ForkServer` pays that once:
it starts :mod:`.forkserver` inside one sandbox whose view is fixed (the decoder's folders
read-only, the worker's folder writable with its ``in/`` read-only, the goldens, suites and
run folder hidden), in one cgroup (process and memory limits over the tree), and asks it to
run each input. The per-process limits (address space, file size, CPU, time, sampled RSS)
are set in each child as the one-shot launcher sets them; the results are the same
:class:`~fbaconf.harness.sandbox.ProcResult`, judged by the same :mod:`.exits`.

What differs from a one-shot case: the sandbox (its ``/tmp``, its PID namespace) lives for the
worker, not for one input; after each input the server kills every process the decoder left
in the namespace, and the harness empties the worker's folder. A server that dies or stops
answering is restarted; the input it was running is reported as the decoder's ending.
"""
from __future__ import annotations

import json
import os
import select
import shutil
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

from . import sandbox
from .sandbox import Limits, ProcResult, View

SERVER_SCRIPT = Path(__file__).with_name("forkserver.py")
GRACE_S = 5.0  # how long past the decoder's timeout the server may take to answer


class ForkServerError(RuntimeError):
    """The fork server cannot be started (a harness problem, not the decoder's)."""


class ForkServer:
    """A long-lived fork server for one worker folder; :meth:`run` has the signature and the
    result of :func:`fbaconf.harness.sandbox.run` for decoders run in that folder."""

    def __init__(self, root: Path, view: View, limits: Limits, env: dict[str, str] | None = None,
                 sum_outputs_every: int = 1) -> None:
        self.root = Path(root).resolve()
        self.view = view
        self.limits = limits
        self.env = env
        self.proc: subprocess.Popen | None = None
        self.cg = None
        self.starts = 0
        self._env_key = None
        self._events: list[tuple[str, int]] | None = None
        self._answers = 0
        self.sum_outputs_every = sum_outputs_every
        self._env: dict[str, str] = {}
        self._lock = threading.Lock()
        self.io = self.root / ".io"  # the decoder's stdout/stderr files: outside its view
        self.srv = self.root / ".srv"  # the server script, read-only in the sandbox

    # ---------------------------------------------------------------- lifecycle
    def _start(self) -> None:
        for d in (self.io, self.srv):
            d.mkdir(parents=True, exist_ok=True)
        script = self.srv / SERVER_SCRIPT.name
        if not script.exists():
            shutil.copyfile(SERVER_SCRIPT, script)
        py = os.path.realpath(sys.executable)
        r3, r4 = os.dup(self._out_file().fileno()), os.dup(self._err.fileno())
        inner = [py, "-I", "-S", str(script), "--fds", str(r3), str(r4)]
        if sandbox.isolation() == "bwrap":
            v = View(read_only=[*self.view.read_only, self.srv, Path(sys.base_prefix).resolve(), Path(py).parent],
                     writable=list(self.view.writable), hidden=list(self.view.hidden),
                     read_only_inside=list(self.view.read_only_inside))
            inner = sandbox._bwrap_argv(v, self.root) + inner + ["--reap-namespace"]
        self.cg = sandbox._Cgroups(self.limits)
        full = [py, "-I", "-S", str(sandbox.LIMIT_LAUNCHER), "0", "0", "0", *self.cg.launcher_args(), "--", *inner]
        try:
            # the decoder's output files become the server's descriptors 3 and 4
            self.proc = subprocess.Popen(full, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=None,
                                         cwd=self.root, start_new_session=True, close_fds=True,
                                         pass_fds=(r3, r4),
                                         env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LC_ALL": "C.UTF-8"})
        except OSError as e:
            raise ForkServerError(f"cannot start the fork server: {e}") from e
        finally:
            os.close(r3)
            os.close(r4)
        self.starts += 1
        sandbox._RUNNING.add(self.proc.pid)

    def _out_file(self):
        """Open the decoder's stdout/stderr files (the server hands them to each child)."""
        self._out = open(self.io / "stdout", "wb+")
        self._err = open(self.io / "stderr", "wb+")
        return self._out

    def close(self) -> None:
        p, self.proc = self.proc, None
        if p is not None:
            sandbox._RUNNING.discard(p.pid)
            sandbox._kill_group(p.pid)
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass
            for f in (p.stdin, p.stdout):
                try:
                    f.close()
                except OSError:
                    pass
        for _name, fd in self._events or ():
            os.close(fd)
        self._events = None
        if self.cg is not None:
            self.cg.close()
            self.cg = None
        for name in ("_out", "_err"):
            f = getattr(self, name, None)
            if f is not None:
                f.close()
                setattr(self, name, None)

    def __enter__(self) -> "ForkServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- one input
    def run(self, argv: list[str], workdir: Path, limits: Limits | None = None, *,
            env: dict[str, str] | None = None, measure_dirs: list[Path] | None = None) -> ProcResult:
        """Run ``argv`` in ``workdir`` (inside this server's root) and return how it ended."""
        return self.start(argv, workdir, limits, env=env, measure_dirs=measure_dirs)()

    def start(self, argv: list[str], workdir: Path, limits: Limits | None = None, *,
              env: dict[str, str] | None = None, measure_dirs: list[Path] | None = None):
        """Send one input to the server and return a function that waits for its ending
        (the caller may work meanwhile: the fuzzer makes its next input). One input at a
        time per server: call the returned function before the next :meth:`start`."""
        if not argv or not all(isinstance(a, str) for a in argv):
            raise ValueError("argv must be a non-empty list of strings")
        limits = limits or self.limits
        workdir = os.path.realpath(workdir)
        os.makedirs(os.path.join(workdir, "tmp"), exist_ok=True)
        key = (workdir, tuple(sorted((env or {}).items())))
        if self._env_key != key:
            self._env_key = key
            self._env = sandbox.decoder_env(Path(workdir), {**(self.env or {}), **(env or {})})
        req = {"argv": argv, "cwd": workdir, "env": self._env,
               "as": limits.memory_mb * 2**20 if limits.memory_kind == "address-space" else 0,
               "fsize": limits.output_mb * 2**20, "cpu": int(max(1, limits.timeout_s * 2 + 1)),
               "timeout": limits.timeout_s, "rss_mb": limits.memory_mb if limits.memory_kind == "rss" else 0}
        self._lock.acquire()
        try:
            if sandbox.stopping():
                self._lock.release()
                res = ProcResult(argv, None, stderr_tail="harness stopping", notes=["harness-start-failed"])
                return lambda: res
            if self.proc is None or self.proc.poll() is not None:
                self.close()
                self._start()
            t0 = time.perf_counter()
            sent = self._send(req)
        except BaseException:
            self._lock.release()
            raise

        def finish() -> ProcResult:
            try:
                reply = self._receive(t0 + limits.timeout_s + GRACE_S) if sent else None
                elapsed = time.perf_counter() - t0
                if reply is None:  # the server died or hung: restart it next time, judge this input
                    self.close()
                    return ProcResult(argv, None, timed_out=elapsed >= limits.timeout_s, elapsed_s=elapsed,
                                      stderr_tail=sandbox._tail(self.io / "stderr"),
                                      notes=[] if elapsed >= limits.timeout_s else ["harness-start-failed"])
                oom, pids_hit = self._cgroup_events()
                out_tail, err_tail = _tail_fd(self._out.fileno()), _tail_fd(self._err.fileno())
                if oom or pids_hit:  # the cgroup's counters are per server: start afresh after a hit
                    self.close()
            finally:
                self._lock.release()
            self._answers += 1
            # Each file is capped by RLIMIT_FSIZE; the folder's total is summed after a decode
            # (exit 0) and every 16th input otherwise — the fuzzer's inputs are ~1 ms each.
            dirs = measure_dirs or [Path(workdir)]
            if self.sum_outputs_every > 1 and reply["status"] != 0 and self._answers % self.sum_outputs_every:
                dirs = []
            return sandbox.result(argv, limits, reply["status"],
                                  (reply["utime"], reply["stime"], reply["maxrss_kb"]), reply["elapsed"],
                                  timed_out=reply["timed_out"], mem_hit=reply["mem_hit"], oom=oom,
                                  pids_hit=pids_hit, bwrap_status=False, stdout_tail=out_tail,
                                  stderr_tail=err_tail, measure_dirs=dirs)
        return finish

    def _cgroup_events(self) -> tuple[bool, bool]:
        """(memory limit hit, process limit hit) in this server's cgroups since it started:
        the event counters, read through descriptors kept open (no open per input)."""
        if self._events is None:
            self._events = []
            for kind, d in self.cg.dirs:
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

    def _send(self, req: dict) -> bool:
        data = json.dumps(req).encode()
        try:
            self.proc.stdin.write(struct.pack(">I", len(data)) + data)
            self.proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError):
            return False

    def _receive(self, deadline: float) -> dict | None:
        fd = self.proc.stdout.fileno()
        buf, need = b"", 4
        while True:
            while len(buf) < need:
                left = deadline - time.perf_counter()
                if left <= 0 or not select.select([fd], [], [], left)[0]:
                    return None
                chunk = os.read(fd, 65536)
                if not chunk:
                    return None
                buf += chunk
            if need == 4:
                need = 4 + struct.unpack(">I", buf[:4])[0]
                continue
            return json.loads(buf[4:need])

def _tail_fd(fd: int) -> str:
    """The last ``TAIL_BYTES`` the decoder wrote to one of its output files (kept open)."""
    size = os.fstat(fd).st_size
    data = os.pread(fd, sandbox.TAIL_BYTES, max(0, size - sandbox.TAIL_BYTES))
    return ("…" if size > sandbox.TAIL_BYTES else "") + data.decode("utf-8", "replace")
