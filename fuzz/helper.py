"""Helper processes of the fuzzing loop: a Python process (``python -m MODULE ARGS``) that answers
numbered requests ahead of the loop on a CPU the loop leaves free.

With one decoder at a time the loop is the limit: the decoder under test answers in microseconds
and waits for the loop's next input, so the second CPU is mostly idle. Work whose result is a pure
function of what the loop already knows (a fresh valid stream of an input number, the coverage of
an input's bytes) is asked of a helper as soon as it is known and taken when needed; a helper that
is late, dead or never started leaves the loop to do the same work itself, with the same result, so
a run replays input for input with or without one. Both directions are records: the number
(int64), the payload's length (uint64), the payload. The helper runs at a lower priority: the
decoder under test and the loop come first."""

from __future__ import annotations

import collections
import fcntl
import os
import select
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from typing import Any

HEAD = struct.Struct("<qQ")
# How long the loop waits for the request the helper is working on before it does that work
# itself. Waiting frees the loop's CPU for the helper, which has a head start on that very
# request: doing it again here is slower, unless the helper is stuck. (A fixed wait of about one
# request's usual cost had the loop redo the slow ones: a fresh stream of 100 ms, a 36 KB parse
# of 240 ms, each made twice.)
STUCK_S = 1.0


def record(index: int, payload: bytes = b"") -> bytes:
    return HEAD.pack(index, len(payload)) + payload


class Helper:
    """One helper process: :meth:`send` requests, :meth:`drain` answers. Any failure (it cannot
    start, it dies, a pipe breaks) stops it; the caller sees :attr:`alive` false and does the
    work itself."""

    def __init__(self, module: str, args: list[str]) -> None:
        self.argv = [sys.executable, "-m", module, *args]
        self.proc: subprocess.Popen[bytes] | None = None
        self._out = -1
        self._buf = bytearray()

    @property
    def alive(self) -> bool:
        return self.proc is not None

    def start(self) -> bool:
        try:
            proc = subprocess.Popen(self.argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        except OSError:
            return False
        assert proc.stdin is not None and proc.stdout is not None  # noqa: S101 - both are pipes
        self.proc, self._out = proc, proc.stdout.fileno()
        os.set_blocking(self._out, False)
        try:  # room for answers ahead (a pipe holds 64 KiB; a fresh stream and its frames 5-45 KB)
            fcntl.fcntl(self._out, fcntl.F_SETPIPE_SZ, 1 << 20)
        except (OSError, AttributeError):
            pass
        return True

    def send(self, data: bytes) -> bool:
        """Write requests (records); False when the helper is gone (it is stopped)."""
        if self.proc is None or self.proc.stdin is None:
            return False
        try:
            self.proc.stdin.write(data)
            self.proc.stdin.flush()
        except OSError:  # it died
            self.stop()
            return False
        return True

    def drain(self, timeout: float) -> list[tuple[int, bytes]]:
        """The answers the helper wrote, waiting up to ``timeout`` s for something."""
        fd = self._out
        if fd < 0 or not select.select([fd], [], [], max(0.0, timeout))[0]:
            return []
        try:
            while chunk := os.read(fd, 1 << 20):
                self._buf += chunk
        except BlockingIOError:  # all there is for now
            pass
        else:  # end of its output: it died
            self.stop()
            return []
        out = []
        while len(self._buf) >= HEAD.size:
            k, n = HEAD.unpack_from(self._buf)
            if len(self._buf) < HEAD.size + n:
                break
            out.append((k, bytes(self._buf[HEAD.size : HEAD.size + n])))
            del self._buf[: HEAD.size + n]
        return out

    def stop(self) -> None:
        proc, self.proc, self._out = self.proc, None, -1
        self._buf.clear()
        if proc is None:
            return
        for f in (proc.stdin, proc.stdout):
            try:
                if f is not None:
                    f.close()
            except OSError:  # its stdin: the helper is gone
                pass
        proc.kill()  # nothing of its own to keep: what it is making is wanted no more
        proc.wait()


class Ahead:
    """A helper's answers to requests numbered in the order they are asked: sent
    (:meth:`_send`), read into ``ready`` as they come (:meth:`_drain`, each through
    :meth:`_decode`) and taken by number (:meth:`_take`), waiting for the one the helper is
    working on unless it is stuck. Whatever fails stops the helper; the caller does the work."""

    def __init__(self, module: str, args: list[str], helper: bool) -> None:
        self.helper = helper  # start it when first needed
        self._helper = Helper(module, args)
        self.queue: collections.deque[int] = collections.deque()  # asked, not answered yet, in order
        self.ready: dict[int, Any] = {}  # answered, not taken yet

    @property
    def proc(self) -> subprocess.Popen[bytes] | None:
        """The helper's process while it runs, else None."""
        return self._helper.proc

    def _running(self) -> bool:
        """Whether the helper runs, started now if it is wanted and not yet."""
        if self.helper and not self._helper.alive and not self._helper.start():
            self.helper = False
        return self._helper.alive

    def _send(self, numbers: list[int], data: list[bytes]) -> None:
        if self._helper.send(b"".join(record(k, d) for k, d in zip(numbers, data, strict=True))):
            self.queue.extend(numbers)
        else:
            self.close()

    def _take(self, index: int) -> Any:
        """Request ``index``'s answer, or None (not asked, behind, dead, stuck); requests before it
        are wanted no more."""
        while self.queue and self.queue[0] < index:
            self.queue.popleft()
        if self._helper.alive and index not in self.ready:
            self._drain(0.0)
            end = time.monotonic() + STUCK_S
            while self._helper.alive and index not in self.ready and self.queue and self.queue[0] == index:
                if time.monotonic() >= end:  # the one it is working on: stuck
                    break
                self._drain(end - time.monotonic())
        got = self.ready.pop(index, None)
        for k in [k for k in self.ready if k < index]:
            del self.ready[k]
        while self.queue and self.queue[0] <= index:
            self.queue.popleft()  # answered later, if at all: done here by then
        return got

    def _drain(self, timeout: float) -> None:
        """Read what the helper wrote, waiting up to ``timeout`` s for something."""
        got = self._helper.drain(timeout)
        if not self._helper.alive:
            self.close()
            return
        for k, payload in got:
            if self.queue and k >= self.queue[0]:  # else taken (done here) already
                self.ready[k] = self._decode(payload)
            while self.queue and self.queue[0] <= k:
                self.queue.popleft()

    def _decode(self, payload: bytes) -> Any:
        raise NotImplementedError

    def close(self) -> None:
        """Stop the helper; what is asked later is done by the caller."""
        self.helper = False
        self._helper.stop()
        self.queue.clear()
        self.ready.clear()


def serve(answer: Callable[[int, bytes], bytes]) -> int:
    """The helper's side: a request record at a time from stdin, its answer record to stdout,
    until the loop closes its end."""
    try:  # the decoder under test and the loop first: this one fills the time they leave
        os.nice(10)
    except OSError:
        pass
    inp, out = sys.stdin.buffer, sys.stdout.buffer
    while len(head := inp.read(HEAD.size)) == HEAD.size:
        index, n = HEAD.unpack(head)
        payload = inp.read(n)
        if len(payload) != n:
            break
        try:
            out.write(record(index, answer(index, payload)))
            out.flush()
        except BrokenPipeError:  # the loop stopped
            return 0
    return 0
