"""Independent mutants: faulty decoders written from ``../shared/spec/fap-bitstream.md`` alone,
by people who had not read the suite's cases, to measure the suites honestly.

One module per area; each defines ``MUTANTS_LIST`` (``mutation.core.Mutant`` with
``family="independent"`` and the rule it breaks). ``mutation/data/mutants-independent.md``
lists them with how each was shown to differ from the reference, and the equivalent ones
with their reasons.
"""

from __future__ import annotations

import importlib

AREAS = ("syntax", "coder", "timing", "highlevel", "text", "writers", "animation")


def _load() -> list:
    out = []
    for area in AREAS:
        out += importlib.import_module(f"{__name__}.{area}").MUTANTS_LIST
    return out


MUTANTS_LIST = _load()
