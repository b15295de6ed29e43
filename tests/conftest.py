"""Shared test configuration: the tiers, hypothesis profiles, the optional external data folder
and the fixtures several tiers share (one certified package per session).

Tiers, by folder (each test is marked with its folder's name, so ``-m unit`` works too):

* ``tests/unit/`` — one module or one verb in-process: the fast tier of the developer loop
  (``python -m pytest tests/unit -n auto``, under 3 minutes on 2 cores). Kept fast by rule, not by
  a clock: a unit test starts no process (no decoder, no forked mutant, no CLI in a child) — the
  guard below fails one that does — unless it is marked ``spawns`` with the reason its subject is
  a process of its own;
* ``tests/integration/`` — decoders run through the harness, the sandbox, the fuzzer, the
  cluster, the installed wheel;
* ``tests/suites/`` — the suites' own checks: rebuilt byte for byte, coverage, mutants, the
  image-stage renderer matrices;
* ``tests/attacks/`` — hostile decoders, manifests and packages.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from fbaconf.certification import certify
from fbaconf.certification.package import load_key, seal

# ci: deterministic (derandomised) so a CI run is reproducible; dev: random exploration;
# HYPOTHESIS_PROFILE picks one (stress: 2,000 examples each).
settings.register_profile(
    "ci",
    derandomize=True,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile("dev", deadline=None, suppress_health_check=[HealthCheck.too_slow])
# fast: the developer's loop (README: the fast tier); each property meets 20 examples, not 100
settings.register_profile("fast", max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    "stress", max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci" if os.environ.get("CI") else "dev"))

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
TIERS = ("unit", "integration", "suites", "attacks")


def pytest_xdist_auto_num_workers(config):
    """``-n auto``: two workers more than the cores the process may use. Part of many tests is
    waiting — on a decoder's time-out, a sandbox starting, a cluster peer — and the extra workers
    fill it: README command 2 on 2 cores took 530 s with 2 workers, 442 s with 3 and 431 s with 4
    (that one with other work running beside it; 2026-11-28, this machine)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return cores + 2


def _refuse_processes(monkeypatch: pytest.MonkeyPatch, nodeid: str) -> None:
    def refuse(*_a, **_k):
        pytest.fail(
            f"{nodeid}: a unit test runs in-process (it started a process); move it to the tier its "
            "subject belongs to, or mark it @pytest.mark.spawns(reason) when the process is the subject",
            pytrace=False,
        )

    monkeypatch.setattr(subprocess.Popen, "__init__", refuse)
    for name in ("fork", "forkpty", "posix_spawn", "posix_spawnp"):
        if hasattr(os, name):
            monkeypatch.setattr(os, name, refuse)


@pytest.fixture(autouse=True)
def _unit_tier_in_process(request, monkeypatch):
    if request.node.get_closest_marker("unit") and not request.node.get_closest_marker("spawns"):
        _refuse_processes(monkeypatch, request.node.nodeid)


def pytest_collection_modifyitems(config, items):
    """Mark each test with its tier (its folder under tests/)."""
    for item in items:
        path = Path(item.path).resolve()
        if path.is_relative_to(TESTS):
            tier = path.relative_to(TESTS).parts[0]
            if tier in TIERS:
                item.add_marker(getattr(pytest.mark, tier))


SHARED_FAP = REPO.parent / "shared" / "data" / "fap"


def real_fap_files() -> list[Path]:
    return sorted(SHARED_FAP.rglob("*.fap")) if SHARED_FAP.is_dir() else []


@pytest.fixture
def real_files() -> list[Path]:
    files = real_fap_files()
    if not files:
        pytest.skip("../shared/data/fap is not present (external suite)")
    return files


# ------------------------------------------------------------------ made once per session, for every worker
@pytest.fixture(scope="session")
def made_once(tmp_path_factory):
    """``made_once(name, make) -> folder``: a folder shared by the session's xdist workers, made
    by ``make(folder)`` by the first worker to take its lock (the others wait, then use it). For
    what is expensive and read-only once made (a certified package, the wheel in a venv), and
    for what must not be made twice at once (two wheel builds collide in setuptools' ``build/``)."""
    base = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        base = base.parent  # the session's folder, above each worker's

    def once(name: str, make) -> Path:
        root = base / name
        root.mkdir(exist_ok=True)
        with open(root / ".lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            if not (root / ".made").is_file():
                make(root)
                (root / ".made").write_text("")
        return root

    return once


def _certify(out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "certify",
            "--decoder",
            "reference-inprocess",
            "--claim",
            "simple@1",
            "--no-speed",
            "-o",
            str(out),
            *extra,
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )


def _make_packages(root: Path) -> None:
    unsigned = _certify(root / "unsigned")
    key, _pub = certify.keygen(root / "keys")
    shutil.copytree(root / "unsigned", root / "signed", symlinks=True)
    seal(root / "signed", load_key(key, private=True))
    (root / "made.json").write_text(
        json.dumps({"returncode": unsigned.returncode, "output": unsigned.stdout + unsigned.stderr})
    )


@pytest.fixture(scope="session")
def _packages(made_once):
    """``certify --decoder reference-inprocess --claim simple@1 --no-speed``, made once per
    session and shared by the xdist workers: unsigned, and that package sealed with a fresh key
    as ``certify --key`` seals it (``seal(out, key)``; the end-to-end ``certify --key`` runs in
    tests/attacks/test_lab.py)."""
    root = made_once("fbaconf-packages", _make_packages)
    made = json.loads((root / "made.json").read_text())
    run = subprocess.CompletedProcess(["certify"], made["returncode"], made["output"], "")
    return root, run, run


@pytest.fixture
def certified_package(_packages, tmp_path) -> Path:
    """A fresh copy of the session's unsigned simple@1 package (the test may change it)."""
    root, run, _ = _packages
    assert run.returncode == 0, run.stdout + run.stderr
    return Path(shutil.copytree(root / "unsigned", tmp_path / "package", symlinks=True))


@pytest.fixture
def signed_package(_packages, tmp_path) -> tuple[Path, Path]:
    """A fresh copy of the session's signed simple@1 package and the public key that checks it."""
    root, _, run = _packages
    assert run.returncode == 0, run.stdout + run.stderr
    pkg = Path(shutil.copytree(root / "signed", tmp_path / "package", symlinks=True))
    return pkg, root / "keys" / certify.PUB_FILE
