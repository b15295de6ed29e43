"""The tiers' rules hold by construction: a unit test that starts a process fails, with the way
out named; one marked ``spawns`` runs (the rule is in tests/conftest.py)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1]

SPAWNING = """
import subprocess, sys
import pytest

def test_quiet():
    assert 1 + 1 == 2

def test_forks_a_child():
    subprocess.run([sys.executable, "-c", "pass"], check=True)

@pytest.mark.spawns("the child is the subject")
def test_declared_child():
    subprocess.run([sys.executable, "-c", "pass"], check=True)
"""


def test_a_unit_test_that_starts_a_process_fails_unless_it_says_why(tmp_path):
    tests = tmp_path / "tests"
    (tests / "unit").mkdir(parents=True)
    shutil.copy(TESTS / "conftest.py", tests / "conftest.py")
    (tests / "unit" / "test_spawning.py").write_text(SPAWNING)
    shutil.copy(TESTS.parent / "pyproject.toml", tmp_path / "pyproject.toml")  # the markers
    r = subprocess.run(
        [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "0", "-q", "tests/unit"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 1, r.stdout + r.stderr
    assert "1 failed, 2 passed" in r.stdout, r.stdout
    assert "test_forks_a_child: a unit test runs in-process" in r.stdout
    assert "@pytest.mark.spawns(reason)" in r.stdout
