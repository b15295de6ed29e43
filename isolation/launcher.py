"""Launcher that joins the case's cgroups, applies resource limits, then execs the program
(no shell, no preexec_fn in the threaded harness).

Run as ``python -I -S launcher.py AS_BYTES FSIZE_BYTES CPU_S [--cgroup DIR]... -- argv...``.
The program is usually ``bwrap …`` (the sandbox), which then execs the decoder: limits and
cgroup membership are inherited by everything the decoder starts. Kept free of imports
beyond the standard library's ``os``/``resource``/``signal``/``sys`` so it starts in milliseconds. A
limit of 0 means "not set"; the descriptor count is always capped (``NOFILE``). Exit code 127
with a message on stderr when the program cannot be started (not found, not executable) or a
cgroup cannot be joined.
"""

import os
import resource
import signal
import sys

NOFILE = 1024  # descriptors per process: isolation/seccomp.py's NOFILE (kept free of imports here)


def _set(which: int, value: int) -> None:
    if value > 0:
        soft, hard = resource.getrlimit(which)
        if hard != resource.RLIM_INFINITY:
            value = min(value, hard)
        resource.setrlimit(which, (value, value if hard == resource.RLIM_INFINITY else hard))


def main() -> None:
    a = sys.argv
    if len(a) < 6 or "--" not in a[4:]:
        sys.stderr.write("fbaconf-limit: usage: AS FSIZE CPU [--cgroup DIR]... -- argv...\n")
        os._exit(126)
    as_bytes, fsize, cpu = int(a[1]), int(a[2]), int(a[3])
    i = 4
    while a[i] == "--cgroup":
        try:
            with open(os.path.join(a[i + 1], "cgroup.procs"), "w") as f:
                f.write(str(os.getpid()))
        except OSError as e:
            sys.stderr.write(f"fbaconf-limit: cannot join cgroup {a[i + 1]}: {e.strerror}\n")
            os._exit(127)
        i += 2
    if a[i] != "--":
        sys.stderr.write("fbaconf-limit: usage: AS FSIZE CPU [--cgroup DIR]... -- argv...\n")
        os._exit(126)
    _set(resource.RLIMIT_AS, as_bytes)
    _set(resource.RLIMIT_FSIZE, fsize)
    _set(resource.RLIMIT_CPU, cpu)
    _set(resource.RLIMIT_NOFILE, NOFILE)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    # Python starts with SIGPIPE and SIGXFSZ ignored, and an ignored signal stays ignored
    # across exec: without this a decoder past the file-size limit gets EFBIG instead of
    # SIGXFSZ, and one writing to a closed pipe EPIPE instead of SIGPIPE.
    for s in (signal.SIGPIPE, signal.SIGXFSZ):
        signal.signal(s, signal.SIG_DFL)
    argv = a[i + 1 :]
    try:
        os.execvp(argv[0], argv)
    except OSError as e:
        sys.stderr.write(f"fbaconf-limit: cannot execute {argv[0]!r}: {e.strerror}\n")
        os._exit(127)


if __name__ == "__main__":
    main()
