"""A certificate says what it rests on, and verify says it in its one line: suites and goldens
that are not the ones this fbaconf ships (a hostile suite cut to one case certified "PASS (1
case)" and verified OK on a machine with the official suites), and a decoder that ran without
isolation (verify printed a plain OK for an --allow-unisolated certificate)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest

from fbaconf.certification import certify, package
from fbaconf.conformance import official
from fbaconf.isolation import sandbox


def fbaconf(*args, env=None, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, **(env or {})},
        cwd=cwd,
    )


@pytest.fixture(scope="module")
def one_case_package(tmp_path_factory):
    """``simple-l1-core`` cut to one case, its version string kept, in a suites folder of its own."""
    tmp = tmp_path_factory.mktemp("official")
    src = official.suites_folder() / "simple-l1-core"
    dst = tmp / "suites" / "simple-l1-core"
    shutil.copytree(src, dst)
    doc = json.loads((dst / "suite.json").read_text())
    doc["cases"] = doc["cases"][:1]
    (dst / "suite.json").write_text(json.dumps(doc, indent=1))
    r = fbaconf(
        "certify",
        "--decoder",
        "reference-inprocess",
        "--claim",
        "simple@1",
        "--no-speed",
        "-o",
        tmp / "pkg",
        env={"FBACONF_SUITES": str(tmp / "suites")},
    )
    return tmp / "pkg", r


def test_a_cut_suite_certifies_only_as_unofficial(one_case_package):
    pkg, r = one_case_package
    assert r.returncode == 0, r.stderr[-2000:]
    cert = json.loads((pkg / "certificate.json").read_text())
    assert cert["cases"] == 1 and cert["unofficial"]
    assert cert["unofficial"][0].startswith("suite simple-l1-core: not this fbaconf's")
    assert (pkg / "summary.txt").read_text().startswith("UNOFFICIAL SUITES")
    assert "- suites and goldens: UNOFFICIAL: suite simple-l1-core" in (pkg / "statement.md").read_text()
    assert "UNOFFICIAL SUITES" in r.stderr


def test_verify_on_a_machine_with_the_official_suites_refuses_it_or_says_unofficial(one_case_package):
    pkg, _r = one_case_package
    r = fbaconf("certify", "verify", pkg)  # no FBACONF_SUITES: this fbaconf's own suites
    assert r.returncode == 1 and r.stdout.startswith("certify verify: NOT VERIFIED"), r.stdout
    assert "UNOFFICIAL SUITES" in r.stdout and "simple@1: PASS" in r.stdout
    ok = fbaconf("certify", "verify", pkg, "--unofficial-ok")
    assert ok.returncode == 0 and "OK (" in ok.stdout and "UNOFFICIAL SUITES" in ok.stdout, ok.stdout


def test_the_official_suites_are_this_fbaconfs_whatever_the_environment_says(one_case_package, tmp_path):
    pkg, _r = one_case_package
    suites = json.loads((pkg / "certificate.json").read_text())["suites"]
    assert official.differences(suites, None)  # the cut suite is not ours
    ours = [
        {
            "name": "simple-l1-core",
            "sha256": package.hashlib.sha256(
                (official.suites_folder() / "simple-l1-core" / "suite.json").read_bytes()
            ).hexdigest(),
        }
    ]
    golden = (official.golden_folder() / "MANIFEST.json").read_bytes()
    assert official.differences(ours, golden) == []
    assert official.differences(ours, golden + b" ") == ["goldens: the golden manifest is not this fbaconf's"]
    assert official.differences([{"name": "../etc", "sha256": "x"}], None) == [
        "suite ../etc: not a suite this fbaconf ships"
    ]


def test_certify_records_that_the_decoder_ran_unisolated(tmp_path, monkeypatch):
    monkeypatch.setattr(sandbox, "isolation", lambda: "none")
    monkeypatch.setattr(certify, "preflight", lambda *a, **k: None)  # the canary would run unisolated too
    monkeypatch.setattr(
        certify,
        "select_cases",
        lambda suites, claim, *a, **k: [c for s in suites if s.name == "simple-l1-core" for c in s.cases[:2]],
    )
    certify.certify("reference", "simple@1", tmp_path / "pkg", speed=False, allow_unisolated=True, jobs=1)
    cert = json.loads((tmp_path / "pkg" / "certificate.json").read_text())
    assert cert["isolated"] is False and (tmp_path / "pkg" / "summary.txt").read_text().startswith("NOT ISOLATED")
    assert package.verify(tmp_path / "pkg").isolated is False


def test_verify_of_an_unisolated_certificate_exits_0_only_saying_so(certified_package):
    cert = json.loads((certified_package / "certificate.json").read_text())
    assert cert["isolated"] is True
    r = fbaconf("certify", "verify", certified_package)
    assert r.returncode == 0 and "UNISOLATED" not in r.stdout
    cert["isolated"] = False  # as certify --allow-unisolated writes it (above)
    (certified_package / "certificate.json").write_text(json.dumps(cert, indent=1) + "\n")
    package.seal(certified_package)
    r = fbaconf("certify", "verify", certified_package)
    assert r.returncode == 0 and r.stdout.startswith("certify verify: OK (") and "UNISOLATED" in r.stdout, r.stdout
