"""What a test needs of the machine to mean anything: the sandbox (bubblewrap), its seccomp
filter, writable cgroups. Each helper skips where the machine lacks it — and fails in CI, where
a skip would hide that hostile decoders ran unisolated."""

from __future__ import annotations

import os

import pytest

from fbaconf.isolation import cgroups, sandbox, seccomp


def _missing(ci_reason: str, local_reason: str, *, ci_needs_root: bool = False) -> None:
    if os.environ.get("CI") and (not ci_needs_root or os.geteuid() == 0):
        pytest.fail(ci_reason)
    pytest.skip(local_reason)


def needs_sandbox() -> None:
    if sandbox.isolation() == "none":
        _missing(
            "bubblewrap is not available in CI: decoders would run unisolated",
            "bubblewrap (bwrap) is not installed: decoders run unisolated on this machine",
        )


def needs_seccomp_sandbox() -> None:
    if sandbox.isolation() == "none" or not seccomp.supported():
        _missing(
            "bubblewrap (with the seccomp filter) is not available in CI",
            "bubblewrap (bwrap) is not installed, or the filter does not know this architecture",
        )


def needs_cgroups() -> None:
    if not cgroups.cgroup_bases():
        _missing(
            "no writable cgroups in CI (running as root)",
            "no writable cgroup hierarchy here (not root?): no whole-tree limits",
            ci_needs_root=True,
        )


def needs_memory_cgroup() -> None:
    if "memory" not in cgroups.controllers():
        _missing(
            "no writable memory cgroup in CI (running as root)",
            "no writable memory cgroup here (not root?): no whole-tree memory limit",
            ci_needs_root=True,
        )
