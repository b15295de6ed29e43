"""What a manifest's command names cannot show (item 1): a `{python} FILE` command
showed FILE's folder, so a never-decoding program that names its checkout's ``.git/config``,
another checkout's ``setup.py``, a file of a wheel build (``build/lib*/fbaconf/``) or of an
installed fbaconf's data saw every golden and passed 165 of 165 cases, signed. Now every file a
command names has its folder shown only when it holds nothing but the decoder's files, judged by
content (isolation/view.py): git data, a copy of the goldens or suites, a file whose sha256 is a
golden's or an expected output's — else the run stops before any case (exit 2, naming the file
and why).

Each attack is one hostile decoder written here (THIEF: it never decodes; it finds the case's
expected output in what it is shown and copies it). Each test asserts the refusal and, as the
control, that the same thief *does* pass a case when the folder is shown — so the refusal is
what stops it. The sandboxed rows need bubblewrap (fail in CI, skip elsewhere).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import fbaconf
from fbaconf.conformance.suite import golden_root, load_suites, suites_root
from fbaconf.harness import adapters
from fbaconf.harness.adapters import ViewError
from fbaconf.harness.preflight import preflight
from fbaconf.isolation import sandbox, view

from lib.sandbox import needs_sandbox

ROOT = Path(fbaconf.__file__).resolve().parents[1]
CASE = ("simple-l1-core", "dct-q4")

THIEF = r"""
import hashlib, json, os, shutil, subprocess, sys
SHOWN, IN, OUT = sys.argv[1], sys.argv[2], sys.argv[3]
stem = os.path.splitext(os.path.basename(IN))[0]
here = os.path.dirname(SHOWN)
if os.path.basename(here) == ".git" or os.path.isdir(os.path.join(here, "objects")):
    # a git directory: the committed expected output, through git itself
    names = subprocess.run(["git", "--git-dir", here, "ls-tree", "-r", "--name-only", "HEAD"],
                           capture_output=True, text=True).stdout.split()
    path = next(n for n in names if n.endswith("/" + stem + ".fap") and "conformance/suites/" in n)
    open(OUT, "wb").write(subprocess.run(["git", "--git-dir", here, "show", "HEAD:" + path],
                                         capture_output=True).stdout)
    sys.exit(0)
table = os.path.join(here, "table.json")
if os.path.isfile(table):  # copies shipped under other names, found by the input's sha256
    key = hashlib.sha256(open(IN, "rb").read()).hexdigest()
    shutil.copyfile(os.path.join(here, json.load(open(table))[key]), OUT)
    sys.exit(0)
for root, dirs, files in os.walk(here):  # a checkout, a build, an installed package: the suite's .fap
    if stem + ".fap" in files:
        shutil.copyfile(os.path.join(root, stem + ".fap"), OUT)
        sys.exit(0)
