"""A deliberately misbehaving decoder for testing the harness (``adapters/dummy.toml``).

``python -m fbaconf.harness.dummydec --mode MODE IN.fba OUT.fap|OUT.npz``

Modes: ``ok`` (the reference's output), ``segfault`` (SIGSEGV), ``abort`` (SIGABRT), ``hang``
(busy loop forever), ``sleep`` (sleeps 1 h), ``noout`` (exit 0, writes nothing), ``garbage``
(random bytes as the output), ``huge`` (tries to write 1 GiB), ``wrong`` (the reference's
output with one value changed: frame ``--frame``, FAP ``--fap``), ``notsupported`` (exit 69),
``reject`` (exit 1 with a message), ``alloc`` (allocates 8 GiB), ``startup`` (speed model:
sleeps ``--startup`` s, then ``--per-frame`` s per decoded frame, then writes the output).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path

from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.fapio import save_faps
from fbaconf.bitstreams.frames import FREE


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="dummydec")
    ap.add_argument("--mode", default="ok")
    ap.add_argument("--frame", type=int, default=3)
    ap.add_argument("--fap", type=int, default=19)
    ap.add_argument("--startup", type=float, default=0.0)
    ap.add_argument("--per-frame", type=float, default=0.0)
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    a = ap.parse_args(argv)
    m = a.mode
    if m == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
    if m == "abort":
        os.abort()
    if m == "hang":
        while True:
            pass
    if m == "sleep":
        time.sleep(3600)
    if m == "notsupported":
        print("dummydec: this stream is not supported", file=sys.stderr)
        return 69
    if m == "reject":
        print("dummydec: invalid stream", file=sys.stderr)
        return 1
    if m == "noout":
        return 0
    if m == "garbage":
        a.output.write_bytes(os.urandom(4096))
        return 0
    if m == "huge":
        block = b"\0" * (1 << 20)
        with open(a.output, "wb") as f:
            for _ in range(1024):
                f.write(block)
        return 0
    if m == "alloc":
        x = bytearray(8 << 30)
        x[-1] = 1
        return 0
    if m == "startup":
        time.sleep(a.startup)
    frames = decode(a.input.read_bytes(), file=str(a.input)).frames
    if m == "startup":
        time.sleep(a.per_frame * len(frames))
    if m == "wrong":
        f = min(a.frame, len(frames) - 1)
        if frames.status[f, a.fap - 1] == FREE:
            frames.status[f, a.fap - 1] = 1
        frames.values[f, a.fap - 1] += 1
    save_faps(frames, a.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
