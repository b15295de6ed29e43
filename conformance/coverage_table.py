"""The coverage points of each committed case, kept so that a certificate need not decode every case again.

:func:`fbaconf.conformance.coverage.case_points` decodes each stream with the reference and the
instrumented arithmetic coder, runs the stream checker twice and parses and compiles the scene:
about 0.15 s a case, 18-30 s for the cases of one claim, paid by every ``certify`` for its
"what this verdict rests on" section. The points depend only on what the case is (kind, group,
stages), the bytes of its input files and the coverage model; ``data/case-points.json`` holds, for
each committed case, a key over exactly those and the points computed from them.

:func:`points_of` takes the stored points when the key matches and computes them otherwise (an
input that changed, a suite of the user's own under ``FBACONF_SUITES``, an edited model): the
table makes certify faster, never different. The extractors' code is not in the key:
``tests/suites/test_coverage.py`` checks every entry against a fresh computation, and
``fbaconf suites coverage --write`` rewrites the file.
"""

from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

from .coverage import CaseCoverage, case_points

TABLE_FORMAT = "fbaconf.case-points/1"
TABLE_PATH = Path(__file__).resolve().parent / "data" / "case-points.json"
MODEL_PATH = Path(__file__).resolve().parent / "data" / "coverage.toml"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _model_digest() -> str:
    """The coverage model's sha256, read once per file version (every case's key holds it)."""
    st = MODEL_PATH.stat()
    return _model_digest_at(st.st_mtime_ns, st.st_size)


@lru_cache(maxsize=2)
def _model_digest_at(_mtime_ns: int, _size: int) -> str:
    return _sha(MODEL_PATH)


def case_key(case) -> str | None:
    """The digest of everything ``case_points`` reads of a case (None when an input cannot be read:
    the case is then computed, and the computation reports the problem)."""
    try:
        files: dict[str, object] = {}
        for role, rel in sorted(case.inputs.items()):
            if isinstance(rel, list):
                files[role] = [_sha(case.suite_dir / str(p)) for p in rel]
            elif isinstance(rel, str):
                files[role] = _sha(case.suite_dir / rel)
            else:
                files[role] = rel
        doc = {
            "kind": str(case.kind),
            "group": case.group,
            "stages": sorted(case.stages),
            "inputs": files,
            "model": _model_digest(),
        }
    except (OSError, TypeError):
        return None
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


@lru_cache(maxsize=4)
def _table_at(path: str, _mtime_ns: int, _size: int) -> dict:
    try:
        doc = json.loads(Path(path).read_text("utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(doc, dict) or doc.get("format") != TABLE_FORMAT or not isinstance(doc.get("cases"), dict):
        return {}
    return doc["cases"]


def _table(path: Path | None) -> dict:
    path = path or TABLE_PATH
    try:
        st = path.stat()
    except OSError:
        return {}
    return _table_at(str(path), st.st_mtime_ns, st.st_size)


def stored_points(case, path: Path | None = None) -> set[str] | None:
    """The stored points of a case when its key matches the table's, else None."""
    entry = _table(path).get(case.full_id)
    if not isinstance(entry, dict) or not isinstance(entry.get("points"), list):
        return None
    key = case_key(case)
    if key is None or entry.get("key") != key:
        return None
    return {str(p) for p in entry["points"]}


def points_of(case, path: Path | None = None) -> set[str]:
    """The coverage points a case hits: stored when its key matches, computed otherwise."""
    known = stored_points(case, path)
    return known if known is not None else case_points(case).points


def table(computed: list[tuple[object, CaseCoverage]]) -> dict:
    """The table document of freshly computed (case, coverage) pairs (cases with problems are left
    out: they are computed, and their problem reported, every time)."""
    cases = {}
    for case, cc in computed:
        key = case_key(case)
        if key is None or cc.problems:
            continue
        cases[case.full_id] = {"key": key, "points": sorted(cc.points)}
    return {
        "format": TABLE_FORMAT,
        "about": "Coverage points of each committed case (conformance/coverage_table.py); written by "
        "`fbaconf suites coverage --write`, checked against a fresh computation by "
        "tests/suites/test_coverage.py.",
        "cases": dict(sorted(cases.items())),
    }


def write(computed: list[tuple[object, CaseCoverage]], path: Path | None = None) -> tuple[Path, int]:
    """Write the table (default: the package's ``data/case-points.json``), one case per line;
    returns (the file, how many cases it holds)."""
    path = path or TABLE_PATH
    doc = table(computed)
    body = ",\n".join(f" {json.dumps(k)}: {json.dumps(v, sort_keys=True)}" for k, v in doc["cases"].items())
    head = {k: v for k, v in doc.items() if k != "cases"}
    text = json.dumps(head, indent=1)[:-2] + ',\n "cases": {\n' + body + "\n }\n}\n"
    path.write_text(text, "utf-8")
    return path, len(doc["cases"])


__all__ = ["TABLE_FORMAT", "TABLE_PATH", "case_key", "points_of", "stored_points", "table", "write"]
