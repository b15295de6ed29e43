"""The hand-annotated bit vectors (tests/vectors/README.md): the assembler of their ``.bits``
text and the check of a decoder against their ``.expect.toml``.

``failing`` decodes with the ``decode`` this module imported when it was loaded: a driver that
applies a reference mutant first and then loads this file (``runpy.run_path``) checks the mutant."""

from __future__ import annotations

import re
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, RETAINED, SET, STATUS_NAMES, FapFrames
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


def check_vector(name: str, decoder: Callable[[bytes], FapFrames], exact_error: bool = True) -> None:
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
            check_vector(name, lambda data: decode(data).frames)
        except (AssertionError, Exception, pytest.fail.Exception):  # noqa: BLE001 - any failure counts
            bad.append(name)
            if first:
                break
    return bad
