"""What the command line gives ``run``, ``certify`` and ``bench``, checked: the claim, the suites
named, the lab's extra folders; a wrong value is one :class:`UsageError` line (exit 2)."""

from __future__ import annotations

import difflib
import os
from pathlib import Path
from typing import TextIO

from fbaconf.conformance.suite import Suite
from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import sandbox, view
from fbaconf.profiles.model import Claim

from .adapters import Adapter, highest_claim


class UsageError(FbaconfInputError):
    """A command-line value is wrong (exit 2, one line)."""

    rule = "usage"


def use_color(stream: TextIO) -> bool:
    """Colour only on a terminal and never when NO_COLOR is set (https://no-color.org)."""
    return stream.isatty() and not os.environ.get("NO_COLOR")


def resolve_claim(text: str | None, adapter: Adapter) -> str:
    try:
        return str(Claim.parse(text or highest_claim(adapter)))
    except ValueError as e:
        raise UsageError(f"--claim: {e}") from None


def lab_folders(paths: list[Path]) -> list[Path]:
    """The lab's --sandbox-ro folders, checked: absolute, existing, not too broad, holding none of
    what a decoder never sees (git data, a copy of the goldens or suites: UsageError)."""
    out = []
    for p in paths:
        p = Path(p)
        if not p.is_absolute() or not p.is_dir():
            raise UsageError(f"--sandbox-ro {p}: give an absolute path to an existing folder")
        why = sandbox.view_problem(p) or view.folder_problem(p)
        if why:
            raise UsageError(f"--sandbox-ro {p}: {why}")
        out.append(p)
    return out


def check_suites(suites: list[Suite], names: list[str]) -> None:
    """Unknown ``--suite`` names are a usage error, with the nearest name."""
    known = [s.name for s in suites]
    for n in names:
        if n not in known:
            close = difflib.get_close_matches(n, known, n=1)
            raise UsageError(
                f"--suite {n!r}: no such suite"
                + (f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})")
            )
