"""Fresh valid streams, made ahead of the fuzzing loop by a helper process.

An input is a pure function of the run's seed and its index (:func:`input_rng`), and whether input
``i`` is a fresh valid stream is that generator's first draw: the loop knows which of the coming
inputs are before it reaches them. Encoding one takes the reference encoder 3-6 ms, against well
under a millisecond to make and judge any other input, so at a 4 % share they took a sixth of the
loop's time while the second CPU waited on a decoder that needs microseconds. A helper
process (``python -m fbaconf.fuzz.fresh SEED``, :mod:`.helper`: input numbers in, pickled entries
out) encodes them there; the stream it hands back is the one the loop would have made from the
same generator state, so a run replays input for input with or without it, and whatever goes wrong
with the helper (no process, a crash, stuck, behind) leaves the loop to make the stream itself."""

from __future__ import annotations

import collections
import pickle
import random
import sys
import time
from collections.abc import Callable

from fbaconf.harness.sysinfo import usable_cpus

from .choosers import RandomChooser
from .helper import STUCK_S, Helper, record, serve
from .inputs import Entry, gen_valid

# how many inputs ahead the helper is asked: at a 4 % share about ten streams, 30-60 ms of encoding
AHEAD = 256
# a helper costs a process start (~0.5 s of CPU importing the encoder, while the first streams are
# made in the loop anyway): a run of fewer inputs (some 60 fresh streams) makes its own
MIN_EXECS = 1500


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
        self._helper = Helper("fbaconf.fuzz.fresh", [str(seed)])
        self.queue: collections.deque[int] = collections.deque()  # asked, not answered yet, in order
        self.ready: dict[int, Entry] = {}  # answered, not taken yet
        self.planned = 0  # inputs below this one were looked at
        self.taken_below = 0  # the loop is past every input below this one

    @property
    def proc(self):
        """The helper's process while it runs, else None."""
        return self._helper.proc

    def take(self, index: int) -> Entry:
        if self.helper and not self._helper.alive and not self._helper.start():
            self.helper = False
        if self._helper.alive:
            self._ask(index)
            self._drain(0.0)
            end = time.monotonic() + STUCK_S
            while self._helper.alive and index not in self.ready and self.queue and self.queue[0] == index:
                if time.monotonic() >= end:  # the one it is making: stuck
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
    def _ask(self, index: int) -> None:
        self.planned = max(self.planned, index)
        want = []
        while self.planned <= index + AHEAD:
            if self.wanted(self.planned):
                want.append(self.planned)
            self.planned += 1
        if not want:
            return
        if not self._helper.send(b"".join(record(k) for k in want)):
            self.close()
            return
        self.queue.extend(want)

    def _drain(self, timeout: float) -> None:
        """Read what the helper wrote, waiting up to ``timeout`` s for something."""
        got = self._helper.drain(timeout)
        if not self._helper.alive:
            self.close()
            return
        for k, blob in got:
            while self.queue and self.queue[0] <= k:
                self.queue.popleft()
            if k >= self.taken_below:  # else made here already
                self.ready[k] = pickle.loads(blob)  # noqa: S301 - our own helper's output

    def _stop(self) -> None:
        self._helper.stop()
        self.queue.clear()
        self.ready.clear()


def main(argv: list[str]) -> int:
    """The helper: input numbers in, their pickled entries out, until the loop closes its end."""
    seed = int(argv[0])
    return serve(lambda index, _: pickle.dumps(fresh_valid(seed, index), protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
