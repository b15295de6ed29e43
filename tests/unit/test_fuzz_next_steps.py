"""``fbaconf fuzz --promote`` says what to do next: build the regression suite with
its goldens, run the decoder on it, commit the files — each named as a user types it."""

from __future__ import annotations

import argparse
import json

from fbaconf.fuzz.cli import _after_promotion


def test_promote_names_the_next_commands(tmp_path):
    f = tmp_path / "fz" / "findings" / "crash-1a2b"
    f.mkdir(parents=True)
    (f / "finding.json").write_text(json.dumps({"decoder": {"name": "acme", "manifest": "/src/acme/ci/acme.toml"}}))
    args = argparse.Namespace(promote=tmp_path / "fz", data_dir=None)
    assert _after_promotion([{"id": "crash-1a2b"}], args) == [
        "next:",
        "  1. fbaconf suites build simple-l1-regression --goldens   # the new case(s) join the suite, with goldens",
        "  2. fbaconf run --decoder /src/acme/ci/acme.toml --suite simple-l1-regression"
        "   # fails on them until the decoder is fixed",
        "  3. commit conformance/data/regression.toml, conformance/data/regression/, "
        "conformance/suites/simple-l1-regression/ and golden/",
    ]
    args = argparse.Namespace(promote=tmp_path / "fz", data_dir="/tmp/mine")
    lines = _after_promotion([{"id": "crash-1a2b"}], args)
    assert lines[1].startswith("  (the cases went to /tmp/mine; `suites build` reads the package's conformance/data")
    assert lines[-1].startswith("  3. commit /tmp/mine/regression.toml")
    assert _after_promotion([], args) == [
        "nothing new: every finding is already a regression case (or none is a stream)"
    ]


def test_the_scene_seeds_hold_the_face_family_of_the_suites():
    """The seed scenes are the suites' own small BT scenes (FDP feature points, FIT, a FaceDefTables
    grid), not generator output: a generator call that failed was swallowed and no promised scene was
    ever added."""
    from fbaconf.fuzz.corpus import scene_seeds  # noqa: PLC0415 (this test only)

    seeds = scene_seeds()
    texts = [e.data.decode("utf-8", "replace") for e in seeds if e.origin.startswith("seed:")]
    assert any("featurePointsCoord" in t for t in texts) and any("FIT" in t for t in texts)
    assert any("FaceDefTables" in t for t in texts)
    assert all(e.kind == "scene" for e in seeds)
