"""A seccomp filter for sandboxed decoders: no inotify or fanotify instances, no new namespaces.

Both are kernel objects counted per host user, and a user namespace's count is charged to its
parent's too: a decoder in bubblewrap's namespace (root inside, root outside) that opens 128
inotify instances takes every one root has on the host until it dies — the file managers,
the editors, systemd; one that nests user and mount namespaces takes the host user's
namespaces (``user.max_user_namespaces`` and its kin count them per user), so that a root
process outside cannot ``unshare -U`` and a concurrent case's sandbox cannot start. A decoder
has no use for either, so the sandbox refuses:

* ``inotify_init``, ``inotify_init1``, ``fanotify_init`` — with ``EMFILE``, the error a
  process at the per-user limit gets;
* ``unshare`` and ``clone`` with any namespace flag (``CLONE_NEWNS``, ``CLONE_NEWUSER``,
  ``CLONE_NEWPID``, ``CLONE_NEWNET``, ``CLONE_NEWIPC``, ``CLONE_NEWUTS``, ``CLONE_NEWCGROUP``,
  ``CLONE_NEWTIME``), and ``setns`` always — with ``EPERM``, what an unprivileged process
  gets; ``clone``/``unshare`` without those flags (threads, ``fork``) are allowed;
* ``clone3`` — with ``ENOSYS``: its flags are in a structure a seccomp filter cannot read,
  and every C library and runtime falls back to ``clone`` on ``ENOSYS``.

Every other call is allowed. bubblewrap loads the filter (``--seccomp FD``) for the decoder
after it has made the sandbox's own namespaces, so the filter does not stand in its way. The
per-process descriptor count is capped by ``RLIMIT_NOFILE`` (:data:`NOFILE`, set by the
launcher and the fork server).

The filter is classic BPF, written here (no libseccomp): it checks the calling convention
(x86-64, i386 — an x86-64 program can call the i386 table — and AArch64; x32 calls are
refused with ``ENOSYS``), the call number and, for ``clone``/``unshare``, the low 32 bits of the
first argument (the flags, on all three).
"""

from __future__ import annotations

import errno
import os
import platform
import struct
from typing import TypedDict

NOFILE = 1024  # descriptors per decoder process (RLIMIT_NOFILE)

# CLONE_NEWTIME, CLONE_NEWNS, CLONE_NEWCGROUP, CLONE_NEWUTS, CLONE_NEWIPC, CLONE_NEWUSER, CLONE_NEWPID, CLONE_NEWNET
NAMESPACE_FLAGS = 0x80 | 0x20000 | 0x02000000 | 0x04000000 | 0x08000000 | 0x10000000 | 0x20000000 | 0x40000000

_LD_W_ABS, _JEQ, _JGE, _JSET, _RET = 0x20, 0x15, 0x35, 0x45, 0x06
_ALLOW = 0x7FFF0000
_ERRNO = 0x00050000
_X32 = 0x40000000
_NR, _ARCH, _ARG0 = 0, 4, 16  # offsets in struct seccomp_data (arg0's low word: little-endian)


# calling convention -> the call numbers the filter judges there
class _Calls(TypedDict):
    """An architecture's numbers of the system calls the filter decides on."""

    inotify: tuple[int, ...]
    clone: int
    unshare: int
    setns: int
    clone3: int


_CALLS: dict[int, _Calls] = {
    0xC000003E: {"inotify": (253, 294, 300), "clone": 56, "unshare": 272, "setns": 308, "clone3": 435},  # x86-64
    0x40000003: {"inotify": (291, 332, 338), "clone": 120, "unshare": 310, "setns": 346, "clone3": 435},  # i386
    0xC00000B7: {"inotify": (26, 262), "clone": 220, "unshare": 97, "setns": 268, "clone3": 435},  # AArch64
}


def supported() -> bool:
    """Whether this machine's architecture is one the filter knows."""
    return platform.machine() in ("x86_64", "amd64", "aarch64", "arm64")


# one BPF instruction (code, jump-if-true and jump-if-false: a label name, or 0 or None for the next),
# or a label naming the next instruction
_Ins = tuple[int, str | int | None, str | int | None, int]
_Label = tuple[str, str]


def _instructions() -> list[_Ins | _Label]:
    ins: list[_Ins | _Label] = [(_LD_W_ABS, 0, 0, _ARCH)]
    for i, arch in enumerate(_CALLS):
        ins.append((_JEQ, f"arch{i}", None, arch))
    ins.append((_RET, 0, 0, _ALLOW))
    for i, (arch, calls) in enumerate(_CALLS.items()):
        ins.append(("label", f"arch{i}"))
        ins.append((_LD_W_ABS, 0, 0, _NR))
        if arch == 0xC000003E:
            ins.append((_JGE, "enosys", None, _X32))
        for n in calls["inotify"]:
            ins.append((_JEQ, "emfile", None, n))
        ins.append((_JEQ, "eperm", None, calls["setns"]))
        ins.append((_JEQ, "enosys", None, calls["clone3"]))
        ins.append((_JEQ, "flags", None, calls["clone"]))
        ins.append((_JEQ, "flags", None, calls["unshare"]))
        ins.append((_RET, 0, 0, _ALLOW))
    ins += [
        ("label", "flags"),
        (_LD_W_ABS, 0, 0, _ARG0),
        (_JSET, "eperm", None, NAMESPACE_FLAGS),
        (_RET, 0, 0, _ALLOW),
        ("label", "emfile"),
        (_RET, 0, 0, _ERRNO | errno.EMFILE),
        ("label", "eperm"),
        (_RET, 0, 0, _ERRNO | errno.EPERM),
        ("label", "enosys"),
        (_RET, 0, 0, _ERRNO | errno.ENOSYS),
    ]
    return ins


def program() -> bytes:
    """The filter as ``struct sock_filter`` records (what ``--seccomp FD`` reads)."""
    labels: dict[str, int] = {}
    code: list[_Ins] = []
    for item in _instructions():
        if len(item) == 2:
            labels[item[1]] = len(code)
        else:
            code.append(item)
    out = b""
    for at, (op, jt, jf, k) in enumerate(code):
        t = labels[jt] - at - 1 if isinstance(jt, str) else 0
        f = labels[jf] - at - 1 if isinstance(jf, str) else 0
        if not (0 <= t < 256 and 0 <= f < 256):
            raise AssertionError("a seccomp jump is out of range")  # the program's own shape, not input
        out += struct.pack("=HBBI", op, t, f, k)
    return out


def program_fd() -> int:
    """A descriptor to read :func:`program` from (a pipe holding it; the caller passes it to
    bubblewrap's ``--seccomp`` and closes it after the start)."""
    r, w = os.pipe()
    try:
        os.write(w, program())
    finally:
        os.close(w)
    return r
