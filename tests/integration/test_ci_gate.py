"""The CI gate laid out as the GitHub Actions example has it (docs/harness.md, "Gating a
project's CI"): fbaconf checked out at ``./fbaconf`` beside the project's own tests, the decoder
(here a script) in a folder of its own with its manifest, the baseline beside them in ``ci/``.
``pytest --fbaconf-decoder`` from the repository root collects the conformance cases only (not
fbaconf's tests, whose conftest needs hypothesis, nor the project's), honours the baseline
(known failure xfail, fixed and new ones fail and are named first, flakes retried), and stops at
once on a malformed baseline; ``fbaconf run`` records required NotSupported cases and keeps
hand-written lines.

The decoder is the reference behind a script with planted bugs switched by ``[env] BUG``:
A changes a FAP of ``arith-q1-all-faps``, B one of ``arith-q31-timecodes`` (both cases rest on
public facts only, so their failures are never provisional differences)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fbaconf.harness.adapters import resolve
from fbaconf.harness.preflight import preflight
from fbaconf.harness.usage import UsageError

CASES = ["arith-q1-all-faps", "timecode-past-a-minute"]
DECODER = """\
import os, sys
from fbaconf.reference.pipeline import reference_outputs
reference_outputs(sys.argv[1], faps_out=sys.argv[2])
bugs, name = os.environ.get("BUG", ""), os.path.basename(sys.argv[1])
count = os.environ.get("COUNT")
if count:  # flaky: fails every other run (a counter outside the sandbox: FBACONF_SANDBOX=none)
    n = int(open(count).read()) if os.path.exists(count) else 0
    open(count, "w").write(str(n + 1))
    bugs += "A" if n % 2 == 0 else ""
if ("A" in bugs and "q1-all-faps" in name) or ("B" in bugs and "q31-timecodes" in name):
    lines = open(sys.argv[2]).read().splitlines()
    t = lines[2].split()
    t[1] = str(int(t[1]) + 1)
    lines[2] = " ".join(t)
    open(sys.argv[2], "w").write(chr(10).join(lines) + chr(10))
