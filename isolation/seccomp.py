"""A seccomp filter for sandboxed decoders: no inotify or fanotify instances.

inotify instances are counted per user, and a user namespace's count is charged to its
parent's too: a decoder in bubblewrap's namespace (root inside, root outside) that opens 128
of them takes every inotify instance root has on the host until it dies — the file managers,
the editors, systemd. A decoder has no use for file-change notification, so the sandbox
refuses the calls that create the instances (``inotify_init``, ``inotify_init1``,
``fanotify_init``) with ``EMFILE``, the error a process at the per-user limit gets; every
other call is allowed. The per-process descriptor count is capped by ``RLIMIT_NOFILE``
(:data:`NOFILE`, set by the launcher and the fork server).

The filter is classic BPF, written here (no libseccomp): it checks the calling convention
(x86-64, i386 — an x86-64 program can call the i386 table — and AArch64; x32 calls are
refused with ``ENOSYS``) and the call number. bubblewrap loads it (``--seccomp FD``) for
everything in the sandbox.
"""
from __future__ import annotations

import errno
import os
import platform
import struct

NOFILE = 1024  # descriptors per decoder process (RLIMIT_NOFILE)

_LD_W_ABS, _JEQ, _JGE, _RET = 0x20, 0x15, 0x35, 0x06
_ALLOW = 0x7FFF0000
_ERRNO = 0x00050000
_X32 = 0x40000000
# calling convention -> the numbers of inotify_init, inotify_init1, fanotify_init there
_DENIED = {0xC000003E: (253, 294, 300),  # x86-64
           0x40000003: (291, 332, 338),  # i386
           0xC00000B7: (26, 262)}  # AArch64 (no inotify_init)


def supported() -> bool:
    """Whether this machine's architecture is one the filter knows."""
    return platform.machine() in ("x86_64", "amd64", "aarch64", "arm64")


def program() -> bytes:
    """The filter as ``struct sock_filter`` records (what ``--seccomp FD`` reads)."""
    ins: list[tuple] = [(_LD_W_ABS, 0, 0, 4)]  # the calling convention (seccomp_data.arch)
    for i, arch in enumerate(_DENIED):
        ins.append((_JEQ, f"arch{i}", None, arch))
    ins.append((_RET, 0, 0, _ALLOW))
    for i, (arch, numbers) in enumerate(_DENIED.items()):
        ins.append(("label", f"arch{i}"))
        ins.append((_LD_W_ABS, 0, 0, 0))  # the call number (seccomp_data.nr)
        if arch == 0xC000003E:
            ins.append((_JGE, "enosys", None, _X32))
        for n in numbers:
            ins.append((_JEQ, "deny", None, n))
        ins.append((_RET, 0, 0, _ALLOW))
    ins += [("label", "deny"), (_RET, 0, 0, _ERRNO | errno.EMFILE),
            ("label", "enosys"), (_RET, 0, 0, _ERRNO | errno.ENOSYS)]
    labels, code = {}, []
    for item in ins:
        if item[0] == "label":
            labels[item[1]] = len(code)
        else:
            code.append(item)
    out = b""
    for at, (op, jt, jf, k) in enumerate(code):
        t = labels[jt] - at - 1 if isinstance(jt, str) else 0
        f = labels[jf] - at - 1 if isinstance(jf, str) else 0
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
