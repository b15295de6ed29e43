"""The syntax-model coverage of inputs, measured ahead of the fuzzing loop by a helper process.

The coverage of an input that the oracle did not decode costs a reference parse (0.2-1.5 ms in
Python: a fifth of a persistent run's time at one input in eight, py-spy). An
input's features are a pure function of its bytes, known once the input is made: the loop asks
the helper (``python -m fbaconf.fuzz.features_ahead``, :mod:`.helper`) then, the decoder runs the
input and the inputs queued before it meanwhile, and the answer is usually there when the input is
recorded. A dead, stuck or absent helper, or one behind on inputs asked before, leaves the loop to
parse the input itself, the same features: coverage, the corpus and so the run are the same with
or without it."""

from __future__ import annotations

import collections
import sys
import time

from .helper import STUCK_S, Helper, record, serve
from .model import features_of

SEP = b"\n"


class FeaturesAhead:
    """Features of inputs asked for (:meth:`ask`) when they are made, taken (:meth:`take`) when
    they are recorded. ``helper``: whether to start the helper at the first :meth:`ask`."""

    def __init__(self, helper: bool) -> None:
        self.helper = helper
        self._helper = Helper("fbaconf.fuzz.features_ahead", [])
        self.queue: collections.deque[int] = collections.deque()  # asked, not answered yet, in order
        self.ready: dict[int, set[str]] = {}
        self.from_helper = 0  # inputs whose features came from the helper

    @property
    def proc(self):
        return self._helper.proc

    def ask(self, index: int, data: bytes) -> None:
        if self.helper and not self._helper.alive and not self._helper.start():
            self.helper = False
        if self._helper.alive and self._helper.send(record(index, data)):
            self.queue.append(index)
        elif self.helper:
            self.close()

    def take(self, index: int, data: bytes) -> set[str]:
        """``data``'s features (input ``index``): the helper's answer, else parsed here."""
        while self.queue and self.queue[0] < index:
            self.queue.popleft()  # asked, not wanted after all (the oracle's parse gave them)
        if self._helper.alive and index not in self.ready:
            self._drain(0.0)
            end = time.monotonic() + STUCK_S
            while self._helper.alive and index not in self.ready and self.queue and self.queue[0] == index:
                if time.monotonic() >= end:  # the one it is parsing: stuck
                    break
                self._drain(end - time.monotonic())
        feats = self.ready.pop(index, None)
        for k in [k for k in self.ready if k < index]:  # never taken: recorded otherwise
            del self.ready[k]
        while self.queue and self.queue[0] <= index:
            self.queue.popleft()  # answered later, if at all: parsed here by then
        if feats is None:
            return features_of(data)
        self.from_helper += 1
        return feats

    def close(self) -> None:
        self.helper = False
        self._helper.stop()
        self.queue.clear()
        self.ready.clear()

    def _drain(self, timeout: float) -> None:
        got = self._helper.drain(timeout)
        if not self._helper.alive:
            self.close()
            return
        for k, payload in got:
            if self.queue and k >= self.queue[0]:  # else taken (parsed here) already
                self.ready[k] = {f.decode() for f in payload.split(SEP) if f}
            while self.queue and self.queue[0] <= k:
                self.queue.popleft()


def main() -> int:
    """The helper: inputs in, their features out (one per line), until the loop closes its end."""
    return serve(lambda _index, data: SEP.join(f.encode() for f in sorted(features_of(data))))


if __name__ == "__main__":
    sys.exit(main())