"""


def make_repo(tmp_path: Path) -> Path:
    repo = tmp_path / "acme"
    # an fbaconf checkout beside the tests: its own pytest configuration and a conftest needing a missing module
    (repo / "fbaconf" / "tests").mkdir(parents=True)
    (repo / "fbaconf" / "pyproject.toml").write_text(
        '[tool.pytest.ini_options]\ntestpaths = ["tests"]\naddopts = "-p no:nothing-like-this"\n'
    )
    (repo / "fbaconf" / "tests" / "conftest.py").write_text("import hypothesis_is_not_installed_here\n")
    (repo / "fbaconf" / "tests" / "test_own.py").write_text("def test_fbaconfs_own():\n    assert False\n")
    (repo / "tests").mkdir()
    (repo / "tests" / "test_mine.py").write_text("def test_the_projects_own():\n    assert False\n")
    (repo / "ci").mkdir()
    (repo / "ci" / "acme.py").write_text(DECODER)  # a script: the sandbox shows it the manifest's folder
    set_bugs(repo, "A")
    return repo


def set_bugs(repo: Path, bugs: str, extra_env: str = "") -> None:
    (repo / "ci" / "acme.toml").write_text(
        textwrap.dedent(f"""\
        name = "acme"
        claims = ["simple@1"]
        inputs = ["fba"]
        outputs = ["faps"]
        faps_format = "fap"
        [commands]
        decode = ["{{python}}", "{{manifest_dir}}/acme.py", "{{input}}", "{{faps_out}}"]
        [env]
        BUG = "{bugs}"
        {extra_env}
        [limits]
        timeout_s = 30
        """)
    )


def pytest_in(repo: Path, *args, env=None):
    # -P: the checkout at ./fbaconf must not shadow the installed package (as `.venv/bin/pytest` runs it)
    # no hypothesis plugin: a decoder project's CI has none (and it costs seconds to load)
    cmd = [
        sys.executable,
        "-P",
        "-m",
        "pytest",
        "-p",
        "no:cacheprovider",
        "-p",
        "no:hypothesispytest",
        "--fbaconf-decoder",
        "ci/acme.toml",
        "--fbaconf-suite",
        "simple-l1-core",
        *args,
    ]
    return subprocess.run(cmd, cwd=repo, capture_output=True, text=True, timeout=600, env={**os.environ, **(env or {})})


def k_cases():
    return ["-k", " or ".join(CASES)]


@pytest.fixture(scope="module")
def repo(tmp_path_factory) -> Path:
    r = make_repo(tmp_path_factory.mktemp("gate"))
    (r / "ci" / "baseline.txt").write_text("# acme\nsimple-l1-core/arith-q1-all-faps,Fail,faps:3  # ticket ACME-12\n")
    return r


def test_pytest_collects_only_the_conformance_cases_and_honours_the_baseline(repo):
    r = pytest_in(repo, "--fbaconf-baseline", "ci/baseline.txt", "-rx", *k_cases())
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    assert f"rootdir: {repo}\n" in out and "hypothesis_is_not_installed_here" not in out
    assert "test_fbaconfs_own" not in out and "test_the_projects_own" not in out
    assert "1 passed" in out and "1 xfailed" in out
    assert "known failure (baseline: simple-l1-core/arith-q1-all-faps,Fail,faps:3)" in out
    assert "fbaconf: 0 new, 1 known, 0 fixed, 0 flaky" in out


def test_pasted_node_ids_are_cases_not_the_fbaconf_folder(repo):
    r = pytest_in(repo, "--fbaconf-baseline", "ci/baseline.txt", "fbaconf::simple-l1-core/arith-q1-all-faps")
    out = r.stdout + r.stderr
    assert r.returncode == 0, out
    assert "collected 1 item" in out and f"rootdir: {repo}\n" in out and "hypothesis_is_not_installed_here" not in out


def test_node_ids_of_a_decoder_elsewhere_paste_back_from_the_repository_root(repo, tmp_path):
    """pytest takes every argument naming a file for a path, the manifest after --fbaconf-decoder
    too: a manifest outside the repository made its folder the rootdir, and the summary printed
    ``../../that/folder/fbaconf::suite/case``, which does not run when pasted."""
    elsewhere = tmp_path / "decoders"
    elsewhere.mkdir()
    for name in ("acme.toml", "acme.py"):
        (elsewhere / name).write_text((repo / "ci" / name).read_text())
    cmd = [
        sys.executable,
        "-P",
        "-m",
        "pytest",
        "-p",
        "no:cacheprovider",
        "-p",
        "no:hypothesispytest",
        "--fbaconf-decoder",
        str(elsewhere / "acme.toml"),
        "--fbaconf-suite",
        "simple-l1-core",
        "-rf",
    ]
    r = subprocess.run(cmd + ["-k", "arith-q1-all-faps"], cwd=repo, capture_output=True, text=True, timeout=600)
    failed = [line.split()[1] for line in r.stdout.splitlines() if line.startswith("FAILED ")]
    assert failed == ["fbaconf::simple-l1-core/arith-q1-all-faps"], r.stdout[-2000:]
    again = subprocess.run(cmd + failed, cwd=repo, capture_output=True, text=True, timeout=600)
    assert "collected 1 item" in again.stdout and "1 failed" in again.stdout, again.stdout[-2000:]


def test_a_fixed_case_and_a_new_bug_fail_and_are_named_first(repo, tmp_path):
    set_bugs(repo, "B")  # bug A fixed, bug B new
    try:
        both = ["fbaconf::simple-l1-core/arith-q1-all-faps", "fbaconf::simple-l1-core/arith-q31-timecodes"]
        r = pytest_in(
            repo,
            "--fbaconf-baseline",
            "ci/baseline.txt",
            "--fbaconf-keep-workdirs",
            "--fbaconf-out",
            str(tmp_path / "out"),
            "--junitxml",
            str(tmp_path / "junit.xml"),
            *both,
        )
        out = r.stdout
        assert r.returncode == 1 and "fbaconf: 1 new, 0 known, 1 fixed, 0 flaky" in out, out
        junit = (tmp_path / "junit.xml").read_text()
        assert '<property name="baseline" value="1 new, 0 known, 1 fixed, 0 flaky"' in junit
        assert (
            out.index("NEW    fbaconf::simple-l1-core/arith-q31-timecodes")
            < out.index("FIXED  fbaconf::simple-l1-core/arith-q1-all-faps")
            < out.index("= FAILURES =")
        )
        assert "lists it as Fail,faps:3: remove its line (or --fbaconf-allow-fixed)" in out
        assert "first difference: frame 0, FAP" in out and "{'" not in out  # words, no Python repr
        # the kept case folder is named as it is: the line reruns the decoder as printed
        line = next(ln for ln in out.splitlines() if ln.startswith("reproduce: "))
        assert "<case folder>" not in line and Path(line.split()[3]).is_file(), line
        assert (
            pytest_in(repo, "--fbaconf-baseline", "ci/baseline.txt", "--fbaconf-allow-fixed", both[0]).returncode == 0
        )
    finally:
        set_bugs(repo, "A")


def test_a_malformed_baseline_stops_pytest_before_any_case(repo, tmp_path):
    bad = tmp_path / "bad.txt"
    bad.write_text("simple-l1-core/arith-q1-all-faps,Failed\n")
    r = pytest_in(repo, "--fbaconf-baseline", str(bad))
    assert r.returncode == 4 and "collected" not in r.stdout
    assert f"{bad}: line 1:" in r.stderr and "(did you mean Fail?)" in r.stderr and "Traceback" not in r.stderr


def test_a_flaky_case_listed_as_a_flake_is_retried(repo, tmp_path):
    flakes = tmp_path / "b.txt"
    flakes.write_text("simple-l1-core/arith-q1-all-faps,Flake\n")
    set_bugs(repo, "", extra_env=f'COUNT = "{tmp_path / "count"}"')
    try:
        r = pytest_in(
            repo,
            "--fbaconf-baseline",
            str(flakes),
            "fbaconf::simple-l1-core/arith-q1-all-faps",
            env={"FBACONF_SANDBOX": "none"},
        )
        assert r.returncode == 0 and "1 passed" in r.stdout and "0 new, 0 known, 0 fixed, 1 flaky" in r.stdout, (
            r.stdout + r.stderr
        )
        assert (tmp_path / "count").read_text() == "2"  # failed, then passed on the re-run
    finally:
        set_bugs(repo, "A")


def fbaconf_run(repo: Path, *args):
    return subprocess.run(
        [sys.executable, "-P", "-m", "fbaconf", "run", "--decoder", "ci/acme.toml", "--no-progress", "-j", "2", *args],
        cwd=repo,
        capture_output=True,
        text=True,
        timeout=600,
    )


def test_write_baseline_then_an_unchanged_run_has_nothing_new(tmp_path):
    """Claim simple@2 with no decode_multi: the multi-face cases are required and NotSupported; they
    are recorded, a hand-written line and comment survive, and the unchanged run passes."""
    repo = make_repo(tmp_path)
    set_bugs(repo, "A")
    m = repo / "ci" / "acme.toml"
    m.write_text(m.read_text().replace('claims = ["simple@1"]', 'claims = ["simple@2"]'))
    b = repo / "ci" / "baseline.txt"
    b.write_text("# acme's baseline\nsimple-l1-core/arith-ntsc-rate,Flake   # slow runners\n")
    sel = [
        "--suite",
        "simple-l2-stress",
        "--suite",
        "simple-l1-core",
        "--case",
        "simple-l1-core/arith-q1-all-faps",
        "--case",
        "simple-l2-stress/*",
    ]
    r = fbaconf_run(repo, *sel, "-o", "run1", "--write-baseline", "ci/baseline.txt")
    assert r.returncode == 1, r.stdout + r.stderr
    lines = b.read_text().splitlines()
    assert lines[:2] == ["# acme's baseline", "simple-l1-core/arith-ntsc-rate,Flake   # slow runners"]
    assert "simple-l1-core/arith-q1-all-faps,Fail,faps:3" in lines
    multi = [ln for ln in lines if ln.endswith(",NotSupported")]
    assert len(multi) == 3 and all(ln.startswith("simple-l2-stress/") for ln in multi)
    r = fbaconf_run(repo, *sel, "-o", "run2", "--baseline", "ci/baseline.txt")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "  baseline: 0 new, 4 known, 0 fixed, 0 flaky" in r.stdout
    # the bug fixed: the log names the case before anything else
    set_bugs(repo, "")
    m.write_text(m.read_text().replace('claims = ["simple@1"]', 'claims = ["simple@2"]'))
    r = fbaconf_run(repo, *sel, "-o", "run3", "--baseline", "ci/baseline.txt")
    assert r.returncode == 1
    head = r.stdout.splitlines()[1:3]
    assert head[0] == "  baseline: 0 new, 3 known, 1 fixed, 0 flaky"
    assert head[1].split()[:2] == ["FIXED", "simple-l1-core/arith-q1-all-faps"]


def test_a_malformed_baseline_stops_the_run_before_any_case(tmp_path):
    repo = make_repo(tmp_path)
    (repo / "ci" / "baseline.txt").write_text("# ok\nsimple-l1-core/x,Fail\nsimple-l1-core/y,Fail,a,b\nbroken line\n")
    r = fbaconf_run(repo, "-o", "run", "--baseline", "ci/baseline.txt")
    assert r.returncode == 2 and "ci/baseline.txt: line 4: expected 'suite/case,Outcome[,signature]'" in r.stderr
    assert not (repo / "run" / "results.jsonl").exists()


def test_a_decoder_not_built_yet_is_named_with_its_folder_expanded(tmp_path):
    """The manifest's {manifest_dir} template is expanded in the message, which says what to do."""
    repo = make_repo(tmp_path)
    m = repo / "ci" / "acme.toml"
    m.write_text(m.read_text().replace('"{python}", "{manifest_dir}/acme.py"', '"{manifest_dir}/../build/acme"'))
    with pytest.raises(UsageError) as e:
        preflight(resolve(str(m)))
    assert e.value.args[0] == (
        f"decoder acme: program {repo}/build/acme not found (not a file, and not on "
        f'PATH); [commands] decode names it "{{manifest_dir}}/../build/acme": build the '
        f"decoder first"
    )
