"""The persistent decoder protocol (version 2): ``[commands] serve`` keeps one decoder process
alive for many inputs (AFL++'s persistent mode, over a pipe).

The harness starts ``serve`` once per worker, sandboxed and limited like any decoder (its
folder, its view, the memory and file-size limits for the whole process — no CPU-time limit,
which would add up over inputs), with stdin and stdout as pipes. Per input::

    harness -> decoder:  "<id> <size> <output path>\\n" then <size> bytes (the stream)
    decoder -> harness:  "<id> <code>[ <message>]\\n"

``<id>`` is the request's number (random, never guessable ahead), echoed in its answer. ``<code>``
means what the exit code of ``decode`` means (0 decoded, the output written to the path; 69
not supported; a reject code from ``reject_exit_codes``; anything else is a Fail). The output
path's extension is the manifest's ``faps_format``. The decoder flushes its answer (nothing
else is sent until it arrives) and ends when its stdin closes.

Framing, one input at a time. The next input is written only once the previous one's answer is
in, so whatever happens between two answers — a crash, a hang, a report on stderr — is the
input in flight's (unless confirmation says otherwise: "Answers bound to what they answer",
below), and the inputs queued behind it are sent, in order, to a fresh process (after a first
crash two spare processes are kept starting in the background, so the next input need not wait
for a sandbox: a crash can cost two, as said below). Reads and writes are bounded in size and
time, in both directions: the input is written with the input's deadline while the harness
keeps reading (a decoder that answers instead of reading cannot block it), an answer is one
line of at most :data:`MAX_ANSWER` bytes, and a decoder that sends more than the one answer
asked for — an answer before its input, two answers, a megabyte of text, another request's id —
has broken the protocol (``protocol-error``, an unexpected exit), and the process is replaced.
Whose error it is: a garbled line, a flood, or a second line after the answer, the input in
flight's; bytes written before the input in flight was (an answer ahead of its request, whose
random id cannot be guessed), or a repeated answer to the previous request, the previous
input's — for a decoder that reads one request at a time, that is what wrote them. To make that
possible, an input's result is given out only once the next queued input has answered too (when
one is queued: the decoder keeps working meanwhile), and an input wrongly held up by the
previous one's error is sent again to a fresh process. A process that exits while decoding is
that input's ending as its exit status says (a crash, a memory limit...); one that exits 0
without answering is a protocol error too.

A crash (the process dies: a signal, a sanitizer abort, a panic), a hang (no answer within
``timeout_s``) or a memory or output blow-up is the ending of the input being decoded, and
what the process writes on stderr from the previous answer to this input's is this input's
stderr (a crash report there is a crash). The
folder's size is watched while an input runs (:mod:`.watch`). The result is a
:class:`~fbaconf.isolation.sandbox.ProcResult`, judged by :mod:`.endings` like a spawned
decoder's.

Answers bound to what they answer. An answer says "done" — a decoder may send it before it has
finished (answer, then decode), and then its crash, hang, blow-up, exit or crash report comes
while the *next* input is in flight. So an ending on a process that had answered an earlier
input is confirmed. The input in flight is sent again as the first input of a fresh process
(the spare): an ending there is its own. If it is answered there instead, the input the old
process answered last is run **alone** (:meth:`PersistentDecoder.alone`: a fresh process, that
one input, its stdin closed after the answer and its exit awaited — everything the process
does is that input's); if it ends so alone, the ending is filed under it (its result is still
held: an input's result is given out once the next queued input has answered, and that
answer now includes the confirmation; one already given out — one input at a time, ``-j N``
— reaches its caller through :attr:`Answer.on_late`). An ending neither reproduces alone
needs what the process decoded before: it stays with the input in flight, marked
``not-reproduced-alone`` (flaky). A process that crashes between an answer and the next
request, and a crash report printed while an input was in flight, are confirmed alone the same
way. Once an ending of a kind (signal, limit, exit code, crash report: :func:`ending_key`) has
been confirmed as the input-in-flight's, that kind is not confirmed again on this decoder: a
later one is at worst one more hit of a finding already filed under its own input. A clean
answer costs nothing; a new kind of crash, one process start (two when the input answered
before it must be run alone); a hang, its timeout once more.
"""

from __future__ import annotations

import collections
import os
import tempfile
import time
from pathlib import Path

from fbaconf.safefs import tree_size

