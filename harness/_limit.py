"""Launcher that applies resource limits, then execs the decoder (no shell, no preexec_fn).

Run as ``python -I -S _limit.py AS_BYTES FSIZE_BYTES CPU_S -- argv...``. Kept free of
imports beyond the standard library's ``os``/``resource``/``sys`` so it starts in
milliseconds. A limit of 0 means "not set". Exit code 127 with a message on stderr when
the program cannot be started (not found, not executable).
"""
import os
import resource
import sys


def _set(which, value):
    if value > 0:
        soft, hard = resource.getrlimit(which)
        if hard != resource.RLIM_INFINITY:
            value = min(value, hard)
        resource.setrlimit(which, (value, value if hard == resource.RLIM_INFINITY else hard))


def main():
    a = sys.argv
    if len(a) < 6 or a[4] != "--":
        sys.stderr.write("fbaconf-limit: usage: AS FSIZE CPU -- argv...\n")
        os._exit(126)
    as_bytes, fsize, cpu = int(a[1]), int(a[2]), int(a[3])
    _set(resource.RLIMIT_AS, as_bytes)
    _set(resource.RLIMIT_FSIZE, fsize)
    _set(resource.RLIMIT_CPU, cpu)
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    argv = a[5:]
    try:
        os.execvp(argv[0], argv)
    except OSError as e:
        sys.stderr.write(f"fbaconf-limit: cannot execute {argv[0]!r}: {e.strerror}\n")
        os._exit(127)


main()
