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

import pickle
import random
import sys
from collections.abc import Callable

from fbaconf.harness.sysinfo import usable_cpus

from .choosers import RandomChooser
from .helper import Ahead, serve
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


class FreshStreams(Ahead):
    """Input ``index``'s fresh valid stream (:meth:`take`): the helper's when it made it in time,
    else made here. ``wanted(i)`` says whether input ``i`` will be one. The helper (``helper``)
    starts at the first :meth:`take` and stops at :meth:`close`."""

    def __init__(self, seed: int, wanted: Callable[[int], bool], helper: bool) -> None:
        super().__init__("fbaconf.fuzz.fresh", [str(seed)], helper)
        self.seed = seed
        self.wanted = wanted
        self.planned = 0  # inputs below this one were looked at

    def take(self, index: int) -> Entry:
        if self._running():
            self._ask(index)
        e = self._take(index)
        return e if e is not None else fresh_valid(self.seed, index)

    def _ask(self, index: int) -> None:
        """Ask for the fresh streams up to :data:`AHEAD` inputs past ``index``."""
        self.planned = max(self.planned, index)
        want = []
        while self.planned <= index + AHEAD:
            if self.wanted(self.planned):
                want.append(self.planned)
            self.planned += 1
        if want:
            self._send(want, [b""] * len(want))

    def _decode(self, payload: bytes) -> Entry:
        return pickle.loads(payload)  # noqa: S301 - our own helper's output


def main(argv: list[str]) -> int:
    """The helper: input numbers in, their pickled entries out, until the loop closes its end."""
    seed = int(argv[0])
    return serve(lambda index, _: pickle.dumps(fresh_valid(seed, index), protocol=pickle.HIGHEST_PROTOCOL))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