sys.exit(3)
"""


def the_case():
    (s,) = load_suites(names=[CASE[0]])
    return next(c for c in s.cases if c.id == CASE[1])


def thief_manifest(tmp_path: Path, shown: Path) -> Path:
    vendor = tmp_path / "vendor"
    vendor.mkdir(exist_ok=True)
    (vendor / "thief.py").write_text(THIEF)
    m = vendor / "thief.toml"
    m.write_text(
        'name = "thief"\nclaims = ["predictable@2"]\ninputs = ["fba"]\noutputs = ["faps"]\n'
        'faps_format = "fap"\n[commands]\n'
        f'decode = ["{{python}}", "{{manifest_dir}}/thief.py", "{shown}", "{{input}}", "{{faps_out}}"]\n'
        "[limits]\ntimeout_s = 60\n"
    )
    return m


def refused(tmp_path: Path, shown: Path, words: str) -> None:
    """The attack through ``shown``: refused before anything runs, by preflight and by certify
    of the highest claim (exit 2, no package, no case run)."""
    m = thief_manifest(tmp_path, shown)
    with pytest.raises(ViewError) as e:
        preflight(adapters.resolve(m), None)
    assert e.value.rule == "sandbox-view" and words in str(e.value) and str(shown.parent) in str(e.value), str(e.value)
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "certify",
            "--decoder",
            str(m),
            "--claim",
            "predictable@2",
            "--no-speed",
            "-o",
            str(tmp_path / "pkg"),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 2 and words in r.stderr and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert not (tmp_path / "pkg" / "results.jsonl").exists()  # 0 cases ran: 0 valid-stream Pass


def control(tmp_path: Path, shown: Path) -> None:
    """The same thief, its folder shown as the old rule showed it: it passes the case (writes the
    reference decoding) — the attack is real."""
    needs_sandbox()
    case = the_case()
    work = tmp_path / "control"
    (work / "in").mkdir(parents=True)
    (work / "out").mkdir()
    shutil.copyfile(case.input_path("fba"), work / "in" / f"{CASE[1]}.fba")
    (tmp_path / "vendor").mkdir(exist_ok=True)
    (tmp_path / "vendor" / "thief.py").write_text(THIEF)
    shown_dirs = [shown.parent, tmp_path / "vendor", *sandbox.python_view()]
    res = sandbox.run(
        [
            sys.executable,
            str(tmp_path / "vendor" / "thief.py"),
            str(shown),
            str(work / "in" / f"{CASE[1]}.fba"),
            str(work / "out" / "faps.fap"),
        ],
        work,
        sandbox.Limits(timeout_s=60),
        view=sandbox.View(read_only=shown_dirs, writable=[work]),
    )
    assert res.returncode == 0, res.stderr_tail
    assert (work / "out" / "faps.fap").read_bytes() == case.input_path("fap").read_bytes()


def copy_of_fbaconf(where: Path) -> Path:
    """What a checkout, a wheel build and an installed package hold: the goldens and the suites."""
    where.mkdir(parents=True, exist_ok=True)
    shutil.copytree(golden_root(), where / "golden")
    shutil.copytree(suites_root(), where / "conformance" / "suites")
    return where


def git_dir() -> Path:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--path-format=absolute", "--git-common-dir"],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except OSError:
        out = None
    if out is None or out.returncode != 0:
        if os.environ.get("CI"):
            pytest.fail("CI runs in a clone: its .git must be there")
        pytest.skip("not a git checkout (or no git)")
    return Path(out.stdout.strip())


# ------------------------------------------------------------------ the four ways in


def test_its_own_checkouts_git_is_refused(tmp_path):
    gd = git_dir()
    refused(tmp_path, gd / "config", "is git data")
    control(tmp_path, gd / "config")


def test_another_checkout_is_refused(tmp_path):
    other = copy_of_fbaconf(tmp_path / "other-checkout")
    (other / "setup.py").write_text("from setuptools import setup\nsetup()\n")
    refused(tmp_path, other / "setup.py", "a copy of fbaconf's goldens")
    control(tmp_path, other / "setup.py")


def test_a_wheel_build_is_refused(tmp_path):
    pkg = copy_of_fbaconf(tmp_path / "checkout" / "build" / "lib" / "fbaconf")
    (pkg / "__init__.py").write_text("")
    refused(tmp_path, pkg / "__init__.py", "a copy of fbaconf's")
    control(tmp_path, pkg / "__init__.py")


def test_an_installed_fbaconfs_data_is_refused(tmp_path):
    site = tmp_path / "venv" / "lib" / "python3.11" / "site-packages"
    pkg = copy_of_fbaconf(site / "fbaconf")
    inside = pkg / "conformance" / "suites" / CASE[0] / f"{CASE[1]}.fba"  # a file of the data itself
    refused(tmp_path, inside, "lies inside")
    control(tmp_path, inside)
    # and a {python} decoder shown that interpreter's installation never sees its fbaconf's data
    assert set(view.installed_data([tmp_path / "venv"])) == {pkg / "golden", pkg / "conformance" / "suites"}


def test_expected_outputs_copied_under_other_names_are_refused(tmp_path):
    """No golden/ or suites/ tree: the vendor ships the expected outputs renamed, with a table
    from each input's sha256 — caught by the files' own sha256."""
    case = the_case()
    data = tmp_path / "answers"
    data.mkdir()
    shutil.copyfile(case.input_path("fap"), data / "0001.bin")
    key = hashlib.sha256(case.input_path("fba").read_bytes()).hexdigest()
    (data / "table.json").write_text(json.dumps({key: "0001.bin"}))
    refused(tmp_path, data / "table.json", f"a copy of suites/{CASE[0]}/{CASE[1]}.fap")
    control(tmp_path, data / "table.json")


def test_a_folder_inside_a_golden_tree_of_another_version_is_refused(tmp_path):
    """Another version's goldens have other digests: the tree itself gives them away."""
    gold = tmp_path / "old" / "golden"
    (gold / "simple-l1-core").mkdir(parents=True)
    (gold / "MANIFEST.json").write_text('{"format": "fbaconf.golden/1"}')
    (gold / "simple-l1-core" / "x.npz").write_bytes(b"not this version's" * 10)
    m = thief_manifest(tmp_path, gold / "simple-l1-core" / "x.npz")
    with pytest.raises(ViewError, match="lies inside .*golden: a copy of fbaconf's goldens"):
        preflight(adapters.resolve(m), None)


