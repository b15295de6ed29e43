"""Fresh valid streams, made ahead of the fuzzing loop by a helper process.

An input is a pure function of the run's seed and its index (:func:`input_rng`), and whether input
``i`` is a fresh valid stream is that generator's first draw: the loop knows which of the coming
inputs are before it reaches them. Encoding one takes the reference encoder 3-6 ms, against well
under a millisecond to make and judge any other input, so at a 4 % share they took a sixth of the
loop's time while the second CPU waited on a decoder that needs microseconds. A helper
process (``python -m fbaconf.fuzz.fresh SEED``: input numbers on its stdin, pickled entries on its
stdout) encodes them there; the stream it hands back is the one the loop would have made from the
same generator state, so a run replays input for input with or without it, and whatever goes wrong
with the helper (no process, a crash, late) leaves the loop to make the stream itself."""

from __future__ import annotations

import collections
import fcntl
import os
import pickle
import random
import select
import struct
import subprocess
import sys
import time
from collections.abc import Callable
from typing import IO

from fbaconf.harness.sysinfo import usable_cpus

from .choosers import RandomChooser
from .inputs import Entry, gen_valid

# how many inputs ahead the helper is asked: at a 4 % share about ten streams, 30-60 ms of encoding
AHEAD = 256
# how long the loop waits for the stream the helper is making before it makes it itself: about one
# stream's encoding, past which making it here is no slower
WAIT_S = 0.008
# a helper costs a process start (~0.5 s of CPU importing the encoder, while the first streams are
# made in the loop anyway): a run of fewer inputs (some 60 fresh streams) makes its own
MIN_EXECS = 1500
_HEAD = struct.Struct("<qQ")  # a record: the input's number, the pickle's length


def input_rng(seed: int, index: int) -> random.Random:
    """The generator input ``index`` of run ``seed`` is made from."""
    return random.Random(seed * 1_000_003 + index)


def fresh_valid(seed: int, index: int) -> Entry:
    """Input ``index`` of run ``seed`` when its first draw made it a fresh valid stream."""
    rng = input_rng(seed, index)
    rng.random()  # the draw that chose a fresh valid stream
    return gen_valid(RandomChooser(rng))


def helper_worthwhile(jobs: int, max_execs: int | None) -> bool:
    """Whether a run gains from the helper: one decoder at a time (the loop is the limit and a CPU
    is free), a machine with two CPUs or more, and a run long enough to repay its start."""
    return jobs == 1 and usable_cpus() >= 2 and (max_execs is None or max_execs >= MIN_EXECS)


class FreshStreams:
    """Input ``index``'s fresh valid stream (:meth:`take`): the helper's when it made it in time,
    else made here. ``wanted(i)`` says whether input ``i`` will be one. The helper (``helper``)
    starts at the first :meth:`take` and stops at :meth:`close`."""

    def __init__(self, seed: int, wanted: Callable[[int], bool], helper: bool) -> None:
        self.seed = seed
        self.wanted = wanted
        self.helper = helper
        self.proc: subprocess.Popen[bytes] | None = None
        self._in: IO[bytes] | None = None  # its stdin
        self._out = -1  # its stdout's descriptor
        self.queue: collections.deque[int] = collections.deque()  # asked, not answered yet, in order
        self.ready: dict[int, Entry] = {}  # answered, not taken yet
        self.planned = 0  # inputs below this one were looked at
        self.taken_below = 0  # the loop is past every input below this one
        self._buf = bytearray()

    def take(self, index: int) -> Entry:
        if self.helper and self.proc is None:
            self._start()
        if self.proc is not None:
            self._ask(index)
            self._drain(0.0)
            end = time.monotonic() + WAIT_S
            while self.proc is not None and index not in self.ready and self.queue and self.queue[0] == index:
                if time.monotonic() >= end:  # the one it is making, late
                    break
                self._drain(end - time.monotonic())
        e = self.ready.pop(index, None)
        self.taken_below = max(self.taken_below, index + 1)
        for k in [k for k in self.ready if k < self.taken_below]:  # never taken: the loop moved on
            del self.ready[k]
        return e if e is not None else fresh_valid(self.seed, index)

    def close(self) -> None:
        """Stop the helper; inputs made later (a finding regenerated) are made here."""
        self.helper = False
        self._stop()

    # ---------------------------------------------------------------- the helper
    def _start(self) -> None:
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "fbaconf.fuzz.fresh", str(self.seed)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
            )
        except OSError:
            self.helper = False
            return
        assert proc.stdin is not None and proc.stdout is not None  # noqa: S101 - both are pipes
        self.proc, self._in, self._out = proc, proc.stdin, proc.stdout.fileno()
        os.set_blocking(self._out, False)
        try:  # room for a few streams ahead (a pipe holds 64 KiB; a stream and its frames 5-45 KB)
            fcntl.fcntl(self._out, fcntl.F_SETPIPE_SZ, 1 << 20)
        except (OSError, AttributeError):
            pass

    def _ask(self, index: int) -> None:
        self.planned = max(self.planned, index)
        want = []
        while self.planned <= index + AHEAD:
            if self.wanted(self.planned):
                want.append(self.planned)
            self.planned += 1
        if not want or self._in is None:
            return
        try:
            self._in.write(b"".join(b"%d\n" % k for k in want))
            self._in.flush()
        except OSError:  # it died
            self.close()
            return
        self.queue.extend(want)

    def _drain(self, timeout: float) -> None:
        """Read what the helper wrote, waiting up to ``timeout`` s for something."""
        fd = self._out
        if not select.select([fd], [], [], max(0.0, timeout))[0]:
            return
        try:
            while chunk := os.read(fd, 1 << 20):
                self._buf += chunk
        except BlockingIOError:  # all there is for now
            pass
        else:  # end of its output: it died
            self.close()
            return
        while len(self._buf) >= _HEAD.size:
            k, n = _HEAD.unpack_from(self._buf)
            if len(self._buf) < _HEAD.size + n:
                break
            blob = bytes(self._buf[_HEAD.size : _HEAD.size + n])
            del self._buf[: _HEAD.size + n]
            while self.queue and self.queue[0] <= k:
                self.queue.popleft()
            if k >= self.taken_below:  # else made here already
                self.ready[k] = pickle.loads(blob)  # noqa: S301 - our own helper's output

    def _stop(self) -> None:
        proc, self.proc, self._in, self._out = self.proc, None, None, -1
        self.queue.clear()
        self.ready.clear()
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


def main(argv: list[str]) -> int:
    """The helper: an input number per line on stdin, the pickled entry on stdout, until EOF."""
    seed = int(argv[0])
    try:  # the decoder under test and the loop first: this one fills the time they leave
        os.nice(10)
    except OSError:
        pass
    out = sys.stdout.buffer
    for line in sys.stdin.buffer:
        index = int(line)
        blob = pickle.dumps(fresh_valid(seed, index), protocol=pickle.HIGHEST_PROTOCOL)
        try:
            out.write(_HEAD.pack(index, len(blob)) + blob)
            out.flush()
        except BrokenPipeError:  # the loop stopped
            return 0
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
