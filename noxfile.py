"""The platform matrix: the same verdict on every supported Python and dependency set.

``nox -s matrix`` runs six cells -- Python 3.11, 3.12, 3.13 x {the oldest versions of the declared
dependency ranges that install on that Python, the newest the package index serves} -- each in a
fresh virtual environment holding only the wheel built from this tree and its dependencies, and
from a folder outside the tree (so nothing is imported from the source):

1. ``fbaconf suites build`` into a temporary folder: byte-identical to the committed suites;
2. ``fbaconf golden verify``: digests, then the goldens regenerated and compared;
3. ``fbaconf suites mutants --list``;
4. ``fbaconf certify --decoder reference-inprocess --claim predictable@2 --no-speed``: PASS (every
   required case; the speed measurement is the machine's, not the dependency set's).

One cell: ``nox -s "matrix-3.12(oldest)"``; the table of the cells run so far:
``nox -s matrix_summary``. Interpreters are taken from PATH (``python3.X``), else from pyenv
(``~/.pyenv/versions/3.X.*``). The oldest sets are pinned below (OLDEST): a pip dry run of the
next-older release of each finds no wheel for that Python or a conflict.
"""

from __future__ import annotations

import filecmp
import json
import os
import time
from pathlib import Path

import nox

ROOT = Path(__file__).resolve().parent
RESULTS = ROOT / "build" / "matrix"
PYTHONS = ["3.11", "3.12", "3.13"]
# The oldest set of the declared ranges (pyproject.toml) that installs together from wheels, per
# Python. 3.11/3.12: every floor of the ranges installs. 3.13: no numpy wheel before 2.1.0, and
# colour-science 0.4.4 requires Python < 3.13. scipy is not a dependency of fbaconf; it comes with
# colour-science (its newest release that accepts the pinned numpy).
OLDEST = {
    "3.11": {"numpy": "1.26.0", "OpenImageIO": "3.0.3.1", "colour-science": "0.4.4", "cryptography": "42.0.0"},
    "3.12": {"numpy": "1.26.0", "OpenImageIO": "3.0.3.1", "colour-science": "0.4.4", "cryptography": "42.0.0"},
    "3.13": {"numpy": "2.1.0", "OpenImageIO": "3.0.3.1", "colour-science": "0.4.5", "cryptography": "42.0.0"},
}
# The distributions each cell reports.
SHOWN = ("numpy", "scipy", "OpenImageIO", "colour-science", "cryptography")

nox.options.sessions = ["matrix"]
nox.options.reuse_existing_virtualenvs = False


def _pyenv_on_path() -> None:
    """Put pyenv's interpreters of PYTHONS on PATH when ``python3.X`` is not there (pyenv's shims
    answer only for the global version)."""
    base = Path(os.environ.get("PYENV_ROOT", Path.home() / ".pyenv")) / "versions"
    if not base.is_dir():
        return
    dirs = []
    for v in PYTHONS:
        found = sorted(
            base.glob(f"{v}.*/bin/python{v}"),
            key=lambda p: [int(x) for x in p.parents[1].name.split(".")[:3] if x.isdigit()],
        )
        if found:
            dirs.append(str(found[-1].parent))
    os.environ["PATH"] = os.pathsep.join(dirs + [os.environ.get("PATH", "")])


_pyenv_on_path()


def _versions(session) -> dict[str, str]:
    code = (
        "import importlib.metadata as m, json\n"
        "def v(d):\n    try:\n        return m.version(d)\n    except m.PackageNotFoundError:\n        return '-'\n"
        f"print(json.dumps({{d: v(d) for d in {SHOWN!r}}}))"
    )
    out = session.run("python", "-c", code, silent=True)
    return json.loads(out.strip().splitlines()[-1])


