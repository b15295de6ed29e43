"""Per-case cost of `fbaconf run` against a native decoder, measured side by side:
the independent C decoder (examples/fbadec, built into a temporary folder) on one
conformance stream,

* ``bare spawn``: ``posix_spawn`` + wait, nothing else — the floor;
* ``sandbox.run, prlimit launcher``: the harness's one-shot path (limits, bubblewrap when
  available, output files, the result) with util-linux ``prlimit`` as the launcher;
* ``sandbox.run, Python launcher``: the same with ``isolation/launcher.py`` (the fallback without prlimit);

and the wall time of ``fbaconf run --decoder fbadec.toml --claim simple@2 -j 1`` with each
launcher (every case: decode, read the output, compare, write the reports).

    python benchmarks/bench_run.py [--n N]
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

from fbaconf.conformance.suite import load_suites
from fbaconf.isolation import sandbox

SRC = Path(__file__).resolve().parent.parent / "examples" / "fbadec"


def bare(exe: Path, stream: Path, out: Path, n: int) -> float:
    t0 = time.perf_counter()
    for _ in range(n):
        pid = os.posix_spawn(str(exe), [exe.name, str(stream), str(out)], {})
        os.waitpid(pid, 0)
    return (time.perf_counter() - t0) / n * 1000


def harness(exe: Path, stream: Path, work: Path, n: int) -> float:
    limits = sandbox.Limits(timeout_s=10, memory_mb=256, output_mb=64)
    t0 = time.perf_counter()
    for i in range(n):
        wd = work / f"c{i}"
        (wd / "in").mkdir(parents=True)
        shutil.copy(stream, wd / "in" / "s.fba")
        r = sandbox.run(
            [str(exe), str(wd / "in" / "s.fba"), str(wd / "out.npz")],
            wd,
            limits,
            view=sandbox.View(read_only=[exe.parent], writable=[wd], read_only_inside=[wd / "in"]),
        )
        assert r.returncode == 0, r
    return (time.perf_counter() - t0) / n * 1000


def run_wall(manifest: Path, out: Path, python_launcher: bool) -> float:
    env = dict(os.environ, FBACONF_LAUNCHER="python" if python_launcher else "prlimit")
    t0 = time.perf_counter()
    subprocess.run(
        [
            sys.executable,
            "-m",
            "fbaconf",
            "run",
            "--decoder",
            str(manifest),
            "--claim",
            "simple@2",
            "-j",
            "1",
            "-o",
            str(out),
        ],
        check=True,
        capture_output=True,
        env=env,
    )
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200, help="runs per one-shot measurement")
    a = ap.parse_args()
    if not (shutil.which("cc") and shutil.which("make")):
        print("bench_run: no C compiler or make; nothing measured")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="bench-run-"))
    try:
        build = tmp / "fbadec"
        shutil.copytree(SRC, build)
        subprocess.run(["make", "-s", "-C", str(build)], check=True, capture_output=True)
        exe = build / "fbadec"
        (suite,) = load_suites(names=["simple-l1-core"])
        stream = tmp / "in.fba"
        stream.write_bytes(suite.cases[0].input_path("fba").read_bytes())
        rows = [("bare spawn", bare(exe, stream, tmp / "bare.npz", a.n))]
        os.environ["FBACONF_LAUNCHER"] = "prlimit"
        rows.append(("sandbox.run, prlimit launcher", harness(exe, stream, tmp / "p", a.n)))
        os.environ["FBACONF_LAUNCHER"] = "python"
        rows.append(("sandbox.run, Python launcher", harness(exe, stream, tmp / "y", a.n)))
        print(
            f"one case, {a.n} runs each, isolation {sandbox.isolation()}, prlimit "
            f"{'found' if shutil.which('prlimit') else 'MISSING (both rows use the Python launcher)'}"
        )
        for label, ms in rows:
            print(f"  {label:<34} {ms:7.2f} ms/case")
        print(f"  Python / prlimit launcher          {rows[2][1] / rows[1][1]:7.2f}x")
        wp = run_wall(build / "fbadec.toml", tmp / "run-p", False)
        wy = run_wall(build / "fbadec.toml", tmp / "run-y", True)
        print(f"fbaconf run fbadec simple@2 -j 1: prlimit {wp:.2f} s, Python launcher {wy:.2f} s ({wy / wp:.2f}x)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
