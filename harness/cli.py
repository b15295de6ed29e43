"""The harness verbs, each registered here: ``fbaconf run`` and ``fbaconf bench`` (:mod:`.speed.bench`)
(``fbaconf certify`` is the certification stage's: :mod:`fbaconf.certification.cli`).

Exit codes (docs/harness.md): 0 every required case passes (and the speed requirements when
measured); 1 some required case fails (a new failure, when ``--baseline`` is given);
2 usage or setup error; 3 only speed requirements missed; 4 only missed on a machine busy with other work
(speed inconclusive).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fbaconf.isolation.bounds import add_ceiling_options, ceilings_from


def register(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    r = sub.add_parser(
        "run",
        help="run conformance suites against a decoder",
        description="Run the conformance suites against a decoder (a manifest .toml or a bundled "
        "adapter name: reference, reference-inprocess, dummy) and report per case.",
    )
    _common(r)
    r.add_argument("--suite", action="append", default=[], help="only this suite (repeatable)")
    r.add_argument("--case", action="append", default=[], help="only cases whose id matches this glob (repeatable)")
    r.add_argument(
        "--only-required",
        action="store_true",
        help="skip cases outside the claim instead of reporting them NotSupported",
    )
    r.add_argument("-o", "--output", type=Path, default=None, help="run folder (default fbaconf-run/<decoder>)")
    r.add_argument("--resume", action="store_true", help="continue an interrupted run in the same folder")
    r.add_argument(
        "--baseline",
        type=Path,
        help="known failures/flakes (case,Outcome[,signature] lines): only new failures, and fixed cases, fail the run",
    )
    r.add_argument(
        "--flakes",
        type=Path,
        help="file of regular expressions (one per line) of case ids whose failures are accepted as flaky",
    )
    r.add_argument(
        "--retries",
        type=int,
        default=0,
        help="re-run failing cases up to N times; a case that then passes is flaky (default 0)",
    )
    r.add_argument(
        "--allow-fixed",
        action="store_true",
        help="do not fail the run when a case the baseline lists as failing now passes",
    )
    r.add_argument(
        "--write-baseline",
        type=Path,
        help="record every required case that did not pass (NotSupported "
        "included) in this baseline file; an existing file is updated, its comments, Flake lines and "
        "lines of cases not run kept",
    )
    r.add_argument("--junit", type=Path, help="write JUnit XML here")
    r.add_argument("--json", type=Path, help="write the JSON report here")
    r.add_argument("--html", type=Path, help="write the HTML report into this folder")
    r.add_argument("--speed", action="store_true", help="also measure decode/render speed against the level")
    r.set_defaults(func=cmd_run)

    _register_bench(sub)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--decoder", required=True, help="decoder manifest .toml or bundled adapter name")
    p.add_argument("--claim", help="profile@level under test (default: the decoder's highest claim)")
    p.add_argument("-j", "--jobs", type=int, default=None, help="parallel cases (default: CPU cores)")
    p.add_argument(
        "--cluster",
        metavar="local[:N]|tls://HOST:PORT",
        help="run the cases as tasks on a Dask cluster instead of the local pool",
    )
    p.add_argument("--keep-workdirs", action="store_true", help="keep each case's working folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    lab_options(p)


def lab_options(p: argparse.ArgumentParser) -> None:
    """What the lab, not the decoder's manifest, decides: the sandbox's extra read-only folders,
    the ceilings of the decoder's limits and whether provisional differences fail the claim."""
    p.add_argument(
        "--sandbox-ro",
        action="append",
        type=Path,
        default=[],
        metavar="PATH",
        help="show the decoder this folder read-only too (its runtime, e.g. a JVM); repeatable; "
        "certify records it in the statement",
    )
    add_ceiling_options(p)
    p.add_argument(
        "--strict",
        action="store_true",
        help="a failing case that rests on a provisional decision fails the claim (default: the verdict "
        "is PASS (provisional differences: N))",
    )


# ------------------------------------------------------------------ run


