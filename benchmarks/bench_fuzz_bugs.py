"""Time to planted bugs, FuzzBench/Magma style: each bug a patch of examples/fbadec/fbadec.c
(``benchmarks/fuzz_bugs/*.patch``: a one-byte heap overflow behind one condition of the syntax,
which ASan reports and a plain build survives), each engine given the same budget per trial and the
distilled seeds of ``fbaconf fuzz export`` (``corpus/``; ``fbaconf fuzz`` adds its own, the
conformance suites' streams), every build with ASan.

    python benchmarks/bench_fuzz_bugs.py [--bug PATCH ...] [--budget S] [--trials N]
                                         [--engines E,E,...] [--json FILE]

Engines: ``fbaconf-persistent`` (fbadec's ``--serve``), ``fbaconf-fork-server``, ``fbaconf-spawn``
(``fbaconf fuzz`` in each mode), ``aflpp`` (afl-fuzz in persistent mode on an ``AFL_USE_ASAN`` build
of ``fuzz_target_fbadec.c`` by ``afl-clang-fast -fsanitize=fuzzer``), ``libfuzzer`` (clang
``-fsanitize=fuzzer,address,undefined`` on ``fuzz_target_fbadec.c``), and ``aflpp+fbaconf-mutator``
/ ``libfuzzer+fbaconf-mutator`` (the same with fbaconf's structure-aware mutator, ``fba_mutator.c``
of the export: linked into the libFuzzer target, loaded by AFL++ as its custom mutator). An engine
that is not installed is reported with its install line. A bug that a seed already triggers is
reported as such and not scored (it measures nothing about fuzzing).

Prints one table (bug x engine: found/trials, median seconds to the bug, execs/s), then each
engine's inputs/s over one budget on fbadec without a bug (``--no-throughput``: not measured) and,
with ``--json``, ``{"bugs": {NAME: {ENGINE: {"found", "trials", "median_s", "execs_per_s"}}},
"throughput": {ENGINE: execs/s}}``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FBADEC = ROOT / "examples" / "fbadec"
BUGS = Path(__file__).resolve().parent / "fuzz_bugs"
ENGINES = (
    "fbaconf-persistent",
    "fbaconf-fork-server",
    "fbaconf-spawn",
    "aflpp",
    "libfuzzer",
    "aflpp+fbaconf-mutator",
    "libfuzzer+fbaconf-mutator",
)
INSTALL = {
    "aflpp": "apt-get install -y afl++",
    "libfuzzer": "apt-get install -y clang (Debian: libFuzzer comes with clang's runtime)",
}
ASAN = "-fsanitize=address,undefined -fno-sanitize-recover=all"
MARK = "planted"  # the function every planted bug overflows in: its name is in the ASan report

MANIFEST = """name = "fbadec-bug"
claims = ["simple@2"]
inputs = ["fba"]
outputs = ["faps"]
faps_format = "npz"
reject_exit_codes = [1]
[commands]
decode = ["{{manifest_dir}}/fbadec", "{{input}}", "{{faps_out}}"]
{serve}
[limits]
timeout_s = 10
memory_mb = 1024
memory_kind = "rss"   # ASan reserves terabytes of address space: an address-space limit stops it
output_mb = 64
"""


@dataclass
class Trial:
    found: bool
    seconds: float | None
    execs_per_s: float | None


def sh(argv: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(argv, capture_output=True, text=True, **kw)


def have(tool: str) -> bool:
    return shutil.which(tool) is not None


def unavailable(engine: str) -> str | None:
    engine = engine.removesuffix("+fbaconf-mutator")
    if engine == "aflpp" and not (have("afl-fuzz") and have("afl-clang-fast")):
        return f"not installed: {INSTALL['aflpp']}"
    if engine == "libfuzzer" and not have("clang"):
        return f"not installed: {INSTALL['libfuzzer']}"
    return None


def build(bug: Path | None, work: Path, export: Path, engines: list[str]) -> dict[str, Path]:
    """The bug's fbadec (a patched copy; None: fbadec as it is) built for each engine that will run;
    a build that fails raises with the compiler's words."""
    src = work / "src"
    shutil.copytree(FBADEC, src, ignore=shutil.ignore_patterns("fbadec", "fbadec-asan", "*.o"))
    p = sh(["patch", "-s", "-p1", "-d", str(src), "-i", str(bug)]) if bug is not None else None
    if p is not None and p.returncode:
        raise RuntimeError(f"{bug.name}: the patch does not apply: {p.stdout}{p.stderr}")
    out: dict[str, Path] = {}
    cc = os.environ.get("CC", "cc")
    files = [str(src / "fbadec.c"), str(src / "main.c")]
    if any(e.startswith("fbaconf") for e in engines):
        for mode, serve in (("serve", 'serve = ["{manifest_dir}/fbadec", "--serve"]'), ("plain", "")):
            d = work / f"fbaconf-{mode}"
            d.mkdir()
            _cc([cc, "-O1", "-g", *ASAN.split(), "-o", str(d / "fbadec"), *files])
            (d / "fbadec.toml").write_text(MANIFEST.format(serve=serve))
            out[f"manifest-{mode}"] = d / "fbadec.toml"
    # the judge of every engine's crash: ASan alone, whose report names the function (UBSan, first
    # to see the planted store in the other builds, names only a line)
    _cc([cc, "-O1", "-g", "-fsanitize=address", "-o", str(work / "judge"), *files])
    out["judge"] = work / "judge"
    target = [str(export / "fuzz_target_fbadec.c"), str(src / "fbadec.c")]
    if any(e.startswith("aflpp") for e in engines):
        # the libFuzzer target in AFL++'s persistent mode (afl-clang-fast links its libFuzzer driver):
        # AFL++'s recommended form for a decoding function, one process for many inputs
        env = dict(os.environ, AFL_USE_ASAN="1", AFL_QUIET="1")
        afl = ["afl-clang-fast", "-g", "-O1", "-fsanitize=fuzzer", "-I", str(src), "-o", str(work / "fbadec-afl")]
        _cc([*afl, *target], env=env)
        out["aflpp"] = work / "fbadec-afl"
    if "aflpp+fbaconf-mutator" in engines:
        _cc([cc, "-O2", "-shared", "-fPIC", "-DFBA_AFL", str(export / "fba_mutator.c"), "-o", str(work / "m.so")])
        out["mutator.so"] = work / "m.so"
    flags = ["clang", "-g", "-O1", "-fsanitize=fuzzer,address,undefined", "-I", str(src)]
    if "libfuzzer" in engines:
        _cc([*flags, "-o", str(work / "fz"), *target])
        out["libfuzzer"] = work / "fz"
    if "libfuzzer+fbaconf-mutator" in engines:
        # the mutator built on its own, neither instrumented nor sanitized (as the docs say): its own
        # branches are no coverage of the target, and it runs at full speed
        mo = work / "fba_mutator.o"
        _cc(["clang", "-O2", "-c", "-DFBA_LIBFUZZER", str(export / "fba_mutator.c"), "-o", str(mo)])
        _cc([*flags, "-o", str(work / "fzm"), *target, str(mo)])
        out["libfuzzer+fbaconf-mutator"] = work / "fzm"
    return out


