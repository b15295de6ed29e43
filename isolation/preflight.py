"""What the harness knows before it starts a decoder: whether its program can be executed.

A set-up failure must come from the harness's own knowledge, never from the decoder's text
(a decoder whose error message says "No such file or directory" is not a set-up failure:
it ran). Before a start the harness resolves the program as the decoder's environment would
(a bare name on its ``PATH``) and checks that it is a regular file it may execute, on a
filesystem that allows it, and — for a script — that its ``#!`` interpreter exists. What can
only fail inside the sandbox (a path the sandbox does not show) is reported by bubblewrap's
status (:mod:`.sandbox`: no ``exit-code`` from ``--json-status-fd`` means the decoder never ran)
and, in the fork server, by the server itself.
"""

from __future__ import annotations

import os
import stat


def resolve(prog: str, env: dict[str, str] | None) -> str | None:
    """``prog`` as the decoder's environment finds it: a path as is, a bare name on its PATH."""
    if "/" in prog:
        return prog
    for d in ((env or {}).get("PATH") or "/usr/bin:/bin").split(":"):
        p = os.path.join(d or ".", prog)
        if os.path.isfile(p) and os.access(p, os.X_OK):
            return p
    return None


def exec_problem(argv: list[str], env: dict[str, str] | None = None) -> str | None:
    """Why ``argv`` cannot be executed (a sentence starting "cannot execute"), or None."""
    prog = argv[0]
    path = resolve(prog, env)
    if path is None:
        return f"cannot execute {prog!r}: not found on the decoder's PATH"
    why = _file_problem(path)
    if why:
        return f"cannot execute {prog!r}: {why}"
    interp = _interpreter(path)
    if interp is not None:
        name, arg = interp
        if not name.startswith("/"):
            return f"cannot execute {prog!r}: its #! interpreter {name!r} is not an absolute path"
        why = _file_problem(name)
        if why:
            return f"cannot execute {prog!r}: its #! interpreter {name!r}: {why}"
        if os.path.basename(name) == "env" and arg and not arg.startswith("-") and resolve(arg, env) is None:
            return f"cannot execute {prog!r}: its #! line runs {arg!r}, which is not on the decoder's PATH"
    return None


def _file_problem(path: str) -> str | None:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "no such file"
    except OSError as e:
        return e.strerror or "cannot be read"
    if stat.S_ISDIR(st.st_mode):
        return "is a directory"
    if not stat.S_ISREG(st.st_mode):
        return "is not a regular file"
    if not os.access(path, os.X_OK):
        return "is not executable (no x permission)"
    try:
        if os.statvfs(path).f_flag & os.ST_NOEXEC:
            return "is on a filesystem mounted noexec"
    except OSError:
        pass
    return None


def _interpreter(path: str) -> tuple[str, str] | None:
    """(interpreter, first argument) of a ``#!`` script, else None."""
    try:
        with open(path, "rb") as f:
            head = f.read(256)
    except OSError:
        return None
    if not head.startswith(b"#!"):
        return None
    line = head[2:].split(b"\n", 1)[0].decode("utf-8", "replace").strip()
    parts = line.split(None, 1)
    if not parts:
        return ("", "")
    return parts[0], (parts[1].split()[0] if len(parts) > 1 and parts[1].split() else "")