def _same_tree(a: Path, b: Path) -> list[str]:
    """Files that differ between two folders (missing on either side, or other bytes)."""
    fa = {p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    fb = {p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    diff = sorted(fa ^ fb)
    diff += [r for r in sorted(fa & fb) if not filecmp.cmp(a / r, b / r, shallow=False)]
    return [d for d in diff if d != "__init__.py"]


@nox.session(python=PYTHONS)
@nox.parametrize("deps", ["oldest", "newest"], ids=["oldest", "newest"])
def matrix(session, deps):
    """One cell: build the wheel, install it with the oldest or newest dependencies, run the checks."""
    py = session.python
    t0 = time.monotonic()
    tmp = Path(session.create_tmp()).resolve()
    wheels = tmp / "wheels"
    session.install("setuptools>=68", "wheel")
    session.run("python", "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", str(wheels), str(ROOT))
    (whl,) = wheels.glob("fbaconf-*.whl")
    if deps == "oldest":
        pins = [f"{k}=={v}" for k, v in OLDEST[py].items()]
        session.install("--only-binary=:all:", str(whl), *pins)
    else:
        session.install("--only-binary=:all:", "--upgrade", "--upgrade-strategy", "eager", str(whl))
    versions = _versions(session)
    if deps == "oldest":
        wrong = {k: (versions.get(k), v) for k, v in OLDEST[py].items() if versions.get(k) != v}
        if wrong:
            session.error(f"the oldest set did not install as pinned: {wrong}")
    session.chdir(tmp)  # outside the tree: fbaconf comes from the wheel
    where = session.run("python", "-c", "import fbaconf; print(fbaconf.__file__)", silent=True).strip()
    if not Path(where).is_relative_to(Path(session.virtualenv.location)):
        session.error(f"fbaconf is imported from {where}, not from the wheel")
    steps = {}

    def step(name, *args, env=None):
        s = time.monotonic()
        session.run(*args, env=env)
        steps[name] = round(time.monotonic() - s, 1)

    built = tmp / "suites"
    step("suites build", "fbaconf", "suites", "build", env={"FBACONF_SUITES": str(built)})
    differ = _same_tree(built, ROOT / "conformance" / "suites")
    if differ:
        session.error(f"suites build is not byte-identical to the committed suites: {differ[:10]}")
    step("golden verify", "fbaconf", "golden", "verify")
    step("mutants --list", "fbaconf", "suites", "mutants", "--list")
    # --no-speed: the cases' verdict is what may depend on the dependency set; the speed measurement
    # is the machine's (README command 1 and benchmarks/bench_certify.py measure it), and on a shared
    # or loaded machine its wall-clock fit would fail cells for no reason of theirs
    step(
        "certify predictable@2",
        "fbaconf",
        "certify",
        "--decoder",
        "reference-inprocess",
        "--claim",
        "predictable@2",
        "-o",
        str(tmp / "cert"),
        "--no-speed",
    )
    cert = json.loads((tmp / "cert" / "certificate.json").read_text())
    verdict = cert.get("verdict") or cert.get("result")
    RESULTS.mkdir(parents=True, exist_ok=True)
    row = {
        "python": session.run("python", "-c", "import platform; print(platform.python_version())", silent=True).strip(),
        "deps": deps,
        "versions": versions,
        "steps": steps,
        "verdict": verdict,
        "seconds": round(time.monotonic() - t0),
    }
    (RESULTS / f"{py}-{deps}.json").write_text(json.dumps(row, indent=1) + "\n")
    session.log(json.dumps(row))


@nox.session(python=False)
def matrix_summary(session):
    """The table of the matrix cells run so far (build/matrix/*.json)."""
    rows = [json.loads(p.read_text()) for p in sorted(RESULTS.glob("*.json"))]
    head = ["python", "deps", *SHOWN, "build", "verify", "mutants", "certify", "verdict", "total s"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        s = r["steps"]
        lines.append(
            "| "
            + " | ".join(
                [
                    r["python"],
                    r["deps"],
                    *(r["versions"].get(k, "-") for k in SHOWN),
                    *(
                        f"{s.get(k, '-')} s"
                        for k in ("suites build", "golden verify", "mutants --list", "certify predictable@2")
                    ),
                    str(r["verdict"]),
                    str(r["seconds"]),
                ]
            )
            + " |"
        )
    print("\n".join(lines))