def _cc(argv: list[str], env: dict[str, str] | None = None) -> None:
    p = sh(argv, env=env)
    if p.returncode:
        raise RuntimeError(f"build failed: {' '.join(argv)}\n{p.stderr[-2000:]}")


def planted(judge: Path, crash: Path) -> bool:
    """Whether ``crash`` makes the ASan build report the planted overflow (not some other bug)."""
    return MARK in sh([str(judge), str(crash), os.devnull], timeout=60).stderr


def seed_triggers(judge: Path, seeds: list[Path]) -> str | None:
    """The first seed on which the ASan build reports the planted bug, if any."""
    return next((s.name for s in seeds if planted(judge, s)), None)


def run_trial(engine: str, built: dict[str, Path], export: Path, budget: float, seed: int, work: Path) -> Trial:
    if engine.startswith("fbaconf-"):
        return run_fbaconf(engine.removeprefix("fbaconf-"), built, export, budget, seed, work)
    if engine.startswith("aflpp"):
        mutator = built.get("mutator.so") if "+" in engine else None
        return run_aflpp(built["aflpp"], built["judge"], export, budget, seed, work, mutator)
    return run_libfuzzer(built[engine], built["judge"], export, budget, seed, work)


def run_fbaconf(mode: str, built: dict[str, Path], export: Path, budget: float, seed: int, work: Path) -> Trial:
    manifest = built["manifest-serve" if mode == "persistent" else "manifest-plain"]
    out = work / f"fz-{mode}-{seed}"
    argv = [sys.executable, "-m", "fbaconf", "fuzz", "--decoder", str(manifest), "--seconds", str(budget)]
    argv += ["--seed", str(seed), "-o", str(out), "--no-progress", "--json", "--minimise-seconds", "1"]
    argv += ["--seeds", str(export / "corpus")] + (["--spawn"] if mode == "spawn" else [])
    p = sh(argv, timeout=budget * 4 + 120)
    doc = _json_tail(p.stdout)
    times = []
    for f in sorted((out / "findings").glob("*/finding.json")):
        doc_f = json.loads(f.read_text())
        original = next(f.parent.glob("original.*"), None)
        if doc_f.get("class") == "crash" and original is not None and planted(built["judge"], original):
            times.append(float(doc_f.get("found_at_s", 0.0)))
    return Trial(bool(times), min(times) if times else None, doc.get("execs_per_s") if doc else None)