def cmd_run(args: argparse.Namespace) -> int:
    from fbaconf.conformance.suite import load_suites

    from . import baseline as bl, reports
    from .adapters import resolve
    from .preflight import preflight
    from .selection import select_cases
    from .session import RunOptions, execute, write_reports
    from .usage import UsageError, check_suites, lab_folders, resolve_claim, use_color

    adapter = resolve(args.decoder, ceilings=ceilings_from(args))
    claim = resolve_claim(args.claim, adapter)
    if args.sandbox_ro and hasattr(adapter, "lab_read_only"):
        adapter.lab_read_only = lab_folders(args.sandbox_ro)
    suites = load_suites()
    check_suites(suites, args.suite)
    if args.retries < 0:
        raise UsageError("--retries must be >= 0")
    cases = select_cases(suites, claim, args.suite, args.case, args.only_required, adapter)
    if not cases:
        raise UsageError("no case selected (check --case and --only-required)")
    # the baseline files are checked before any case runs (a bad line is a usage error now, not after the run)
    if args.baseline is not None:
        ids = {c.full_id for s in suites for c in s.cases}
        for case_id in sorted(set(bl.load(args.baseline)) - ids):
            print(
                f"fbaconf: warning: {args.baseline} lists {case_id}, which no suite holds (removed or renamed?): "
                f"remove its line",
                file=sys.stderr,
            )
    if args.flakes is not None:
        bl.load_flakes(args.flakes)
    if args.write_baseline is not None:
        bl.check_writable(args.write_baseline)
    preflight(adapter, claim)
    out_dir = (args.output or Path("fbaconf-run") / adapter.name).resolve()
    options = RunOptions(
        jobs=args.jobs,
        cluster=args.cluster,
        resume=args.resume,
        keep_workdirs=args.keep_workdirs,
        progress=False if args.no_progress else None,
        baseline=args.baseline,
        flakes=args.flakes,
        retries=args.retries,
        allow_fixed=args.allow_fixed,
        speed=args.speed,
        strict=args.strict,
    )
    record = execute(adapter, claim, cases, suites, out_dir, options)
    paths = write_reports(record, out_dir, json_path=args.json, junit_path=args.junit, html_dir=args.html)
    print(reports.terminal_summary(record, color=use_color(sys.stdout)))
    if args.write_baseline:
        print(bl.write(record.results, args.write_baseline).line())
    if record.baseline_summary:
        print(f"baseline: {record.baseline_summary}")
    if record.missing:
        accepted = " (the baseline lists them: the run passes)" if record.exit_code == 0 else ""
        print(f"claim {claim} not met{accepted}: the decoder could not take every case it requires:")
        for m in record.missing:
            print(f"  {m}")
        if adapter.is_player:
            print('  (a .fap player cannot hold an MPEG-4 profile claim; see docs/harness.md, "Players")')
    print(f"reports: {paths['html']}  {paths['json']}  {paths['junit']}")
    return record.exit_code


# ------------------------------------------------------------------ bench


def _register_bench(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser(
        "bench",
        help="measure decode/render speed against the level minimums",
        description="Measure a decoder's per-frame decode and render cost (free of process "
        "start-up: several content lengths, a linear fit, median over repeats) and "
        "compare the rates with the claimed level's minimums. Exit 0 all pass, "
        "1 a decoder run failed, 2 setup error, 3 too slow.",
    )
    p.add_argument("--decoder", required=True, help="decoder manifest .toml or bundled adapter name")
    p.add_argument("--claim", help="profile@level (default: the decoder's highest claim)")
    p.add_argument("--repeats", type=int, default=3, help="repeats of the length series (default 3; median)")
    p.add_argument(
        "--operation",
        choices=("decode", "render"),
        action="append",
        help="only this operation (repeatable; default both, render when the decoder outputs images)",
    )
    p.add_argument("--lengths", help="fixed content lengths in frames, comma-separated (default: adaptive)")
    p.add_argument(
        "--target-seconds",
        type=float,
        default=0.5,
        help="adaptive lengths: frame-dependent time of the longest run (default 0.5; at least the start-up time)",
    )
    p.add_argument("--render-size", default="64x64", help="image size of the render measurement (default 64x64)")
    p.add_argument("--work-dir", type=Path, help="keep the generated content here (default: a temporary folder)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    add_ceiling_options(p)
    p.set_defaults(func=cmd_bench)


def cmd_bench(args: argparse.Namespace) -> int:
    from .speed import bench

    return bench.run(args)
