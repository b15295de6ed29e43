"""``fuzz --self``'s ``slow`` class counts the parsers' CPU time, not wall time: on a loaded
machine a 0.2 s parse waiting 7 s for a core is no finding (a fresh ``--self`` run
reported two such inputs; replayed alone they took 0.03 s and 0.23 s of CPU)."""

from __future__ import annotations

import time

from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.selftarget import SelfTarget


def _target(work):
    t = SelfTarget(slow_s=0.15)
    t._stream = lambda inp, feats: work()  # the parser's place in execute()
    return t


def test_waiting_is_not_slow():
    assert _target(lambda: time.sleep(0.3)).execute(Entry(b"x")).verdict is None


def test_computing_is_slow():
    def busy():
        t0 = time.thread_time()
        while time.thread_time() - t0 < 0.3:
            pass

    v = _target(busy).execute(Entry(b"x")).verdict
    assert v is not None and v.cls == "slow" and "s of CPU (> 0.15 s)" in v.message