def _json_tail(text: str) -> dict:
    i = text.find("{")
    try:
        return json.loads(text[i:]) if i >= 0 else {}
    except ValueError:
        return {}


def run_aflpp(
    binary: Path, judge: Path, export: Path, budget: float, seed: int, work: Path, mutator: Path | None = None
) -> Trial:
    out = work / f"afl-{seed}{'-m' if mutator else ''}"
    env = dict(
        os.environ,
        AFL_SKIP_CPUFREQ="1",
        AFL_NO_UI="1",
        AFL_NO_AFFINITY="1",
        AFL_I_DONT_CARE_ABOUT_MISSING_CRASHES="1",
        AFL_BENCH_UNTIL_CRASH="1",
        **({"AFL_CUSTOM_MUTATOR_LIBRARY": str(mutator)} if mutator else {}),
    )
    argv = ["afl-fuzz", "-i", str(export / "corpus"), "-o", str(out), "-x", str(export / "fba.dict")]
    argv += ["-t", "1000+", "-V", str(int(budget)), "-s", str(seed), "--", str(binary)]
    t0 = time.time()
    sh(argv, env=env, timeout=budget + 120)
    stats = _afl_stats(out / "default" / "fuzzer_stats")
    crashes = sorted((out / "default" / "crashes").glob("id:*"), key=lambda p: p.stat().st_mtime)
    for c in crashes:
        if planted(judge, c):
            start = float(stats.get("start_time", t0))
            return Trial(True, max(0.0, c.stat().st_mtime - start), _f(stats.get("execs_per_sec")))
    return Trial(False, None, _f(stats.get("execs_per_sec")))


def _afl_stats(path: Path) -> dict[str, str]:
    if not path.is_file():
        return {}
    return {k.strip(): v.strip() for k, _, v in (ln.partition(":") for ln in path.read_text().splitlines())}


def _f(v: str | None) -> float | None:
    try:
        return float(v) if v is not None else None
    except ValueError:
        return None


