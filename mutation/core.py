"""What a mutant is and how one is applied: shared by the suite's own mutants
(``mutation/own.py``) and the independent set (``mutation/independent/``).

A :class:`Mutant` names the place it changes (``module:qualname``) and how: a source mutation
(one exact snippet of the reference function replaced, the function recompiled in its module's
namespace and installed — in its module and under every fbaconf module's name for it, since
callers import functions by name at the top) or a custom ``patch`` function. ``pure_decoder`` switches the C fast
path of the arithmetic decoder off, so that a change of the Python block decoder takes effect.
Applying a mutant changes the whole process and is never undone.
"""

from __future__ import annotations

import importlib
import inspect
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass

from fbaconf.bitstreams import arith


@dataclass(frozen=True)
class Mutant:
    name: str
    where: str  # module:qualname
    description: str
    old: str = ""  # source mutation: exact snippet ...
    new: str = ""  # ... replaced by this
    patch: Callable[[], None] | None = None  # or a custom patch
    pure_decoder: bool = False  # needs the pure-Python arithmetic decoder
    family: str = "suite"  # "suite": written with the cases; "independent": from the spec notes only
    rule: str = ""  # the spec-notes rule it breaks (independent mutants)
    equivalent: str = ""  # non-empty: why no stream can tell it from the reference (not scored)


def _owner(where: str):
    mod_name, qual = where.split(":")
    mod = importlib.import_module(mod_name)
    owner = mod
    parts = qual.split(".")
    for p in parts[:-1]:
        owner = getattr(owner, p)
    return mod, owner, parts[-1]


def function_source(where: str) -> str:
    """The dedented source of ``module:qualname``."""
    _, owner, attr = _owner(where)
    raw = inspect.getattr_static(owner, attr)
    fn = raw.__func__ if isinstance(raw, (staticmethod, classmethod)) else raw
    return textwrap.dedent(inspect.getsource(fn))


def snippet_count(m: Mutant) -> int:
    """How often a source mutant's snippet occurs in its function (must be 1); 1 for patches."""
    return 1 if m.patch is not None else function_source(m.where).count(m.old)


def source_patch(where: str, old: str, new: str) -> None:
    """Replace ``old`` (must occur exactly once) by ``new`` in the source of ``module:qualname``,
    recompile it in the module's namespace and install it."""
    mod, owner, attr = _owner(where)
    raw = inspect.getattr_static(owner, attr)
    src = function_source(where)
    n = src.count(old)
    if n != 1:
        raise RuntimeError(f"mutant source snippet occurs {n} times in {where} (must be once): {old!r}")
    ns: dict = {}
    exec(compile(src.replace(old, new), f"<mutant of {where}>", "exec"), mod.__dict__, ns)  # noqa: S102 - a mutant recompiles the reference function from its own source
    obj = ns[attr]
    if isinstance(raw, staticmethod) and not isinstance(obj, staticmethod):
        obj = staticmethod(obj)
    setattr(owner, attr, obj)
    if owner is mod:
        _rebind(raw, obj)


def _rebind(old, new) -> None:
    """Point every fbaconf module's name for ``old`` at ``new``: a module that did ``from m import
    f`` holds its own reference to ``f``, which a patch of ``m.f`` alone leaves unchanged (imports
    sit at the top of modules, so the caller is loaded before any mutant is applied)."""
    for name, module in list(sys.modules.items()):
        if module is None or not (name == "fbaconf" or name.startswith("fbaconf.")):
            continue
        for key, value in list(vars(module).items()):
            if value is old:
                setattr(module, key, new)


def pure_decoder() -> None:
    """Switch the C arithmetic decoder off for this process."""
    arith.native_decoder = lambda: None


def apply_mutant(m: Mutant) -> Mutant:
    """Apply ``m`` to this process (irreversible)."""
    if m.pure_decoder:
        pure_decoder()
    if m.patch is not None:
        m.patch()
    else:
        source_patch(m.where, m.old, m.new)
    return m
