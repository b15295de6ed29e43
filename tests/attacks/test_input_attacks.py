"""Inputs a user hands the harness: a suite manifest, a file to check, a scene to
animate. Each bad one is one clear error naming the file and the rule — never a traceback, a
hang or a MemoryError."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.conformance.suite import Suite, SuiteError

from lib.hangs import finishes

BASE = {
    "format": "fbaconf.suite/1",
    "name": "s",
    "claim": "simple@1",
    "cases": [{"id": "c1", "claim": "simple@1", "kind": "decode", "inputs": {"fba": "x.fba"}, "sha256": {}}],
}


def _variant(change) -> str:
    d = json.loads(json.dumps(BASE))
    change(d)
    return json.dumps(d)


BAD_SUITES = {
    "deep JSON": "[" * 100_000 + "]" * 100_000,
    "deep inside a case": _variant(lambda d: d["cases"][0].__setitem__("expect", json.loads("[" * 60 + "]" * 60))),
    "a bogus suite claim": _variant(lambda d: d.__setitem__("claim", "bogus@99")),
    "a bogus case claim": _variant(lambda d: d["cases"][0].__setitem__("claim", "simple")),
    "inputs as a list": _variant(lambda d: d["cases"][0].__setitem__("inputs", ["x.fba"])),
    "an input not a name": _variant(lambda d: d["cases"][0].__setitem__("inputs", {"fba": 7})),
    "sha256 as a list": _variant(lambda d: d["cases"][0].__setitem__("sha256", ["x"])),
    "an id not a string": _variant(lambda d: d["cases"][0].__setitem__("id", 5)),
    "frames not a number": _variant(lambda d: d["cases"][0].__setitem__("frames", "30")),
    "tolerances not a table": _variant(lambda d: d["cases"][0].__setitem__("tolerances", 3)),
    "not UTF-8": "\udcff",
}


@pytest.mark.parametrize("name", list(BAD_SUITES))
def test_a_malformed_suite_is_one_clear_error(tmp_path, name):
    d = tmp_path / "s"
    d.mkdir()
    (d / "suite.json").write_bytes(BAD_SUITES[name].encode("utf-8", "surrogateescape"))
    with pytest.raises(SuiteError) as ei:
        Suite.load(d)
    assert str(d / "suite.json") in str(ei.value) and ei.value.rule.startswith("suite-"), ei.value


def test_a_malformed_suite_stops_a_run_with_its_error_not_a_traceback(tmp_path):
    (tmp_path / "s").mkdir()
    (tmp_path / "s" / "suite.json").write_text(BAD_SUITES["inputs as a list"])
    r = subprocess.run(
        [sys.executable, "-m", "fbaconf", "run", "--decoder", "reference", "-o", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "FBACONF_SUITES": str(tmp_path)},
    )
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "inputs must be a table" in r.stderr, r.stderr


def test_a_suite_manifest_that_is_a_fifo_is_refused_without_blocking(tmp_path):
    (tmp_path / "s").mkdir()
    os.mkfifo(tmp_path / "s" / "suite.json")
    with pytest.raises(SuiteError, match="FIFO"):
        finishes(lambda: Suite.load(tmp_path / "s"), "loading a suite whose manifest is a FIFO")


def test_check_refuses_a_fifo_before_opening_it(tmp_path):
    """Before: `fbaconf check` on a FIFO blocked for ever."""
    fifo = tmp_path / "stream.fba"
    os.mkfifo(fifo)
    for args in (["check", str(fifo)], ["check", "--json", str(fifo)]):
        r = subprocess.run([sys.executable, "-m", "fbaconf", *args], capture_output=True, text=True, timeout=60)
        assert r.returncode == 2 and "FIFO, not a regular file" in r.stdout + r.stderr, r
        assert "Traceback" not in r.stderr


def test_animate_on_a_scene_with_a_huge_token_is_an_error_not_a_memory_error(tmp_path):
    """Before: a 1 GB token was copied into the error message: MemoryError."""
    faps = Path(__file__).resolve().parents[2] / "conformance" / "suites" / "simple-l1-core" / "dct-q4.fap"
    huge = tmp_path / "huge.bt"
    with open(huge, "wb") as f:  # 1 GB (sparse): refused by its size before it is read
        f.write(b"Face { fdp FDP { featurePointsCoord ")
        f.truncate(1 << 30)
    token = tmp_path / "token.bt"
    token.write_bytes(b"Face { fdp " + b"x" * (3 << 20) + b" }\n")  # a 3 MB token in a small file
    for scene, words in (
        (huge, "over the 67108864 byte limit [rule bt-file]"),
        (token, "a token of 3145728 characters ('xxxxxxxx"),
    ):
        r = subprocess.run(
            [
                sys.executable,
                "-m",
                "fbaconf",
                "animate",
                "--scene",
                str(scene),
                "--faps",
                str(faps),
                "-o",
                str(tmp_path / "out.npz"),
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 2 and words in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and "MemoryError" not in r.stderr and len(r.stderr) < 1000
