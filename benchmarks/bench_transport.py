"""The cost of getting one input to a decoder and its ending back, without the fuzzing loop
(input generation, the oracle, coverage): the transports alone, side by side, on one stream.

* ``bare spawn``: ``posix_spawn`` of the decoder and a wait (no sandbox, no limits);
* ``sandbox.run``: one fresh sandbox per input (``fbaconf fuzz --spawn``, ``fbaconf run``);
* ``fork server (C)`` / ``fork server (Python)``: :class:`~fbaconf.isolation.forkclient.ForkServer`;
* ``persistent``: :class:`~fbaconf.isolation.persistent.PersistentDecoder` (``[commands] serve``);
* ``bare persistent``: a loop writing the input to ``skipchain --serve`` and reading the answer.

Prints inputs/s and the ratios of its goals (fork server >= 0.5 x bare spawn, persistent
>= 10 x spawn). The planted decoder is built in its fixed form (no crash restarts).

    python benchmarks/bench_transport.py [--seconds S]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _skipchain import build
from bench_fuzz import bare_spawn

from fbaconf.conformance.suite import load_suites
from fbaconf.harness.adapters import load_manifest
from fbaconf.isolation import sandbox
from fbaconf.isolation.forkclient import ForkServer
from fbaconf.isolation.persistent import PersistentDecoder


def _loop(one, seconds: float) -> float:
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        one()
        n += 1
    return n / (time.perf_counter() - t0)


def spawn_rate(adapter, exe: Path, stream: Path, work: Path, seconds: float) -> float:
    case = work / "spawn"
    (case / "in").mkdir(parents=True)
    (case / "in" / "in.fba").write_bytes(stream.read_bytes())
    argv = [str(exe), str(case / "in" / "in.fba"), str(case / "out.fap")]
    view = sandbox.default_view(argv, case)
    return _loop(lambda: sandbox.run(argv, case, adapter.limits, view=view), seconds)


def fork_rate(adapter, exe: Path, stream: Path, work: Path, seconds: float, python: bool) -> float:
    os.environ["FBACONF_FORKSERVER"] = "python" if python else "c"
    root = work / ("fork-py" if python else "fork-c")
    case = root / "case"
    (case / "in").mkdir(parents=True)
    (case / "in" / "in.fba").write_bytes(stream.read_bytes())
    argv = [str(exe), str(case / "in" / "in.fba"), str(case / "out.fap")]
    with ForkServer(root, sandbox.default_view(argv, case), adapter.limits) as srv:
        srv.run(argv, case)
        return _loop(lambda: srv.run(argv, case), seconds)


def persistent_rate(adapter, exe: Path, stream: Path, work: Path, seconds: float) -> float:
    root = work / "serve"
    case = root / "case"
    (case / "in").mkdir(parents=True)
    argv = [str(exe), "--serve"]
    data, out = stream.read_bytes(), str(case / "out.fap")
    dec = PersistentDecoder(argv, root, case, sandbox.default_view(argv, case), adapter.limits)
    try:
        dec.run(data, out)
        return _loop(lambda: dec.run(data, out), seconds)
    finally:
        dec.close()


def bare_persistent(exe: Path, stream: Path, seconds: float) -> float:
    data = stream.read_bytes()
    p = subprocess.Popen(
        [str(exe), "--serve"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
    )
    i = 0

    def one():
        nonlocal i
        i += 1
        p.stdin.write(f"{i} {len(data)} /dev/null\n".encode() + data)
        p.stdin.flush()
        p.stdout.readline()

    try:
        return _loop(one, seconds)
    finally:
        p.stdin.close()
        p.wait()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        print("bench_transport: no C compiler; nothing measured")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="bench-transport-"))
    try:
        manifest = build(cc, tmp, "fixed", fixed=True, serve=True)
        adapter = load_manifest(manifest)
        exe = tmp / "fixed"
        stream = tmp / "in.fba"
        (suite,) = load_suites(names=["simple-l1-core"])
        stream.write_bytes(suite.cases[0].input_path("fba").read_bytes())
        s = args.seconds
        rows = {
            "bare spawn (posix_spawn loop)": bare_spawn(exe, stream, s),
            "sandbox.run (--spawn)": spawn_rate(adapter, exe, stream, tmp, s),
            "fork server (C)": fork_rate(adapter, exe, stream, tmp, s, python=False),
            "fork server (Python)": fork_rate(adapter, exe, stream, tmp, s, python=True),
            "persistent ([commands] serve)": persistent_rate(adapter, exe, stream, tmp, s),
            "bare persistent (pipe round trip)": bare_persistent(exe, stream, s),
        }
        print(f"transport throughput, {s:g} s each, one decoder at a time, {os.cpu_count()} CPUs")
        for label, rate in rows.items():
            print(f"  {label:<36} {rate:9,.0f} inputs/s")
        bare, spawn = rows["bare spawn (posix_spawn loop)"], rows["sandbox.run (--spawn)"]
        print(f"  fork server (C) / bare spawn         {rows['fork server (C)'] / bare:6.2f}   (goal >= 0.50)")
        print(f"  fork server (Python) / bare spawn    {rows['fork server (Python)'] / bare:6.2f}")
        print(
            f"  persistent / --spawn                 {rows['persistent ([commands] serve)'] / spawn:6.2f}"
            f"   (goal >= 10)"
        )
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
