"""A non-editable install runs the suites (issue 17): build a wheel, install it into a fresh
venv (no network: the project venv's dependencies are made visible through a .pth file added
after the install) and run a suite from ``/``."""
from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_wheel_in_a_fresh_venv_runs_a_suite_from_root(tmp_path):
    if importlib.util.find_spec("wheel") is None:
        pytest.fail("the 'wheel' package is part of the test extras; reinstall with .[test]")
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                    str(wheels), str(ROOT)], check=True, capture_output=True, timeout=600)
    (whl,) = wheels.glob("fbaconf-*.whl")
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    py = venv / "bin" / "python"
    subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(whl)], check=True,
                   capture_output=True, timeout=300)
    site = Path(subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "zz-fbaconf-test-deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    where = subprocess.run([str(py), "-c", "import fbaconf; print(fbaconf.__file__)"], capture_output=True,
                           text=True, check=True, cwd="/").stdout.strip()
    assert where.startswith(str(venv)), where  # the wheel, not the source tree
    out = tmp_path / "run"
    r = subprocess.run([str(venv / "bin" / "fbaconf"), "run", "--decoder", "reference-inprocess", "--suite",
                        "simple-l1-core", "-o", str(out), "--no-progress"], capture_output=True, text=True,
                       cwd="/", timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["counts"]["Pass"] == len(report["results"]) > 0
    v = subprocess.run([str(venv / "bin" / "fbaconf"), "golden", "verify"], capture_output=True, text=True,
                       cwd="/", timeout=600)
    assert v.returncode == 0, v.stdout + v.stderr