from . import preflight, sandbox
from .cgroups import Cgroups
from .endings import crash_report
from .forkclient import ForkServerError
from .process import Finish, Note, ProcResult, exit_reported, kill_group, launch_server, result, stopping
from .sandbox import Limits, View
from .serve import (
    CHUNK as CHUNK,  # the protocol's constants, re-exported
    MAX_ANSWER as MAX_ANSWER,
    PROTOCOL as PROTOCOL,
    Answer,
    Server,
)
from .watch import Watch

FLAKY = Note.NOT_REPRODUCED_ALONE
SPARES = 2  # processes kept starting ahead once a decoder has crashed (PersistentDecoder._start)
NO_ANSWER = Note.NO_ANSWER


def abnormal(res: ProcResult) -> bool:
    """Whether ``res`` is an ending, not an answer: the process ended or was stopped before it
    answered, or died or blew a limit after it, or printed a crash report, or broke the
    protocol — an answered code, whatever it is, is none."""
    return (
        NO_ANSWER in res.notes
        or Note.PROTOCOL_ERROR in res.notes
        or res.signal is not None
        or res.timed_out
        or res.memory_limit_hit
        or res.output_limit_hit
        or crash_report(res.stderr_tail) is not None
    )


# signal, timed out, memory, output, protocol error, exit code before an answer, crash report kind and signature
EndingKey = tuple[str | None, bool, bool, bool, bool, int | None, str | None, str | None]


def ending_key(res: ProcResult) -> EndingKey:
    """What kind of ending ``res`` is (signal, limit, exit code, crash report): an ending of a
    kind already confirmed as the input-in-flight's is not confirmed again (module doc)."""
    rep = crash_report(res.stderr_tail)
    return (
        res.signal,
        res.timed_out,
        res.memory_limit_hit,
        res.output_limit_hit,
        Note.PROTOCOL_ERROR in res.notes,
        res.returncode if NO_ANSWER in res.notes else None,
        rep.kind if rep else None,
        rep.signature if rep else None,
    )


