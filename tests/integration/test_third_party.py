"""Third-party implementations through fbaconf's adapters (docs/third-party.md); each test
skips cleanly when the implementation is not built (it is built outside the repository)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from fbaconf.conformance.suite import load_suites
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases


def _greta():
    m = os.environ.get("FBACONF_GRETA_MANIFEST")
    if not m or not Path(m).is_file():
        pytest.skip("Greta adapter not built (examples/third-party/greta/build.sh; set FBACONF_GRETA_MANIFEST)")
    return adapters.resolve(m)


def _cases(*ids):
    suites = load_suites(names=["simple-l1-core", "simple-l1-text"])
    return [c for s in suites for c in s.cases if c.id in ids]


def test_greta_results_are_the_documented_ones(tmp_path):
    a = _greta()
    cases = _cases("range-extremes", "arith-ntsc-rate", "no-frame-rate", "high-level-classes", "comments-crlf")
    res = {r.case_id.split("/")[-1]: r for r in run_cases(a, cases, claim="simple@1", out_dir=tmp_path,
                                                          jobs=2, progress=False)}
    assert res["range-extremes"].outcome == Outcome.PASS
    assert res["arith-ntsc-rate"].outcome == Outcome.FAIL and "got 25 Hz" in res["arith-ntsc-rate"].message
    assert res["no-frame-rate"].outcome == Outcome.FAIL and "got none" in res["no-frame-rate"].message
    assert res["high-level-classes"].outcome == Outcome.FAIL and "viseme" in res["high-level-classes"].message
    assert res["comments-crlf"].outcome == Outcome.FAIL and "rejected" in res["comments-crlf"].message


def test_xface_results_are_the_documented_ones(tmp_path):
    m = os.environ.get("FBACONF_XFACE_MANIFEST")
    if not m or not Path(m).is_file():
        pytest.skip("Xface adapter not built (examples/third-party/xface/build.sh; set FBACONF_XFACE_MANIFEST)")
    a = adapters.resolve(m)
    cases = _cases("range-extremes", "arith-ntsc-rate", "no-frame-rate", "arith-q1-all-faps", "timecode-past-a-minute",
                   "viseme-def", "fractional-value")
    res = {r.case_id.split("/")[-1]: r for r in run_cases(a, cases, claim="simple@1", out_dir=tmp_path,
                                                          jobs=2, progress=False)}
    assert res["range-extremes"].outcome == Outcome.PASS
    assert "got 29 Hz" in res["arith-ntsc-rate"].message  # frame rate kept in a short
    assert "got 0" in res["no-frame-rate"].message  # no keep semantics
    assert "raise_b_lip_lm" in res["arith-q1-all-faps"].message  # inner/outer lip coupling
    assert res["timecode-past-a-minute"].outcome == Outcome.CRASH  # frame number past the count
    assert "viseme_def" in res["viseme-def"].message  # read and dropped
    assert res["fractional-value"].outcome == Outcome.FAIL  # atof: an invalid file accepted
