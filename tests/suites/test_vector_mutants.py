"""The hand-annotated vectors kill the reference mutants of the rules they were written for:
each mutant applied in a forked child of its own (mutation/own.py), the vectors checked under it."""

from __future__ import annotations

import json
import re
import subprocess
import sys

from lib import vectors
from lib.vectors import NAMES, failing

# Reference mutants (mutation/own.py) the vectors must kill: each breaks one rule a vector
# was written for. Not killed by these vectors: stuffing-not-removed (no vector has a stuffing
# bit inside a block where that mutant's rewind does not compensate it; the suite's
# lookahead-stuffing case kills it).
KILLED = [
    "dequant-step-index",
    "dequant-quant-plus-one",
    "prediction-sign",
    "intra-symbol-offset",
    "alphabet-floor-division",
    "predicted-alphabet-from-intra-range",
    "ignore-retained",
    "mask-type-2-as-1",
    "mask-bits-reversed",
    "minmax-marker-skipped",
    "minmax-lists-ignored",
    "minmax-sign-swapped",
    "intensity-not-scaled",
    "expression-field-order",
    "init-face-def-swapped",
    "skip-not-counted",
    "skip-chain-not-continued",
    "time-code-ignored",
    "time-code-minutes-as-seconds",
    "default-rate-30",
    "skip-not-in-time",
    "frequency-offset-ignored",
    "viseme-prediction-sign",
    "non-adaptive-model",
    "wrong-rewind",
    "ind-cod-d7-rewind-14-stream-bits",
    "ind-cod-d7-lookahead-stuffing-error",
]


# The coder corner vectors (tests/vectors/make_coder_corners.py): each kills the mutant of the
# decoder rule it was made for — a tie taken the other way, a look-ahead position mishandled.
TIE_MUTANTS = {
    "high-q2": "ind-cod-renorm-high-le-q2",
    "low-q2": "ind-cod-renorm-low-gt-q2",
    "low-q1": "ind-cod-renorm-middle-low-gt-q1",
    "high-q3": "ind-cod-renorm-middle-high-le-q3",
}


def corner_mutant(name: str) -> str:
    tie = re.fullmatch(r"c\d\d-coder-tie-(.+)", name)
    if tie:
        return TIE_MUTANTS[tie.group(1)]
    rule, pos = re.fullmatch(r"c\d\d-coder-lookahead-(rewind|error)-(\d\d)", name).groups()
    return f"lookahead-{rule}-at-{int(pos)}"


CORNERS = [n for n in NAMES if "-coder-" in n]


def test_there_are_corner_vectors_for_every_tie_and_position():
    assert len(CORNERS) == 4 + 2 * 14
    assert sorted({corner_mutant(n) for n in CORNERS}) == sorted(
        list(TIE_MUTANTS.values()) + [f"lookahead-{r}-at-{p}" for r in ("rewind", "error") for p in range(1, 15)]
    )


# Under a mutant, in a process of its own: one driver process imports fbaconf and the mutants once,
# then forks a child per mutant (two at a time) that applies it, loads this file (after the mutant,
# so this module's own ``decode`` is the mutated one) and reports the vectors that fail as JSON —
# the same state as a fresh interpreter per mutant, without paying the imports 59 times.
DRIVER = """
import json, os, runpy, signal, sys
from fbaconf.mutation.own import apply
test_file, jobs, first = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3] == "first"
results, running = {}, {}

def reap():
    pid, _status = os.wait()
    mutant, r = running.pop(pid)
    with os.fdopen(r) as f:
        text = f.read()
    results[mutant] = json.loads(text) if text else None  # None: the child died before reporting

for mutant, names in jobs:
    if len(running) == 2:
        reap()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        signal.alarm(120)  # a mutant that hangs the decoder dies here, and reports nothing
        try:
            apply(mutant)
            out = json.dumps(runpy.run_path(test_file)["failing"](names, first))
        except BaseException as e:
            out = json.dumps({"error": repr(e)})
        os.write(w, out.encode())
        os._exit(0)
    os.close(w)
    running[pid] = (mutant, r)
while running:
    reap()
print(json.dumps(results))
"""


def failing_under(jobs: list[tuple[str, list[str] | None]], first: bool = False) -> dict[str, list[str] | None]:
    """{mutant: the vectors of its ``names`` (None: all) that fail under it (``first``: the first
    only)} for each (mutant, names)."""
    r = subprocess.run(
        [sys.executable, "-c", DRIVER, vectors.__file__, json.dumps(jobs), "first" if first else "all"],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-1500:]
    out = json.loads(r.stdout.strip().splitlines()[-1])
    assert not [m for m, v in out.items() if not isinstance(v, list)], out  # every child reported its vectors
    return out


def test_each_corner_vector_kills_its_mutant():
    """Under its mutant the corner vector fails; the reference passes it."""
    assert failing(CORNERS) == []
    out = failing_under([(corner_mutant(n), [n]) for n in CORNERS])
    assert len(out) == len(CORNERS)
    survived = [n for n in CORNERS if out[corner_mutant(n)] != [n]]
    assert survived == []


def test_each_vector_fails_when_its_rule_is_broken():
    """Every listed mutant of the reference (one rule broken, in a process of its own) fails
    at least one vector; the unmutated reference fails none."""
    assert failing() == []
    out = failing_under([(m, None) for m in KILLED], first=True)  # one failing vector kills a mutant
    survived = [m for m in KILLED if not out[m]]
    assert survived == []