def run_libfuzzer(binary: Path, judge: Path, export: Path, budget: float, seed: int, work: Path) -> Trial:
    new = work / f"lf-{binary.name}-{seed}"
    new.mkdir()
    argv = [str(binary), f"-dict={export / 'fba.dict'}", f"-seed={seed}", f"-max_total_time={int(budget)}"]
    argv += ["-timeout=10", "-entropic_scale_per_exec_time=1", "-print_final_stats=1", f"-artifact_prefix={new}/"]
    argv += [str(new), str(export / "corpus")]
    t0 = time.perf_counter()
    p = sh(argv, timeout=budget + 120)
    wall = time.perf_counter() - t0
    execs = re.search(r"stat::number_of_executed_units:\s*(\d+)", p.stderr)
    rate = int(execs.group(1)) / wall if execs and wall > 0 else None
    crash = next(iter(sorted(new.glob("crash-*"))), None)
    found = crash is not None and planted(judge, crash)
    return Trial(found, wall if found else None, rate)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bug", action="append", type=Path, default=[], help="a patch of examples/fbadec/fbadec.c")
    ap.add_argument("--budget", type=float, default=60.0, help="seconds per trial (default 60)")
    ap.add_argument("--trials", type=int, default=3, help="trials per bug and engine (default 3; 0: no bug)")
    ap.add_argument("--engines", default=",".join(ENGINES), help="comma-separated (default: all)")
    ap.add_argument("--json", type=Path, help="write the results here")
    ap.add_argument(
        "--throughput", action=argparse.BooleanOptionalAction, default=True,
        help="also run each engine one budget on fbadec without a bug for its inputs/s (default on)",
    )  # fmt: skip
    a = ap.parse_args()
    engines = [e.strip() for e in a.engines.split(",") if e.strip()]
    bad = [e for e in engines if e not in ENGINES]
    if bad:
        ap.error(f"unknown engine(s) {bad}; known: {', '.join(ENGINES)}")
    bugs = ([b.resolve() for b in a.bug] or sorted(BUGS.glob("*.patch"))) if a.trials > 0 else []  # 0: inputs/s only
    notes = {e: why for e in engines if (why := unavailable(e))}
    runnable = [e for e in engines if e not in notes]
    results: dict[str, dict[str, dict]] = {}
    t_all = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fbaconf-bugs-") as tmp:
        export = Path(tmp) / "export"
        sh([sys.executable, "-m", "fbaconf", "fuzz", "export", str(export)], check=True)
        # the seeds an engine is given (corpus/) and the rest of the small ones; the long streams of
        # stress/ take seconds each under ASan and no engine here starts from them
        seeds = sorted(p for d in ("corpus", "more") for p in (export / d).glob("*.fba"))
        for bug in bugs:
            name = bug.name.removesuffix(".patch")
            work = Path(tmp) / name
            work.mkdir()
            row: dict[str, dict] = {}
            try:
                built = build(bug, work, export, runnable)
            except RuntimeError as e:
                print(f"{name}: {e}", file=sys.stderr)
                continue
            hit = seed_triggers(built["judge"], seeds)
            if hit:
                results[name] = {"_seed_triggered": {"seed": hit}}
                print(f"{name}: the seed {hit} triggers it already: not scored")
                continue
            for engine in engines:
                if engine in notes:
                    row[engine] = {"found": 0, "trials": 0, "median_s": None, "execs_per_s": None}
                    row[engine]["note"] = notes[engine]
                    continue
                trials = [run_trial(engine, built, export, a.budget, s, work) for s in range(a.trials)]
                times = [t.seconds if t.found and t.seconds is not None else a.budget * 2 for t in trials]
                found = sum(t.found for t in trials)
                rates = [t.execs_per_s for t in trials if t.execs_per_s]
                row[engine] = {
                    "found": found,
                    "trials": len(trials),
                    # unfound trials count as twice the budget (Magma's convention for a median over misses)
                    "median_s": round(statistics.median(times), 1) if found * 2 > len(trials) else None,
                    "execs_per_s": round(statistics.median(rates), 1) if rates else None,
                }
            results[name] = row
            print(_row(name, row, engines), flush=True)
        rates: dict[str, float | None] = {}
        if a.throughput:
            # inputs/s on the parser itself (fbadec without a bug), a whole budget each: a trial that
            # finds its bug at once is mostly the engine's start and says little about its speed
            work = Path(tmp) / "no-bug"
            work.mkdir()
            built = build(None, work, export, runnable)
            rates = {e: run_trial(e, built, export, a.budget, 0, work).execs_per_s for e in runnable}
            base = rates.get("fbaconf-persistent")
            print(f"inputs/s on fbadec without a bug ({a.budget:g} s each):")
            for e, r in rates.items():
                ratio = f"  ({r / base:.1f}x fbaconf-persistent)" if r and base and e != "fbaconf-persistent" else ""
                print(f"  {e:28s} {r:9,.0f}{ratio}" if r else f"  {e:28s} -")
    print(f"budget {a.budget:g} s x {a.trials} trial(s); wall {time.perf_counter() - t_all:.0f} s")
    for e, why in notes.items():
        print(f"{e}: {why}")
    if a.json:
        a.json.write_text(json.dumps({"bugs": results, "throughput": rates}, indent=1) + "\n")
    return 0


def _row(name: str, row: dict[str, dict], engines: list[str]) -> str:
    cells = []
    for e in engines:
        r = row.get(e, {})
        if not r.get("trials"):
            cells.append(f"{e}: -")
            continue
        med = f"{r['median_s']:g} s" if r["median_s"] is not None else "not found"
        rate = f", {r['execs_per_s']:,.0f}/s" if r.get("execs_per_s") else ""
        cells.append(f"{e}: {r['found']}/{r['trials']} {med}{rate}")
    return f"{name:24s} " + " | ".join(cells)


if __name__ == "__main__":
    sys.exit(main())
