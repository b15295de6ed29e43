"""The lab's bounds on a decoder: the ceilings a manifest's ``[limits]`` may ask for, and what
is actually in force on this machine.

A manifest asks; the lab decides. Each limit a manifest gives must be a real limit and at most
the lab's ceiling: ``memory_kind = "none"``, ``memory_mb = 0`` and values above a ceiling are
refused (a manifest error, exit 2, naming the key, the value, the ceiling and the flag that
raises it) — never capped silently, so the limits a run states are the manifest's own. The
ceilings have safe defaults (:data:`DEFAULT_CEILINGS`, the one place they are set); the lab
raises them on the command line of ``run``, ``certify``, ``bench`` and ``fuzz``
(``--max-timeout-s``, ``--max-memory-mb``, ``--max-output-mb``, ``--max-processes``), up to the
sane bounds of :class:`~fbaconf.isolation.sandbox.Limits`.

:func:`in_force` says, per limit, what holds a decoder on this machine and by which means: the
cgroup of its whole process tree, an rlimit per process, or sampling — so that a run without
writable cgroups never reads as if memory were limited for the tree.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass, fields

from fbaconf.errors import FbaconfInputError

from . import cgroups, sandbox, seccomp
from .sandbox import MAX_MEMORY_MB, MAX_OUTPUT_MB, MAX_PROCESSES, MAX_TIMEOUT_S, Limits
from .subject import Decoder

# memory_kind values a manifest may give: each one a limit ("none" is not)
MANIFEST_MEMORY_KINDS = ("tree", "address-space", "rss")


@dataclass(frozen=True)
class Ceilings:
    """The most a manifest may ask for, per limit."""

    timeout_s: float = 600.0
    memory_mb: int = 4096
    output_mb: int = 1024
    processes: int = 256

    def __post_init__(self) -> None:
        for name, v, hi in (
            ("timeout_s", self.timeout_s, MAX_TIMEOUT_S),
            ("memory_mb", self.memory_mb, MAX_MEMORY_MB),
            ("output_mb", self.output_mb, MAX_OUTPUT_MB),
            ("processes", self.processes, MAX_PROCESSES),
        ):
            ok = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v) and 0 < v <= hi
            if not ok or (name != "timeout_s" and not isinstance(v, int)):
                kind = "number" if name == "timeout_s" else "whole number"
                raise ValueError(f"the lab's ceiling {FLAGS[name]} must be a {kind} in (0, {hi:g}], not {v!r}")


DEFAULT_CEILINGS = Ceilings()
FLAGS = {
    "timeout_s": "--max-timeout-s",
    "memory_mb": "--max-memory-mb",
    "output_mb": "--max-output-mb",
    "processes": "--max-processes",
}


def problems(limits: Limits, ceilings: Ceilings = DEFAULT_CEILINGS) -> list[str]:
    """What in ``limits`` (a manifest's) the lab does not allow: no limit, or past a ceiling."""
    out = []
    if limits.memory_kind not in MANIFEST_MEMORY_KINDS:
        out.append(
            f'memory_kind = "{limits.memory_kind}" is no limit: the lab always limits memory '
            f"(give {', '.join(repr(k) for k in MANIFEST_MEMORY_KINDS)})"
        )
    if limits.memory_mb <= 0:
        out.append(
            f"memory_mb = {limits.memory_mb} is no limit: give the megabytes the decoder needs, at most "
            f"{ceilings.memory_mb}"
        )
    for f in fields(Ceilings):
        asked, most = getattr(limits, f.name), getattr(ceilings, f.name)
        if asked > most:
            out.append(
                f"{f.name} = {_num(asked)} is over the lab's ceiling of {_num(most)} (the lab raises it "
                f"with {FLAGS[f.name]})"
            )
    return out


def limits_in_force(adapter: Decoder) -> list[str]:
    """What holds ``adapter``'s decoder on this machine, one line per limit and how it is
    enforced (:func:`in_force`; an in-process adapter: what it runs without): what ``run``
    prints and a certificate's statement records."""
    if adapter.kind != "command":
        return [
            f"in-process: {adapter.name} runs inside fbaconf's own process: the timeout "
            f"({adapter.limits.timeout_s:g} s) is checked after each call; no memory, output or process limit"
        ]
    return in_force(adapter.limits)


def _num(v: float) -> str:
    return str(v) if isinstance(v, int) else f"{v:g}"


def in_force(limits: Limits) -> list[str]:
    """One line per limit: what holds a decoder run under ``limits`` here, and how."""
    ctl = cgroups.controllers()
    sandboxed = sandbox.isolation() == "bwrap"  # read through the module, as every caller does
    tree = "memory" in ctl
    mb = limits.memory_mb
    if limits.memory_kind == "tree" and tree:
        memory = f"memory: {mb} MB over the whole process tree (cgroup memory limit; OOM events read from the kernel)"
    elif limits.memory_kind == "tree":
        memory = (
            f"memory: {mb} MB of address space per process (RLIMIT_AS) — no cgroup here, so NOT over the "
            f"whole tree: each process of the decoder may use {mb} MB"
        )
    elif limits.memory_kind == "address-space":
        memory = f"memory: {mb} MB of address space per process (RLIMIT_AS, as the manifest asks)" + (
            f", and {mb} MB over the whole tree (cgroup)" if tree else ""
        )
    elif limits.memory_kind == "rss":
        memory = f"memory: {mb} MB resident over the whole tree, sampled every 10 ms" + (
            f", and {mb} MB over the whole tree (cgroup)" if tree else ""
        )
    else:
        memory = "memory: NOT limited"
    processes = (
        f"processes: {limits.processes} in the tree (cgroup pids limit)"
        if "pids" in ctl
        else "processes: NOT limited (no writable pids cgroup here)"
    )
    filt = (
        "seccomp: no inotify/fanotify instances, no new namespaces"
        if sandboxed and seccomp.supported()
        else "seccomp: none (no sandbox, or an architecture the filter does not know)"
    )
    return [
        f"time: {limits.timeout_s:g} s wall clock per run (the whole process group killed), "
        f"{int(max(1, limits.timeout_s * 2 + 1))} s CPU per process (RLIMIT_CPU)",
        memory,
        f"output: {limits.output_mb} MB per file (RLIMIT_FSIZE) and in total in its folder (watched while it runs)",
        processes,
        f"descriptors: {seccomp.NOFILE} per process; no core dumps; {filt}",
    ]


class CeilingError(FbaconfInputError):
    """A ceiling the lab gave on the command line is not a bound (exit 2)."""

    rule = "usage"


def add_ceiling_options(parser: argparse.ArgumentParser) -> None:
    """The lab's flags that raise the ceilings (``run``, ``certify``, ``bench``, ``fuzz``)."""
    for key, flag in FLAGS.items():
        dflt = getattr(DEFAULT_CEILINGS, key)
        parser.add_argument(
            flag,
            type=float if key == "timeout_s" else int,
            default=dflt,
            metavar="N",
            help=f"the most a manifest's {key} may ask for (default {dflt:g}); a manifest asking more is refused",
        )


def ceilings_from(args: argparse.Namespace) -> Ceilings:
    """The ceilings the lab gave on the command line (:func:`add_ceiling_options`)."""
    try:
        return Ceilings(**{key: getattr(args, flag.lstrip("-").replace("-", "_")) for key, flag in FLAGS.items()})
    except ValueError as e:
        raise CeilingError(str(e)) from None
