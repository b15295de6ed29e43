"""Suite generation: determinism, error cases' diagnostics, regression.toml, the external suite."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.conformance import suite as suite_module
from fbaconf.conformance.golden import verify
from fbaconf.conformance.suite import load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.generators import suites as build
from fbaconf.profiles.checker import analyse

REAL = Path(__file__).resolve().parents[3] / "shared" / "data" / "fap"


def test_build_is_deterministic(tmp_path):
    """Two builds in one process give the same bytes (no state carried from one to the next; the
    committed suites, built in another process, are compared by test_every_suite_rebuilds_byte_for_byte)."""
    names = ["simple-l1-error", "predictable-l1-stress"]
    a = build.build(tmp_path / "a", names, log=lambda *_: None)
    b = build.build(tmp_path / "b", names, log=lambda *_: None)
    for sa, sb in zip(a, b):
        files = sorted(p.relative_to(sa.path) for p in sa.path.rglob("*") if p.is_file())
        assert files == sorted(p.relative_to(sb.path) for p in sb.path.rglob("*") if p.is_file())
        for rel in files:
            assert (sa.path / rel).read_bytes() == (sb.path / rel).read_bytes(), f"{sa.name}/{rel}"


def test_error_cases_carry_the_checker_codes():
    n = 0
    for s in load_suites():
        for c in s.cases:
            if c.kind != "error":
                continue
            if c.input_path("fba") is None:  # an invalid .fap text (players): the reader's rule
                with pytest.raises(FbaconfInputError) as ei:
                    read_fap_file(c.input_path("fap"))
                assert c.expect["diagnostics"] == [ei.value.rule], c.full_id
                continue
            scene = c.input_path("scene")  # a valid stream with an invalid scene
            codes = {d.code for d in analyse(c.input_path("fba").read_bytes(), scene=scene).diagnostics}
            assert set(c.expect["diagnostics"]) <= codes, (c.full_id, codes)
            n += 1
    assert n >= 15


# Stream cases without the .fap form (suites.toml text = false), each for its reason: the
# model-halving cases are 16,500 frames (~2.5 MB of text) and test the binary coder only.
NO_TEXT = {"simple-l1-stress/arith-model-rescale", "simple-l1-stress/arith-halving-random"}


def test_suite_groups_and_claims():
    suites = load_suites()
    groups = {(s.claim, s.group) for s in suites}
    for claim in ("simple@1", "calibration@1", "predictable@1"):
        assert (claim, "core") in groups
    for claim in ("simple@1", "simple@2", "calibration@1", "calibration@2", "predictable@1", "predictable@2"):
        assert (claim, "stress") in groups
    assert ("simple@1", "error") in groups
    for s in suites:
        assert s.name == f"{s.claim.split('@')[0]}-l{s.claim.split('@')[1]}-{s.group}"
        for c in s.cases:
            if c.kind == "decode" and c.inputs.get("fba") and c.full_id not in NO_TEXT:
                assert c.inputs.get("fap"), f"{c.full_id}: every stream case also comes as .fap text"
                # the coder corners that need predicted models skewed by 20-216 planes first are longer
                assert 1 <= c.frames <= 60 or c.id in ("lookahead-stuffing",) or c.id.startswith("coder-"), c.full_id


def test_regression_toml_is_merged(tmp_path):
    data = Path(suite_module.__file__).parent / "data"
    d = tmp_path / "data"
    shutil.copytree(data, d, ignore=shutil.ignore_patterns("regression*"))
    (d / "regression.toml").write_text(
        '[[suite]]\nname = "simple-l1-regression"\nclaim = "simple@1"\n'
        'group = "regression"\n\n[[case]]\nsuite = "simple-l1-regression"\n'
        'id = "fuzz-1"\ngenerator = "file"\nfile = "regression/x.fba"\nexpect = []\n'
    )
    s = build.spec(d)
    assert any(x["name"] == "simple-l1-regression" for x in s["suite"])
    assert s["case"][-1]["id"] == "fuzz-1"
    assert (
        len(s["case"])
        == len(build.spec()["case"])
        + (
            0
            if not (data / "regression.toml").is_file()
            else -len(__import__("tomllib").loads((data / "regression.toml").read_text()).get("case", []))
        )
        + 1
    )


def test_external_suite_skips_cleanly_without_files(tmp_path):
    assert build.build_external(tmp_path / "nothing", tmp_path / "out", log=lambda *_: None) is None


@pytest.mark.skipif(not REAL.is_dir(), reason="../shared/data/fap not present (optional external suite)")
def test_external_suite_from_real_files(tmp_path):
    src = tmp_path / "src"
    (src / "vreng").mkdir(parents=True)
    shutil.copy(REAL / "vreng" / "joy.fap", src / "vreng" / "joy.fap")
    s = build.build_external(src, tmp_path / "out", log=lambda *_: None)
    assert s is not None and s.group == "real" and len(s.cases) >= 4
    (raw,) = [c for c in s.cases if c.group == "text"]  # the file itself, kept as the case input
    assert raw.input_path("fap").read_bytes() == (REAL / "vreng" / "joy.fap").read_bytes()
    assert raw.input_path("fba") is None
    man = json.loads((tmp_path / "out" / "golden" / "MANIFEST.json").read_text())
    assert any(k.startswith(build.EXTERNAL_SUITE + "/") for k in man["files"])
    # nothing lands in the repository
    assert not (Path(suite_module.__file__).parent / "suites" / build.EXTERNAL_SUITE).exists()


def test_every_suite_rebuilds_byte_for_byte(tmp_path):
    """`fbaconf suites build` (the README's first command) leaves the tree as committed: every
    file of every suite is rebuilt identically (fixed seeds, the bundled models from committed
    data, generated geometry at 6 decimals)."""
    built = build.build(tmp_path, None, log=lambda *_: None)
    committed = {s.name: s for s in load_suites()}
    assert sorted(s.name for s in built) == sorted(committed)
    for s in built:
        mine = sorted(p.relative_to(s.path) for p in s.path.rglob("*") if p.is_file())
        theirs = sorted(p.relative_to(committed[s.name].path) for p in committed[s.name].path.rglob("*") if p.is_file())
        assert mine == theirs, s.name
        for rel in mine:
            assert (s.path / rel).read_bytes() == (committed[s.name].path / rel).read_bytes(), f"{s.name}/{rel}"


SUITE_NAMES = [s.name for s in load_suites()]


@pytest.mark.parametrize("suite", SUITE_NAMES)
def test_goldens_regenerate_byte_for_byte(suite):
    """Every golden is what the reference makes of its case, byte for byte (one test per suite, so
    the workers share the work; each also checks every golden's and suite's digest)."""
    assert verify(only=[suite], log=lambda *_: None) == []


def test_the_golden_manifest_names_every_suite_regenerated_above():
    manifest = json.loads((suite_module.golden_root() / "MANIFEST.json").read_text())
    assert sorted(manifest["suites"]) == sorted(SUITE_NAMES)
