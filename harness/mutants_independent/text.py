"""Independent mutants: text (see the package docstring)."""
from __future__ import annotations

from fbaconf.harness.mutant_core import Mutant

MUTANTS_LIST: list[Mutant] = []
