"""The core and the trust boundary are typed: ``mypy --strict`` (the settings in pyproject.toml)
passes on the modules and packages named here.

setup.py installs every top-level stage folder as ``fbaconf.<folder>`` through a path map that
mypy cannot follow, so the check runs on a view of symbolic links laid out as the installed
package is (``fbaconf/<stage>`` -> ``<stage>/``) and reports paths back in the tree's terms.
Run it alone with ``.venv/bin/python -m pytest tests/unit/test_types.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

api = pytest.importorskip("mypy.api", reason="mypy is in the test extra: pip install -e '.[test]'")

REPO = Path(__file__).resolve().parents[2]
# folders beside the stages that are not installed (setup.py's NOT_INSTALLED)
NOT_STAGES = {"tests", "benchmarks", "examples", "docs", "build", "dist"}

# the core every layer imports, and (PACKAGES) the trust boundary: what runs, confines and judges
# an untrusted decoder, and what certifies it
MODULES = ("fbaconf.errors", "fbaconf.rules", "fbaconf.safefs", "fbaconf._atomic")
PACKAGES: tuple[str, ...] = ("fbaconf.isolation", "fbaconf.certification", "fbaconf.harness", "fbaconf.explain")


def _view(root: Path) -> Path:
    pkg = root / "fbaconf"
    pkg.mkdir(parents=True)
    for f in (REPO / "fbaconf").iterdir():
        if f.name != "__pycache__":
            (pkg / f.name).symlink_to(f)
    for d in REPO.iterdir():
        if d.is_dir() and d.name not in NOT_STAGES and d.name != "fbaconf" and (d / "__init__.py").is_file():
            (pkg / d.name).symlink_to(d)
    return root


def _in_tree(line: str) -> str:
    """``fbaconf/harness/x.py:3: error`` -> ``harness/x.py:3: error`` (``fbaconf/errors.py`` stays)."""
    if line.startswith("fbaconf/"):
        rest = line[len("fbaconf/") :]
        if rest.split("/", 1)[0] in {d.name for d in REPO.iterdir() if d.is_dir()} - {"fbaconf"}:
            return rest
    return line


def test_the_core_and_the_trust_boundary_pass_mypy_strict(tmp_path, monkeypatch):
    view = _view(tmp_path / "view")
    monkeypatch.chdir(view)
    args = ["--config-file", str(REPO / "pyproject.toml"), "--cache-dir", str(REPO / ".mypy_cache")]
    for m in MODULES:
        args += ["-m", m]
    for p in PACKAGES:
        args += ["-p", p]
    out, err, rc = api.run(args)
    report = "\n".join(_in_tree(line) for line in (out + err).splitlines())
    assert rc == 0, f"mypy --strict found type errors:\n{report}"
    assert "Success" in out
