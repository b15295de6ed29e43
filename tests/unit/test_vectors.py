"""Hand-annotated bit vectors (tests/vectors/README.md): streams and expected frames written by
hand from the spec notes, run against the reference decoder — independent of its goldens. That
each vector fails when the rule it was written for is broken: tests/suites/test_vector_mutants.py."""

from __future__ import annotations

import pytest

from fbaconf.bitstreams.decoder import decode

from lib.vectors import NAMES, VECTORS, assemble, check_vector


def test_assembler():
    assert assemble("x:000001BA 1 01 stuff") == b"\x00\x00\x01\xba\xaf"  # 101, then 0 1111 (D1)
    assert assemble("10101010 stuff") == b"\xaa\x7f"  # aligned: the byte 0x7F


def test_there_are_vectors():
    assert len(NAMES) >= 8 and all((VECTORS / f"{n}.expect.toml").exists() for n in NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_vector(name):
    check_vector(name, lambda data: decode(data).frames)
