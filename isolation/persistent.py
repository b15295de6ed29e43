"""The persistent decoder protocol: ``[commands] serve`` keeps one decoder process alive for
many inputs (AFL++'s persistent mode, over a pipe).

The harness starts ``serve`` once per worker, sandboxed and limited like any decoder (its
folder, its view, address-space and file-size limits for the whole process — no CPU-time
limit, which would add up over inputs), with stdin and stdout as pipes. Per input::

    harness -> decoder:  "<size> <output path>\\n" then <size> bytes (the stream)
    decoder -> harness:  "<code>[ <message>]\\n"

``<code>`` means what the exit code of ``decode`` means (0 decoded, the output written to
the path; 69 not supported; a reject code from ``reject_exit_codes``; anything else is a
Fail). The output path's extension is the manifest's ``faps_format``. The process ends
when its stdin closes.

A crash (the process dies: a signal, a sanitizer abort, a panic), a hang (no answer within
``timeout_s``) or a memory or output blow-up is the ending of the input being decoded; the
harness kills the process and starts a new one for the next input (after a first crash, a
spare process is kept starting in the background, so the next input need not wait for it).
Whatever the decoder wrote on stderr while decoding an input is that input's stderr (crash
reports are read from it), so a report printed without dying is judged as a crash too. The result is a
:class:`~fbaconf.isolation.sandbox.ProcResult`, judged by :mod:`.endings` like a spawned
decoder's.
"""
from __future__ import annotations

import collections
import os
import select
import subprocess
import time
from pathlib import Path

from . import sandbox
from .forkclient import ForkServerError
from .sandbox import Limits, ProcResult, View


