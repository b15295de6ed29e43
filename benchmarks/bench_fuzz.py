"""Fuzzing throughput, measured side by side in one run.

Builds the planted test decoder (``tests/fuzz_decoders/skipchain.c``) and measures, each for
the same number of seconds on the same machine:

* ``bare spawn``: a loop that only ``posix_spawn``s the decoder on one conformance stream and
  waits (no sandbox, no limits, no input generation) — the ceiling for spawning;
* ``fuzz --spawn``: ``fbaconf fuzz`` with a fresh sandbox per input;
* ``fuzz (fork server)``: the default, one sandbox per worker, its server in C
  (``isolation/forkserver.c``, compiled on first use), and again with the Python server
  (``isolation/forkserver.py``, the fallback without a C compiler);
* ``fuzz (persistent)``: the same program through ``[commands] serve``;
* the last two again with the program built without its planted bug (``-DSKIPCHAIN_FIXED``):
  a crash costs the persistent mode a process (and sandbox) start, so these show it without;
* ``bare persistent``: a loop that only writes one input to ``skipchain --serve`` and reads
  the answer — the ceiling for the persistent protocol.

All fuzz runs are one decoder at a time (``-j 1``) with coverage measured on every 8th input
(the default: ``--coverage-every 8``), minimisation excluded from execs/s. Prints execs/s and the ratios the issue
asks for: harness vs bare spawn (goal >= 0.5), persistent vs fork server.

    python benchmarks/bench_fuzz.py [--seconds S]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _skipchain import build

from fbaconf.conformance.suite import load_suites
from fbaconf.fuzz.corpus import default_seeds
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness.adapters import load_manifest
from fbaconf.isolation import forkserver_build


def bare_spawn(exe: Path, stream: Path, seconds: float) -> float:
    out = str(stream.parent / "out.fap")
    n, t0 = 0, time.perf_counter()
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        while time.perf_counter() - t0 < seconds:
            pid = os.posix_spawn(
                str(exe), [exe.name, str(stream), out], {}, file_actions=[(os.POSIX_SPAWN_DUP2, devnull, 2)]
            )
            os.waitpid(pid, 0)
            n += 1
    finally:
        os.close(devnull)
    return n / (time.perf_counter() - t0)


def bare_persistent(exe: Path, stream: Path, seconds: float) -> float:
    data = stream.read_bytes()
    p = subprocess.Popen(
        [str(exe), "--serve"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL
    )
    n, t0 = 0, time.perf_counter()
    try:
        while time.perf_counter() - t0 < seconds:
            p.stdin.write(f"{n + 1} {len(data)} /dev/null\n".encode() + data)
            p.stdin.flush()
            p.stdout.readline()
            n += 1
    finally:
        p.stdin.close()
        p.wait()
    return n / (time.perf_counter() - t0)


def fuzz_rate(
    manifest: Path, seconds: float, work: Path, *, spawn: bool = False, c_server: bool = True
) -> tuple[float, str, int]:
    os.environ["FBACONF_FORKSERVER"] = "c" if c_server else "python"
    target = DecoderTarget(load_manifest(manifest), work, timeout_s=1.0, fork_server=not spawn, persistent=not spawn)
    mode = "persistent" if target.persistent else "spawn"
    if target.fork_server and not target.persistent:
        mode = f"fork server in {forkserver_build.server_kind()}"
    fz = Fuzzer(
        target,
        default_seeds(),
        FuzzConfig(seed=7, seconds=seconds, progress=False, coverage_every=8, minimise_seconds=2, minimise_tests=50),
    )
    fz.run()
    return fz.stats.rate, mode, fz.stats.execs


def _timed(fn, *args, **kw):
    """``fn``'s result and the CPU seconds it took, this process's and its children's: on a
    shared machine a rate far below an earlier one with CPU seconds far below the wall time is
    the machine's load, not the harness."""

    def cpu() -> float:
        me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
        return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime

    c0 = cpu()
    out = fn(*args, **kw)
    return out, cpu() - c0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    args = ap.parse_args()
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        print("bench_fuzz: no C compiler; nothing measured")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="bench-fuzz-"))
    try:
        spawn = build(cc, tmp)
        serve = build(cc, tmp, serve=True)
        fixed = build(cc, tmp, "fixed", fixed=True)  # no planted crash: no restarts
        fixed_serve = build(cc, tmp, "fixed", fixed=True, serve=True)
        exe = tmp / "skipchain"
        stream = tmp / "in.fba"
        (suite,) = load_suites(names=["simple-l1-core"])
        stream.write_bytes(suite.cases[0].input_path("fba").read_bytes())
        s = args.seconds
        load0 = os.getloadavg()[0]
        rows = [("bare spawn (posix_spawn loop)", *_timed(bare_spawn, exe, stream, s), "")]
        for label, manifest, one_shot, c_server in (
            ("fuzz --spawn", spawn, True, True),
            ("fuzz (fork server, default)", spawn, False, True),
            ("fuzz (fork server in Python)", spawn, False, False),
            ("fuzz (persistent, [commands] serve)", serve, False, True),
            ("fuzz (fork server), bug fixed", fixed, False, True),
            ("fuzz (persistent), bug fixed", fixed_serve, False, True),
        ):
            (rate, mode, execs), cpu = _timed(
                fuzz_rate, manifest, s, tmp / f"work-{len(rows)}", spawn=one_shot, c_server=c_server
            )
            rows.append((label, rate, cpu, f"{execs} inputs, mode {mode}"))
        rows.append(("bare persistent (pipe round trip)", *_timed(bare_persistent, exe, stream, s), ""))
        print(
            f"fuzzing throughput, {s:g} s each, one decoder at a time, {os.cpu_count()} CPUs, "
            f"load average {load0:.1f} -> {os.getloadavg()[0]:.1f}"
        )
        print(f"  {'':<40} {'execs/s':>9}  {'CPU s':>6}  (this process and its children: a share of the machine)")
        for label, rate, cpu, note in rows:
            print(f"  {label:<40} {rate:9,.0f}  {cpu:6.1f}  {note}")
        r = {label: rate for label, rate, _, _ in rows}
        bare = r["bare spawn (posix_spawn loop)"]
        fork = r["fuzz (fork server, default)"]
        pers = r["fuzz (persistent, [commands] serve)"]
        print(f"  harness (fork server) / bare spawn      {fork / bare:6.2f}   (goal >= 0.50)")
        print(f"  harness (fork server in Python) / bare  {r['fuzz (fork server in Python)'] / bare:6.2f}")
        print(f"  harness (--spawn) / bare spawn          {r['fuzz --spawn'] / bare:6.2f}")
        print(f"  persistent / --spawn                    {pers / r['fuzz --spawn']:6.2f}   (goal >= 10)")
        print(f"  persistent / fork server                {pers / fork:6.2f}")
        print(f"  persistent / bare spawn                 {pers / bare:6.2f}")
        fx = r["fuzz (persistent), bug fixed"] / r["fuzz (fork server), bug fixed"]
        print(f"  persistent / fork server, bug fixed     {fx:6.2f}   (no crash restarts)")
        pipe = r["bare persistent (pipe round trip)"]
        print(f"  persistent harness / bare persistent    {pers / pipe:6.2f}   (goal >= 0.10)")
        fixed = r["fuzz (persistent), bug fixed"] / pipe
        print(f"  the same, bug fixed                     {fixed:6.2f}   (no crash restarts, as in the bare loop)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
