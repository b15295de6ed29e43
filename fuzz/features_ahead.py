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

import sys

from .helper import Ahead, serve
from .model import features_of

SEP = b"\n"


class FeaturesAhead(Ahead):
    """Features of inputs asked for (:meth:`ask`) when they are made, taken (:meth:`take`) when
    they are recorded. ``helper``: whether to start the helper at the first :meth:`ask`."""

    def __init__(self, helper: bool) -> None:
        super().__init__("fbaconf.fuzz.features_ahead", [], helper)
        self.from_helper = 0  # inputs whose features came from the helper

    def ask(self, index: int, data: bytes) -> None:
        if self._running():
            self._send([index], [data])

    def take(self, index: int, data: bytes) -> set[str]:
        """``data``'s features (input ``index``): the helper's answer, else parsed here."""
        feats = self._take(index)
        if feats is None:
            return features_of(data)
        self.from_helper += 1
        return feats

    def _decode(self, payload: bytes) -> set[str]:
        return {f.decode() for f in payload.split(SEP) if f}


def main() -> int:
    """The helper: inputs in, their features out (one per line), until the loop closes its end."""
    return serve(lambda _index, data: SEP.join(f.encode() for f in sorted(features_of(data))))


if __name__ == "__main__":
    sys.exit(main())