class PersistentDecoder:
    """One ``serve`` process for one worker folder; :meth:`run` sends one input."""

    def __init__(self, argv: list[str], root: Path, workdir: Path, view: View, limits: Limits,
                 env: dict[str, str] | None = None) -> None:
        self.argv = list(argv)
        self.root = Path(root).resolve()
        self.workdir = Path(workdir).resolve()
        self.view = view
        self.limits = limits
        self.env = env
        self.proc: subprocess.Popen | None = None
        self.cg = None
        self.starts = 0
        self.io = self.root / ".io"
        self._err = None
        self._buf = b""
        self._queue: collections.deque = collections.deque()
        self._answers = 0
        self._err_mark = 0
        self._last_done = 0.0
        self._launches = 0
        self._spare: tuple | None = None  # (process, cgroups, stderr) started ahead, after a first crash

    def _launch(self) -> tuple:
        """One sandboxed ``serve`` process, not yet given an input: (process, cgroups, stderr)."""
        self.io.mkdir(parents=True, exist_ok=True)
        (self.workdir / "tmp").mkdir(parents=True, exist_ok=True)
        inner = list(self.argv)
        if sandbox.isolation() == "bwrap":
            inner = sandbox._bwrap_argv(self.view, self.workdir) + inner
        lim = self.limits
        self._launches += 1
        err = open(self.io / f"stderr{self._launches % 2}", "wb+")  # the process in use and its spare
        try:
            proc, cg = sandbox.launch_server(
                inner, lim, cwd=self.workdir, env=sandbox.decoder_env(self.workdir, self.env), stderr=err,
                as_bytes=lim.memory_mb * 2**20 if lim.memory_kind == "address-space" else 0,
                fsize=lim.output_mb * 2**20)
        except OSError as e:
            err.close()
            raise ForkServerError(f"cannot start the persistent decoder: {e}") from e
        return proc, cg, err

    def _start(self) -> None:
        """The process for the next inputs: the spare if one is ready, else a new one. After a
        first restart a spare is kept starting in the background, so a decoder that crashes
        often does not wait for a sandbox to start before each next input."""
        spare, self._spare = self._spare, None
        if spare is not None and spare[0].poll() is not None:  # it died waiting
            _stop(spare)
            spare = None
        self.proc, self.cg, self._err = spare or self._launch()
        self._buf = b""
        self._err_mark = 0
        self.starts += 1
        if self.starts > 1:
            self._spare = self._launch()

    def _drop(self) -> None:
        """Stop the process in use (it ended or broke the protocol); the spare stays."""
        for a in self._queue:  # inputs queued behind the one that ended the process: sent again
            a.sent = False
        p, self.proc = self.proc, None
        _stop((p, self.cg, self._err))
        self.cg = self._err = None

    def close(self) -> None:
        self._drop()
        spare, self._spare = self._spare, None
        if spare is not None:
            _stop(spare)

    def run(self, data: bytes, out_path: str) -> ProcResult:
        """Decode one input; its ending as a :class:`ProcResult` (``returncode`` = the answered
        code, or the process's own ending when it died)."""
        return self.start(data, out_path).result()

    def start(self, data: bytes, out_path: str) -> "Answer":
        """Send one input; the :class:`Answer` waits for it (one input at a time)."""
        a = Answer(self)
        if sandbox.stopping():
            a.res = ProcResult(self.argv, None, stderr_tail="harness stopping", notes=["harness-start-failed"])
            return a
        if not self._queue and (self.proc is None or self.proc.poll() is not None):
            self._drop()
            self._start()
        a.message = f"{len(data)} {out_path}\n".encode() + data
        self._send(a)
        self._queue.append(a)
        return a

    def _send(self, a: "Answer") -> None:
        a.err_start = os.fstat(self._err.fileno()).st_size
        a.t0 = time.perf_counter()
        try:
            self.proc.stdin.write(a.message)
            self.proc.stdin.flush()
            a.sent = True
        except (BrokenPipeError, OSError):
            a.sent = False

    def _resend(self, a: "Answer") -> None:
        """A fresh process for ``a`` and the inputs queued behind it."""
        self._drop()
        self._start()
        for x in (a, *self._queue):
            self._send(x)

    def _answered(self, line: bytes, err: str, elapsed: float) -> ProcResult:
        text = line.decode("utf-8", "replace").strip()
        head = text.split(" ", 1)[0]
        if not head.lstrip("-").isdigit():
            self._drop()  # the protocol is broken: start afresh, judge this answer
            return ProcResult(self.argv, 125, elapsed_s=elapsed,
                              stderr_tail=err + f"\n[persistent] not an answer line: {text[:120]!r}")
        res = ProcResult(self.argv, int(head), elapsed_s=elapsed, stderr_tail=err)
        self._answers += 1
        if res.returncode == 0 or self._answers % 16 == 0:  # each file is capped by RLIMIT_FSIZE anyway
            res.output_bytes = sandbox.tree_size(self.workdir, stop_at=self.limits.output_mb * 2**20 * 4)
            if res.output_bytes > self.limits.output_mb * 2**20:
                res.output_limit_hit = True
        return res

    def _ended(self, err_start: int, elapsed: float, timed_out: bool) -> ProcResult:
        """The process died or hung while decoding: its ending, then a fresh start next time."""
        p = self.proc
        if timed_out:
            sandbox._kill_group(p.pid)
        if not timed_out:  # it died: give it a moment to be reaped, else it hangs with its stdout closed
            for _ in range(200):
                if os.waitid(os.P_PID, p.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None:
                    break
                time.sleep(0.005)
            else:
                timed_out = True
                sandbox._kill_group(p.pid)
        try:
            _pid, status, ru = os.wait4(p.pid, 0)
        except ChildProcessError:
            status, ru = 0, None
        p.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        oom, pids_hit = self.cg.oom_killed(), self.cg.pids_exhausted()
        err = _tail_from(self._err.fileno(), err_start)
        res = sandbox.result(self.argv, self.limits, status, ru, elapsed, timed_out=timed_out, mem_hit=False,
                             oom=oom, pids_hit=pids_hit, bwrap_status=sandbox.isolation() == "bwrap",
                             stdout_tail="", stderr_tail=err, measure_dirs=[self.workdir])
        self._drop()
        if res.returncode == 0 and not timed_out:  # it exited cleanly in the middle of an input
            res.returncode = 125
            res.stderr_tail += "\n[persistent] the decoder exited without answering"
        return res

    def _read_line(self, deadline: float) -> bytes | None:
        """One answer line; b"" when the process closed its stdout; None on timeout."""
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._buf:
            left = deadline - time.perf_counter()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                return None
            chunk = os.read(fd, 65536)
            if not chunk:
                return b""
            self._buf += chunk
            if len(self._buf) > 65536:
                return self._buf[:200]
        line, _, self._buf = self._buf.partition(b"\n")
        return line


def _stop(server: tuple) -> None:
    """Stop one (process, cgroups, stderr) of :meth:`PersistentDecoder._launch`."""
    proc, cg, err = server
    sandbox.stop_server(proc, cg, grace_s=0.5)  # end of input first: a well-behaved server exits
    if err is not None:
        err.close()


def _tail_from(fd: int, start: int, end: int | None = None) -> str:
    size = os.fstat(fd).st_size if end is None else end
    at = max(start, size - sandbox.TAIL_BYTES)
    data = os.pread(fd, size - at, at) if size > at else b""
    return ("…" if at > start else "") + data.decode("utf-8", "replace")



class Answer:
    """One input sent to a :class:`PersistentDecoder`: ``wait`` until it answered or ended
    (the process is free for the next input), ``result`` judges it."""

    def __init__(self, dec: PersistentDecoder) -> None:
        self.dec = dec
        self.res: ProcResult | None = None
        self.sent = False
        self.t0 = 0.0
        self.err_start = 0
        self.line: bytes | None = None
        self.message = b""

    def wait(self) -> None:
        if self.res is not None or self.line is not None:
            return
        dec = self.dec
        while dec._queue and dec._queue[0] is not self:
            dec._queue[0].wait()  # inputs sent earlier answer first
        if dec._queue and dec._queue[0] is self:
            dec._queue.popleft()
        if not self.sent or dec.proc is None:
            dec._resend(self)  # sent to a process that ended under an earlier input
        # this input's time and stderr begin where the previous answer ended
        begun = max(self.t0, dec._last_done)
        err_start = max(self.err_start, dec._err_mark)
        line = dec._read_line(begun + dec.limits.timeout_s) if self.sent else b""
        dec._last_done = time.perf_counter()
        elapsed = dec._last_done - begun
        if not line:  # None: no answer in time; b"": the process closed its end (it died)
            self.res = dec._ended(err_start, elapsed, timed_out=line is None)
            return
        self.line, self.elapsed = line, elapsed
        err_end = os.fstat(dec._err.fileno()).st_size
        dec._err_mark = err_end
        self.err = _tail_from(dec._err.fileno(), err_start, err_end)

    def result(self) -> ProcResult:
        self.wait()
        if self.res is None:
            self.res = self.dec._answered(self.line, self.err, self.elapsed)
        return self.res
