"""Hand-annotated bit vectors (tests/vectors/README.md): streams and expected frames written by
hand from the spec notes, run against the reference decoder — independent of its goldens."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, STATUS_NAMES
from fbaconf.errors import BitstreamError

VECTORS = Path(__file__).resolve().parents[1] / "vectors"
NAMES = sorted(p.name[: -len(".bits")] for p in VECTORS.glob("*.bits"))


def assemble(text: str) -> bytes:
    """The bytes of an annotated .bits file (see tests/vectors/README.md)."""
    bits: list[str] = []
    for line in text.splitlines():
        for tok in line.split("#", 1)[0].split():
            if tok == "stuff":
                if len(bits) % 8 == 0:
                    bits += list("01111111")
                else:
                    bits.append("0")
                    bits += ["1"] * ((-len(bits)) % 8)
            elif tok.startswith("x:"):
                bits += list("".join(f"{b:08b}" for b in bytes.fromhex(tok[2:])))
            elif re.fullmatch(r"[01]+", tok):
                bits += list(tok)
            else:
                raise ValueError(f"bad token {tok!r}")
    assert len(bits) % 8 == 0, f"{len(bits)} bits: a vector must end on a byte boundary"
    return bytes(int("".join(bits[i : i + 8]), 2) for i in range(0, len(bits), 8))


def test_assembler():
    assert assemble("x:000001BA 1 01 stuff") == b"\x00\x00\x01\xba\xaf"  # 101, then 0 1111 (D1)
    assert assemble("10101010 stuff") == b"\xaa\x7f"  # aligned: the byte 0x7F


def test_there_are_vectors():
    assert len(NAMES) >= 8 and all((VECTORS / f"{n}.expect.toml").exists() for n in NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_vector(name):
    check_vector(name, lambda data: decode(data).frames)


def check_vector(name: str, decoder, exact_error: bool = True) -> None:
    """Run vector ``name`` through ``decoder`` (bytes -> FapFrames, raising on an invalid
    stream) and compare with its expectation; ``exact_error``: a BitstreamError with the
    expected rule and bit offset (the reference), else any exception (another decoder's own
    rule names)."""
    data = assemble((VECTORS / f"{name}.bits").read_text())
    want = tomllib.loads((VECTORS / f"{name}.expect.toml").read_text())
    if "error" in want:
        with pytest.raises(BitstreamError if exact_error else Exception) as ei:
            decoder(data)
        if exact_error:
            assert (ei.value.rule, ei.value.bit_offset) == (want["error"]["rule"], want["error"]["bit_offset"])
        return
    fr = decoder(data)
    assert len(fr) == want["stream"]["frames"]
    assert fr.frame_rate == pytest.approx(want["stream"]["frame_rate"], rel=1e-12)
    for i, w in enumerate(want["frame"]):
        got = {
            "frame_number": int(fr.frame_number[i]),
            "time_ms": float(fr.time_ms[i]),
            "is_intra": bool(fr.is_intra[i]),
            "fap_quant": int(fr.fap_quant[i]),
        }
        exp = {k: w[k] for k in got}
        assert got == pytest.approx(exp, rel=1e-9), f"frame {i}"
        for col, key in ((0, "fap1"), (1, "fap2")):
            if key in w:
                assert STATUS_NAMES[int(fr.status[i, col])] == w[key], f"frame {i} {key}"
        expected_status = np.full(68, FREE, np.uint8)
        expected_values = {}
        for table, status in (("set", SET), ("retained", RETAINED)):
            for fap, value in w.get(table, {}).items():
                expected_status[int(fap) - 1] = status
                expected_values[int(fap)] = value
        low = slice(2, 68)  # FAPs 3..68
        assert list(fr.status[i, low]) == list(expected_status[low]), f"frame {i}: statuses"
        for fap, value in expected_values.items():
            assert int(fr.values[i, fap - 1]) == value, f"frame {i}: FAP {fap}"
        for field, value in w.get("high", {}).items():
            assert int(fr.high[i, HIGH_LEVEL_FIELDS.index(field)]) == value, f"frame {i}: {field}"


def failing(names: list[str] | None = None, first: bool = False) -> list[str]:
    """The vectors (of ``names``, default all) the current reference decoder gets wrong (used under a
    mutant); ``first``: stop at the first."""
    bad = []
    for name in NAMES if names is None else names:
        try:
            test_vector(name)
        except (AssertionError, Exception, pytest.fail.Exception):  # noqa: BLE001 - any failure counts
            bad.append(name)
            if first:
                break
    return bad


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
        [sys.executable, "-c", DRIVER, str(Path(__file__).resolve()), json.dumps(jobs), "first" if first else "all"],
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
