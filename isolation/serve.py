"""One running ``serve`` process of the persistent protocol and the answers it gives
(:mod:`.persistent` drives it)."""

from __future__ import annotations

import os
import secrets
import select
import subprocess
import time
from collections.abc import Callable
from typing import IO, TYPE_CHECKING

from .cgroups import Cgroups
from .process import Note, ProcResult, stop_server, tail_from
from .sandbox import Limits
from .watch import Watch

PROTOCOL = 2
MAX_ANSWER = 4096  # bytes of one answer line
CHUNK = 1 << 16

# How an input ended while the harness waited on it: "answered", "eof", "timeout", "memory",
# "output", or (whose, why) for a broken protocol — whose: "this" input's doing or the
# "previous" one's
End = str | tuple[str, str]

if TYPE_CHECKING:
    from .persistent import PersistentDecoder


class Server:
    """One running ``serve`` process: its pipes (non-blocking), cgroups, stderr file, the
    bubblewrap status descriptor, what it has sent back so far and the input it answered last."""

    def __init__(
        self, proc: subprocess.Popen[bytes], cg: Cgroups, err: IO[bytes], status_r: int | None, as_limit: bool
    ) -> None:
        if proc.stdin is None or proc.stdout is None:
            raise ValueError("a serve process is started with its stdin and stdout as pipes")
        self.proc, self.cg, self.err, self.status_r, self.as_limit = proc, cg, err, status_r, as_limit
        self.stdin, self.stdout = proc.stdin, proc.stdout
        self.buf = b""
        self.last: Answer | None = None
        self.err_mark: int | None = None  # the end of its stderr when its last answer was read

    def exit_status(self) -> int | None:
        """The process's exit code if it has ended (not reaped: :meth:`PersistentDecoder._ended`
        reads its status), else None."""
        if self.proc.returncode is not None:
            return self.proc.returncode
        try:
            info = os.waitid(os.P_PID, self.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return 0
        if info is None:
            return None
        return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status

    def take_status(self) -> int | None:
        fd, self.status_r = self.status_r, None
        return fd

    def stop(self) -> None:
        stop_server(self.proc, self.cg, grace_s=0.5)  # end of input first: a well-behaved server exits
        self.err.close()
        if self.status_r is not None:
            os.close(self.status_r)
            self.status_r = None

    def err_since(self, start: int, end: int | None = None) -> str:
        return tail_from(self.err.fileno(), start, end)

    def send(self, a: Answer, limits: Limits) -> None:
        """Write ``a``'s request within its deadline, reading what the decoder sends meanwhile
        (kept for :meth:`read_answer`; more than one answer's worth is a protocol error)."""
        a.id = secrets.randbits(48)
        a.srv = self
        # stderr written since the last answer was read is this input's (a report an answer sent
        # early left behind is then confirmed); before any answer, from now
        a.err_start = self.err_mark if self.err_mark is not None else os.fstat(self.err.fileno()).st_size
        a.t0 = time.perf_counter()
        data = memoryview(f"{a.id} {len(a.data)} {a.out_path}\n".encode() + a.data)
        wfd, rfd = self.stdin.fileno(), self.stdout.fileno()
        deadline = a.t0 + limits.timeout_s
        if not self._take(rfd, a, wait=False):
            return
        while data:
            left = deadline - time.perf_counter()
            if left <= 0:
                a.pending_end = "timeout"  # it does not read its input
                return
            readable, writable, _ = select.select([rfd], [wfd], [], left)
            if readable and not self._take(rfd, a):
                return
            if writable:
                try:
                    data = data[os.write(wfd, data) :]
                except BlockingIOError:
                    continue
                except (BrokenPipeError, OSError):
                    a.pending_end = "eof"  # it died (or closed its input): its ending says which
                    return
        a.early = bool(self.buf)  # written before it had all of this request: not its answer (module doc)

    def _take(self, rfd: int, a: Answer, wait: bool = True) -> bool:
        """Read what the decoder sent (``wait``: select said there is something); False (and
        ``a.pending_end`` set) when that ends the input."""
        if not wait and not select.select([rfd], [], [], 0)[0]:
            return True
        try:
            chunk = os.read(rfd, CHUNK)
        except BlockingIOError:
            return True
        except OSError:
            chunk = b""
        if not chunk:
            a.pending_end = "eof"
            return False
        self.buf += chunk
        if len(self.buf) > MAX_ANSWER:
            a.pending_end = (
                "this",
                f"sent {len(self.buf)}+ bytes where one answer line of at most {MAX_ANSWER} belongs",
            )
            return False
        return True

    def read_answer(self, a: Answer, deadline: float, watch: Watch) -> End:
        """Wait for ``a``'s answer: "answered" (``a.line`` set), "eof", "timeout", "memory",
        "output", or (whose, why) when the decoder broke the protocol — whose: "this" input's
        doing or the "previous" one's (module doc)."""
        rfd = self.stdout.fileno()
        if a.pending_end is not None:
            return a.pending_end
        if a.early:
            return (
                "previous",
                f"wrote {self.buf[:60]!r} before request {a.id} was written in full (an answer "
                f"ahead of its request, or more than one answer)",
            )
        while b"\n" not in self.buf:
            now = time.perf_counter()
            if now >= deadline:
                return "timeout"
            if not select.select([rfd], [], [], min(deadline - now, watch.next_in(now)))[0]:
                hit = watch.check(time.perf_counter())
                if hit:
                    return hit
                continue
            if not self._take(rfd, a):
                return a.pending_end or "eof"  # _take set it
        line, _, rest = self.buf.partition(b"\n")
        self.buf = b""
        head = line.split(b" ", 2)
        if len(head) < 2 or not head[0].isdigit() or not head[1].lstrip(b"-").isdigit() or len(head[1]) > 9:
            return ("this", f"not an answer line (version {PROTOCOL}: '<id> <code>[ <message>]'): {line[:120]!r}")
        rid = int(head[0]) if len(head[0]) < 20 else -1
        if rid != a.id:
            prev = self.last.id if self.last is not None else None
            what = (
                f"answered request {rid} more than once"
                if rid == prev
                else f"answered request {head[0][:20].decode()}, which was never sent (an answer ahead of its request)"
            )
            return ("previous", what)
        if rest:
            return ("this", f"sent more than the one answer to request {a.id}: {rest[:80]!r}")
        a.line = line
        return "answered"

    def finish(self, a: Answer, deadline: float, watch: Watch) -> End:
        """After the answer of the process's only input (:meth:`PersistentDecoder.alone`): close
        its stdin and wait for it to end — "eof" when it did (closed its output), a limit's
        name, or ("this", why) when it wrote more."""
        try:
            self.stdin.close()
        except OSError:
            pass
        rfd = self.stdout.fileno()
        while True:
            now = time.perf_counter()
            if now >= deadline:
                return "timeout"
            if not select.select([rfd], [], [], min(deadline - now, watch.next_in(now)))[0]:
                hit = watch.check(time.perf_counter())
                if hit:
                    return hit
                continue
            if not self._take(rfd, a):
                return a.pending_end or "eof"  # _take set it
            if self.buf:
                return ("this", f"wrote {self.buf[:60]!r} after its answer to request {a.id}, its only request")


class Answer:
    """One input queued to a :class:`PersistentDecoder`: ``wait`` until it answered or ended
    (the process is free for the next input), ``result`` judges it."""

    def __init__(self, dec: PersistentDecoder, data: bytes, out_path: str) -> None:
        self.dec, self.data, self.out_path = dec, data, out_path
        self.res: ProcResult | None = None
        self.consumed = False  # its result was given out
        self.on_late: Callable[[ProcResult], None] | None = None  # its ending, found after it was given out
        self.suspect: tuple[ProcResult, Answer] | None = None  # an ending to confirm, and the input answered before
        self.reset()

    def reset(self) -> None:
        """Not sent (again): no request id, no process."""
        self.srv: Server | None = None
        self.id = 0
        self.t0 = 0.0
        self.elapsed = 0.0
        self.err_start = 0
        self.line = b""
        self.early = False  # bytes came before its request was written in full
        self.pending_end: End | None = None  # how it ended while its input was written

    def wait(self) -> None:
        dec = self.dec
        while self.res is None:
            if dec._inflight is None:
                dec._dispatch()
                if dec._inflight is None:  # not queued (a stop), or ended at its dispatch
                    if self.res is None:
                        self.res = ProcResult(
                            dec.argv, None, stderr_tail="harness stopping", notes=[Note.HARNESS_START_FAILED]
                        )
                    return
            dec._complete(dec._inflight)

    def result(self) -> ProcResult:
        """Its ending — once the input queued after it on the same process has answered too
        (whatever that brings, a repeated or early answer, is this input's doing)."""
        self.wait()
        dec, nxt = self.dec, self.dec._inflight
        if (
            not self.consumed
            and nxt is not None
            and nxt.res is None
            and self.srv is not None
            and nxt.srv is self.srv
            and self.srv.last is self
        ):
            dec._complete(nxt)
            while nxt.res is None and nxt.suspect is not None and nxt.suspect[1] is self and dec._inflight is nxt:
                dec._complete(nxt)  # its ending is being confirmed: it may be this input's
        self.consumed = True
        if self.res is None:  # wait() returns only once it is set
            raise RuntimeError("an input's result was read before it ended")
        return self.res
