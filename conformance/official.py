"""Which suites and goldens a verdict may rest on: the ones this fbaconf ships.

``FBACONF_SUITES`` and ``FBACONF_GOLDEN`` point a run at other folders (a lab building its own
suites, the tests): a claim judged there says nothing of the release's claim — a suite cut to one
case certified "PASS (1 case)". A certificate names the digest of every suite it ran and carries
the golden manifest; :func:`differences` compares them with the suites and goldens installed
with this fbaconf (never the environment's), which ``certify`` records and ``certify verify``
checks.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from .suite import package_root

MANIFEST = "suite.json"
GOLDEN_MANIFEST = "MANIFEST.json"


def suites_folder() -> Path:
    return package_root() / "suites"


def golden_folder() -> Path:
    return package_root().parent / "golden"


def _sha(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def differences(suites: list[dict], golden_manifest: bytes | None) -> list[str]:
    """What of a run's suites (``[{"name", "sha256"}]``) and golden manifest (its bytes; None:
    not packaged) is not this fbaconf's: one line each, empty when all are."""
    out = []
    for s in suites:
        name = str(s.get("name", "?")) if isinstance(s, dict) else "?"
        ours = _sha(suites_folder() / name / MANIFEST) if name.replace("-", "").isalnum() else None
        if ours is None:
            out.append(f"suite {name}: not a suite this fbaconf ships")
        elif ours != s.get("sha256"):
            out.append(
                f"suite {name}: not this fbaconf's (its suite.json sha256 {str(s.get('sha256'))[:12]}…, "
                f"this fbaconf's {ours[:12]}…)"
            )
    if golden_manifest is not None:
        ours = _sha(golden_folder() / GOLDEN_MANIFEST)
        if ours != hashlib.sha256(golden_manifest).hexdigest():
            out.append("goldens: the golden manifest is not this fbaconf's")
    return out
