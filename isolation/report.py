"""How isolated a decoder runs on this machine: the one report ``run`` prints, ``certify`` refuses
by or records in its statement, and ``certify verify`` repeats (it was worded by three rule sets).

:func:`report` reads the machine — bubblewrap (or ``FBACONF_SANDBOX=none``), the writable cgroup
controllers, the seccomp filter — and, for a decoder, the limits in force
(:func:`.bounds.limits_in_force`). An in-process adapter runs inside fbaconf: no sandbox applies.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from . import bounds, cgroups, sandbox, seccomp
from .subject import Decoder


@dataclass(frozen=True)
class IsolationReport:
    """What isolates a decoder here; ``missing`` says, in words, what is not there and what that
    leaves open (empty when everything is)."""

    bubblewrap: bool
    switched_off: bool  # FBACONF_SANDBOX=none: bubblewrap there, but not used
    controllers: frozenset[str]
    seccomp: bool
    missing: tuple[str, ...]
    in_process: bool = False  # the decoder runs inside fbaconf (no sandbox applies)
    name: str = ""
    limits: tuple[str, ...] = ()  # the limits in force, one line each

    @property
    def complete(self) -> bool:
        """Whether nothing is missing (an in-process adapter is a bundled, trusted one)."""
        return self.in_process or not self.missing

    def line(self) -> str:
        """What the machine gives, in one phrase."""
        if not self.missing:
            return "isolated: bubblewrap sandbox, cgroup memory and process limits, seccomp filter"
        return "not isolated: " + "; ".join(self.missing)

    def notice(self) -> str:
        """The line ``run`` and ``certify`` print before any case."""
        if self.bubblewrap:
            here = "decoders run in a bubblewrap sandbox on this machine" + (
                "" if not self.missing else " — NOT fully isolated: " + "; ".join(self.missing)
            )
        else:
            why = "switched off (FBACONF_SANDBOX=none)" if self.switched_off else "not available"
            here = (
                f"WARNING: bubblewrap (bwrap) is {why}: decoders run UNISOLATED on this machine — they can "
                "read the goldens and write outside their folder. Install it (Debian: apt-get install "
                "bubblewrap); certify refuses to run a decoder without it unless told --allow-unisolated"
            )
        if self.in_process:
            return f"fbaconf: isolation: {self.name} runs inside fbaconf (no sandbox applies); {here}"
        return f"fbaconf: isolation: {here}; limits in force: " + "; ".join(self.limits)

    def statement(self) -> str:
        """How the decoder of a certificate ran, for its statement."""
        if self.in_process:
            return "in-process (a bundled, trusted Python adapter)"
        if self.missing:
            return "not isolated: " + "; ".join(self.missing) + " (--allow-unisolated)"
        return "bubblewrap sandbox (own PID, network, IPC namespaces; the view of docs/harness.md) and cgroups"


def report(adapter: Decoder | None = None) -> IsolationReport:
    """The machine's isolation, and ``adapter``'s limits in force (a command decoder) or that it
    runs in-process."""
    bw = sandbox.isolation() == "bwrap"
    ctl = cgroups.controllers()
    missing = []
    if not bw:
        missing.append(
            "bubblewrap (bwrap): decoders run unsandboxed, seeing the whole machine, its network and its processes"
        )
    if "memory" not in ctl:
        missing.append(
            "writable cgroups with the memory controller: no memory limit on a decoder's whole process "
            "tree (an address-space limit per process instead: three 800 MB children pass a 1 GB limit)"
        )
    if "pids" not in ctl:
        missing.append("writable cgroups with the pids controller: no limit on the processes a decoder starts")
    if bw and not seccomp.supported():
        missing.append(
            "the seccomp filter (an architecture it does not know): a decoder can take the host user's "
            "inotify instances"
        )
    in_process = adapter is not None and adapter.kind != "command"
    return IsolationReport(
        bw,
        os.environ.get("FBACONF_SANDBOX") == "none",
        frozenset(ctl),
        bw and seccomp.supported(),
        tuple(missing),
        in_process,
        adapter.name if adapter is not None else "",
        tuple(bounds.limits_in_force(adapter)) if adapter is not None else (),
    )