class PersistentDecoder:
    """One ``serve`` process for one worker folder; :meth:`run` sends one input."""

    def __init__(
        self, argv: list[str], root: Path, workdir: Path, view: View, limits: Limits, env: dict[str, str] | None = None
    ) -> None:
        self.argv = list(argv)
        self.root = Path(root).resolve()
        self.workdir = Path(workdir).resolve()
        self.view = view
        self.limits = limits
        self.env = env
        self.starts = 0
        self.io = self.root / ".io"
        self.server: Server | None = None
        self._spares: collections.deque[Server] = collections.deque()  # started ahead, after a first crash
        self._alone_spare: Server | None = None  # the next run alone's process, started ahead
        self._pending: collections.deque[Answer] = collections.deque()
        self._inflight: Answer | None = None
        self._launches = 0  # processes started to take inputs in turn (the one in use, the spare)
        self.alone_runs = 0  # processes started for one input each (alone)
        self._answers = 0
        self.unclaimed: list[tuple[Answer, ProcResult]] = []  # late endings of inputs given out, no on_late
        self._owned: set[EndingKey] = set()  # ending kinds confirmed as the input-in-flight's (ending_key)

    # ---------------------------------------------------------------- processes
    def _launch(self, *, alone: bool = False) -> Server:
        """One sandboxed ``serve`` process, not yet given an input."""
        self.io.mkdir(parents=True, exist_ok=True)
        (self.workdir / "tmp").mkdir(parents=True, exist_ok=True)
        env = sandbox.decoder_env(self.workdir, self.env)
        why = preflight.exec_problem(self.argv, env)
        if why is not None:
            raise ForkServerError(f"cannot start the persistent decoder: {why}")
        inner, status_r = list(self.argv), None
        fds: list[int] = []
        if sandbox.isolation() == "bwrap":
            head, status_r = sandbox.sandbox_argv(self.view, self.workdir, fds)
            inner = head + inner
        lim = self.limits
        if alone:
            self.alone_runs += 1
        else:
            self._launches += 1
        err = tempfile.TemporaryFile(dir=self.io)  # its stderr (the one in use, a spare and one alone run at most)
        cg = Cgroups(processes=lim.processes, memory_mb=lim.memory_mb if lim.memory_kind != "none" else 0)
        as_bytes = sandbox.as_bytes_for(lim, cg)
        try:
            proc, cg = launch_server(
                inner,
                lim,
                cwd=self.workdir,
                env=env,
                stderr=err,
                pass_fds=tuple(fds),
                as_bytes=as_bytes,
                fsize=lim.output_mb * 2**20,
                cg=cg,
            )
        except OSError as e:
            err.close()
            if status_r is not None:
                os.close(status_r)
            raise ForkServerError(f"cannot start the persistent decoder: {e}") from e
        finally:
            for fd in fds:
                os.close(fd)
        srv = Server(proc, cg, err, status_r, as_bytes > 0)
        for f in (srv.stdin, srv.stdout):
            os.set_blocking(f.fileno(), False)
        return srv

    def _take_spare(self, *, alone: bool = False) -> Server | None:
        if alone:
            spare, self._alone_spare = self._alone_spare, None
        else:
            spare = self._spares.popleft() if self._spares else None
        if spare is not None and spare.exit_status() is not None:  # it died waiting
            spare.stop()
            spare = None
        return spare

    def _start(self) -> Server:
        """The process for the next inputs: a spare if one is ready, else a new one. After a
        first restart :data:`SPARES` are kept starting in the background, so a decoder that
        crashes often does not wait for a sandbox to start before each next input: a crash in a
        process that answered before takes two (its input confirmed as a fresh process's first,
        which crashes too, then the next input), and a sandbox takes tens of milliseconds to
        start on a busy machine, longer than a crashing decoder's next crash may take."""
        srv = self.server = self._take_spare() or self._launch()
        self.starts += 1
        if self.starts > 1:
            while len(self._spares) < SPARES:
                self._spares.append(self._launch())
        return srv

    def _drop(self) -> None:
        """Stop the process in use (it ended or broke the protocol); the spare stays."""
        srv, self.server = self.server, None
        if srv is not None:
            srv.stop()

    def close(self) -> None:
        self._drop()
        spares = [*self._spares, self._alone_spare]
        self._spares.clear()
        self._alone_spare = None
        for spare in spares:
            if spare is not None:
                spare.stop()

    # ---------------------------------------------------------------- inputs
    def run(self, data: bytes, out_path: str) -> ProcResult:
        """Decode one input; its ending as a :class:`ProcResult` (``returncode`` = the answered
        code, or the process's own ending when it died)."""
        return self.start(data, out_path).result()

    def start(self, data: bytes, out_path: str) -> Answer:
        """Queue one input; it is written to the decoder once every input before it has its
        answer. The :class:`Answer` waits for it."""
        a = Answer(self, data, out_path)
        if stopping():
            a.res = ProcResult(self.argv, None, stderr_tail="harness stopping", notes=[Note.HARNESS_START_FAILED])
            return a
        self._pending.append(a)
        if self._inflight is None:
            self._dispatch()
        return a

    def drain(self) -> None:
        """Every queued input answered or ended (the process is then free)."""
        while self._inflight is not None or self._pending:
            if self._inflight is None:
                self._dispatch()
            if self._inflight is not None:
                self._complete(self._inflight)

    def _dispatch(self) -> None:
        """Write the next queued input (the decoder is free)."""
        while self._inflight is None and self._pending:
            a = self._pending.popleft()
            if a.res is not None:
                continue
            srv = self.server
            if srv is not None and srv.exit_status() is not None:  # it ended after its last answer
                self._ended_between(srv)
            srv = self.server
            if srv is None:
                try:
                    srv = self._start()
                except ForkServerError as e:
                    a.res = ProcResult(self.argv, None, stderr_tail=str(e), notes=[Note.EXEC_FAILED], detail=str(e))
                    continue
            self._inflight = a
            srv.send(a, self.limits)  # how it went is read by _complete

    def _ended_between(self, srv: Server) -> None:
        """The process ended after answering its last input, nothing sent since: an exit is let
        go (a fresh process takes the next input); a crash, or a crash report, is confirmed on
        the input it answered last (module doc)."""
        last = srv.last
        res = self._ended(last, srv, None, answered=True) if last is not None else None
        self._drop()
        if last is not None and res is not None and abnormal(res):
            self._whose(res, None, last)

    def _complete(self, a: Answer) -> None:
        """Read ``a``'s answer (``a`` is in flight) and judge it; then the next input goes out."""
        srv = self.server
        if srv is None:  # an input is in flight only on a running process
            raise RuntimeError("an input in flight without its process")
        prev = srv.last  # the input this process answered before ``a``, if any
        watch = Watch(
            self.limits, [self.workdir], pid=srv.proc.pid, procs=srv.cg.procs if srv.cg.dirs else None, t0=a.t0
        )
        got = srv.read_answer(a, a.t0 + self.limits.timeout_s, watch)
        a.elapsed = time.perf_counter() - a.t0
        self._inflight = None
        res = None
        if got == "answered":
            res = self._answered(a, srv)
            srv.last = a
        elif got in ("timeout", "memory", "output", "eof"):
            res = self._ended(a, srv, None if got == "eof" else got)
            self._drop()
        else:  # a protocol error: of this input, or of the previous one (module doc)
            whose, why = got if isinstance(got, tuple) else ("this", f"ended unexpectedly ({got})")
            if whose == "previous" and prev is not None and not prev.consumed:
                prev.res = self._broken(prev, srv, why)
                self._drop()
                a.reset()
                self._pending.appendleft(a)  # held up by the previous input's error: again, on a fresh process
            else:
                a.res, a.suspect = self._broken(a, srv, why), None
                self._drop()
        if res is None:
            pass
        elif a.suspect is not None:
            self._confirmed(a, res)
        elif prev is None or not abnormal(res) or ending_key(res) in self._owned:
            a.res = res
        elif got == "answered":  # a crash report; the process lives on: confirmed on processes of their own
            self._whose(res, a, prev)
        else:  # maybe what an answer sent early left running (module doc)
            a.reset()
            a.suspect = (res, prev)
            self._pending.appendleft(a)  # again, as the first input of a fresh process
        self._dispatch()

    def _confirmed(self, a: Answer, res: ProcResult) -> None:
        """``a`` ran again as the first input of a fresh process after an ending it may not own
        (``a.suspect``): an ending now is its own; a clean answer sends the question on to the
        input answered before it (module doc)."""
        if a.suspect is None:  # only an input run again to confirm an ending comes here
            raise RuntimeError("confirming an ending no input is suspected of")
        (first, prev), a.suspect = a.suspect, None
        a.res = res  # its own ending or result, whether the first ending was its own or not
        if not abnormal(res):
            self._whose(first, None, prev, inflight=a)
        elif ending_key(res) == ending_key(first):
            self._owned.add(ending_key(res))
        else:  # another ending of its own: the first may still be the input answered before's
            self._before(prev)

    def _whose(self, res: ProcResult, a: Answer | None, prev: Answer, *, inflight: Answer | None = None) -> None:
        """``res`` ended (or was printed by) a process that had answered ``prev`` last, while
        ``a`` was in flight (``a`` None: nothing was, or ``inflight`` has its own result already):
        file it under the input that ends so alone (module doc)."""
        if a is not None:
            own = self.alone(a.data, a.out_path)
            if Note.EXEC_FAILED in own.notes:  # no process to confirm it with: the input in flight's, as ever
                a.res = res
                return
            a.res = own  # its own ending, on a process of its own
            if abnormal(own):
                return
            inflight = a
        if self._before(prev):
            return
        res.notes.append(FLAKY)
        res.detail = (res.detail + " " if res.detail else "") + (
            "(flaky: neither this input nor the one the process answered before it ends so alone — it needs "
            "what the process decoded before)"
        )
        if inflight is not None:
            inflight.res = res
        else:
            self._file(prev, res)

    def _before(self, prev: Answer) -> bool:
        """Run ``prev`` (the input a process answered before an ending) alone; whether it ended
        so there — its ending is then filed under it."""
        before = self.alone(prev.data, prev.out_path)
        if not abnormal(before) or Note.EXEC_FAILED in before.notes:
            return False
        before.detail = (before.detail + " " if before.detail else "") + (
            "(it answered before it had finished: the ending came while the next input was in flight, "
            "and this input alone ends so)"
        )
        self._file(prev, before)
        return True

    def _file(self, ans: Answer, res: ProcResult) -> None:
        """``res`` is ``ans``'s ending: its result if not given out yet, else a late ending."""
        if not ans.consumed:
            ans.res = res
        elif ans.on_late is not None:
            ans.on_late(res)
        else:
            self.unclaimed.append((ans, res))

    def alone(self, data: bytes, out_path: str) -> ProcResult:
        """``data`` as the only input of a fresh process: its request, its answer, then its
        stdin closed and its exit awaited within the input's timeout — everything that process
        does is this input's. A crash, a limit or a crash report after the answer is its ending;
        an exit, whatever its code, leaves the answer. (Not the spare, which stays ready for the
        inputs in turn: one started ahead for runs alone, the next one starting while this one
        runs — a decoder that crashes often, or a minimisation, does not wait for a sandbox.)"""
        try:
            srv = self._take_spare(alone=True) or self._launch(alone=True)
        except ForkServerError as e:
            return ProcResult(self.argv, None, stderr_tail=str(e), notes=[Note.EXEC_FAILED], detail=str(e))
        try:
            self._alone_spare = self._launch(alone=True)
        except ForkServerError:
            self._alone_spare = None  # the next run alone starts its own
        a = Answer(self, data, out_path)
        try:
            srv.send(a, self.limits)
            deadline = a.t0 + self.limits.timeout_s
            watch = Watch(
                self.limits, [self.workdir], pid=srv.proc.pid, procs=srv.cg.procs if srv.cg.dirs else None, t0=a.t0
            )
            got = srv.read_answer(a, deadline, watch)
            a.elapsed = time.perf_counter() - a.t0
            answered = got == "answered"
            if answered:
                res = self._answered(a, srv)
                got = srv.finish(a, deadline, watch)
                if got == "eof":
                    end = self._ended(a, srv, None, answered=True)
                    return end if abnormal(end) else res
            if got in ("timeout", "memory", "output", "eof"):
                return self._ended(a, srv, None if got == "eof" else got, answered=answered)
            return self._broken(a, srv, got[1])
        finally:
            srv.stop()

    def _answered(self, a: Answer, srv: Server) -> ProcResult:
        head = a.line.split(b" ", 2)
        code = int(head[1])
        srv.err_mark = os.fstat(srv.err.fileno()).st_size  # what it writes from now on is the next input's
        res = ProcResult(self.argv, code, elapsed_s=a.elapsed, stderr_tail=srv.err_since(a.err_start, srv.err_mark))
        self._answers += 1
        if code == 0 or self._answers % 16 == 0:  # each file is capped by RLIMIT_FSIZE anyway
            res.output_bytes = tree_size(self.workdir, stop_at=self.limits.output_mb * 2**20 * 4)
            if res.output_bytes > self.limits.output_mb * 2**20:
                res.output_limit_hit = True
        return res

    def _broken(self, a: Answer, srv: Server, why: str) -> ProcResult:
        """The decoder broke the protocol during ``a``: that input's ending (a fresh process next)."""
        return ProcResult(
            self.argv,
            None,
            elapsed_s=a.elapsed,
            stderr_tail=srv.err_since(a.err_start),
            notes=[Note.PROTOCOL_ERROR],
            detail=f"broke the persistent protocol (version {PROTOCOL}, docs/fuzzing.md): {why}",
        )

    def _ended(self, a: Answer, srv: Server, hit: str | None, *, answered: bool = False) -> ProcResult:
        """The process died (``hit`` None) or was stopped at a limit (``hit``) while decoding
        ``a`` (``answered``: after its answer)."""
        p = srv.proc
        if hit is not None:
            kill_group(p.pid)
        else:  # it died: give it a moment to be reaped, else it hangs with its stdout closed
            for _ in range(200):
                if os.waitid(os.P_PID, p.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT) is not None:
                    break
                time.sleep(0.005)
            else:
                hit = "timeout"
                kill_group(p.pid)
        try:
            _pid, status, ru = os.wait4(p.pid, 0)
        except ChildProcessError:
            status, ru = 0, None
        p.returncode = os.waitstatus_to_exitcode(status)  # reaped here, not by Popen
        notes = [Note.AS_LIMIT] if srv.as_limit else []
        if srv.status_r is not None and hit is None and not exit_reported(srv.take_status()) and not stopping():
            notes.append(Note.SANDBOX_FAILED)
        fin = Finish(
            status,
            ru,
            a.elapsed,
            timed_out=hit == "timeout",
            mem_hit=hit == "memory",
            out_hit=hit == "output",
            oom=srv.cg.oom_killed(),
            pids_hit=srv.cg.pids_exhausted(),
            bwrap_status=sandbox.isolation() == "bwrap",
            notes=tuple(notes),
        )
        res = result(
            self.argv,
            self.limits,
            fin,
            stdout_tail="",
            stderr_tail=srv.err_since(a.err_start),
            measure_dirs=[self.workdir],
        )
        if not answered:
            res.notes.append(NO_ANSWER)
        if res.returncode == 0 and hit is None and not answered:  # it exited cleanly in the middle of an input
            res.returncode = None
            res.notes.append(Note.PROTOCOL_ERROR)
            res.detail = f"broke the persistent protocol (version {PROTOCOL}): exited without answering request {a.id}"
        return res