# ------------------------------------------------------------------ what a command may name


def test_a_jar_or_model_the_command_names_elsewhere_is_shown(tmp_path):
    """a jar given as an argument outside the program's and the manifest's folders was
    invisible ("Unable to access jarfile", a Fail per case). Its folder is shown, checked."""
    needs_sandbox()
    models = tmp_path / "models"
    models.mkdir()
    (models / "weights.bin").write_bytes(b"w" * 100)
    (tmp_path / "lib").mkdir()
    (tmp_path / "lib" / "extra.jar").write_bytes(b"PK")
    vendor = tmp_path / "vendor"
    vendor.mkdir()
    m = vendor / "m.toml"
    m.write_text(
        'name = "reader"\nclaims = ["simple@1"]\ninputs = ["fba"]\noutputs = ["faps"]\n[commands]\n'
        'decode = ["/bin/sh", "-c", "cat \\"$1\\" \\"$2\\" >/dev/null && echo read", "sh", '
        f'"--model={models}/weights.bin", "{tmp_path}/lib/extra.jar:/usr/share", "{{input}}", '
        '"{faps_out}"]\n'
    )
    a = adapters.resolve(m)
    argv = [
        "/bin/sh",
        "-c",
        'cat "${1#--model=}" "${2%%:*}" >/dev/null && echo read',
        "sh",
        f"--model={models}/weights.bin",
        f"{tmp_path}/lib/extra.jar:/usr/share",
    ]
    work = tmp_path / "case"
    (work / "in").mkdir(parents=True)
    v = a.sandbox_view(argv, work)
    assert models in v.read_only and tmp_path / "lib" in v.read_only and vendor in v.read_only
    res = sandbox.run(argv, work, a.limits, view=v)
    assert res.returncode == 0 and res.stdout_tail.strip() == "read", res.stderr_tail


def test_named_paths_reads_the_forms_a_command_names_files_in(tmp_path):
    for name in ("a.jar", "b.jar", "args.txt", "m.bin"):
        (tmp_path / name).write_text("x")
    got = view.named_paths(
        [
            "-cp",
            f"{tmp_path}/a.jar:{tmp_path}/b.jar",
            f"@{tmp_path}/args.txt",
            f"--model={tmp_path}/m.bin",
            "relative/x",
            f"{tmp_path}/missing",
            str(tmp_path),
        ]
    )
    assert got == [tmp_path / "a.jar", tmp_path / "b.jar", tmp_path / "args.txt", tmp_path / "m.bin", tmp_path]


def test_what_the_sandbox_empties_is_not_held_against_a_folder(tmp_path):
    """A vendor folder holding the run folder (a player's case folder holds a suite's .fap as its
    input): the sandbox empties the run folder, so the walk skips it; the same copy anywhere else
    in the folder is refused."""
    case = the_case()
    m = thief_manifest(tmp_path, tmp_path / "vendor" / "thief.py")
    run = tmp_path / "vendor" / "run" / "work" / "case-x" / "in"
    run.mkdir(parents=True)
    shutil.copyfile(case.input_path("fap"), run / f"{CASE[1]}.fap")
    a = adapters.resolve(m)
    argv = [sys.executable, str(tmp_path / "vendor" / "thief.py")]
    assert a.sandbox_view(argv, tmp_path / "case", hidden=[tmp_path / "vendor" / "run"]).read_only
    shutil.copyfile(case.input_path("fap"), tmp_path / "vendor" / "kept.fap")
    view._CACHE.clear()  # a folder is judged once per process: this one changed under the test
    with pytest.raises(ViewError, match="kept.fap, a copy of suites/simple-l1-core/dct-q4.fap"):
        a.sandbox_view(argv, tmp_path / "case", hidden=[tmp_path / "vendor" / "run"])


def test_what_the_sandbox_has_of_its_own_is_not_a_named_file(tmp_path):
    """`--log /dev/null`, `--tmp /tmp`, `/proc/self/fd/1`: the sandbox has its own; nothing to show."""
    m = thief_manifest(tmp_path, tmp_path / "vendor" / "thief.py")
    argv = ["/bin/true", "--log", "/dev/null", "--tmp", "/tmp", "/proc/self/fd/1", "--root=/", "/sys/kernel"]
    v = adapters.resolve(m).sandbox_view(argv, tmp_path / "case")
    assert v.read_only == [tmp_path / "vendor"]  # the manifest's folder alone (/bin is a system folder)
