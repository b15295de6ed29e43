"""Processes a test looks for: the fork servers and persistent decoders still alive."""

from __future__ import annotations

import os
import time
from pathlib import Path

# what the command line of a server's process tree holds (the launcher, bwrap, the server, and the
# decoder started by ``serve``): the server in C or in Python, or a persistent decoder
SERVER_MARKS = ("fbaconf-forkserver --fds", "forkserver.py --fds", " --serve")


def alive(tag: str, grace_s: float = 0.0) -> list[str]:
    """Command lines of the live fork-server and persistent-decoder processes (not zombies) whose
    command line names ``tag``; waits up to ``grace_s`` for them to go."""
    end = time.monotonic() + grace_s
    while True:
        out = []
        for d in Path("/proc").iterdir():
            if not d.name.isdigit():
                continue
            try:
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
                state = (d / "stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if tag in cmd and any(m in cmd for m in SERVER_MARKS) and state != "Z" and int(d.name) != os.getpid():
                out.append(f"{d.name}: {cmd[:200]}")
        if not out or time.monotonic() >= end:
            return out
        time.sleep(0.1)
