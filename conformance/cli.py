"""Verbs ``fbaconf suites list|build|counts|coverage|mutants`` and ``fbaconf golden regenerate|verify|margins``."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser(
        "suites",
        help="show or regenerate the conformance suites",
        description="Conformance suites: list them, or rebuild every stream/scene from "
        "conformance/data/suites.toml (deterministic).",
    )
    ss = p.add_subparsers(dest="suites_cmd", metavar="CMD", required=True)
    ls = ss.add_parser("list", help="list suites and cases")
    ls.add_argument("--cases", action="store_true", help="also list each case")
    ls.add_argument("--json", action="store_true")
    ls.set_defaults(func=cmd_list)
    b = ss.add_parser("build", help="regenerate the suites (then run `fbaconf golden verify`)")
    b.add_argument("names", nargs="*", help="only these suites")
    b.add_argument("--goldens", action="store_true", help="also regenerate the goldens")
    b.add_argument(
        "--external",
        type=Path,
        metavar="DIR",
        help="also build the optional external suite from the real .fap files in DIR "
        "(never committed; written to --external-out or a temporary folder)",
    )
    b.add_argument(
        "--external-out",
        type=Path,
        metavar="DIR",
        help="where the external suite goes (default: a new temporary folder, printed)",
    )
    b.set_defaults(func=cmd_build)
    cn = ss.add_parser("counts", help="the case counts per suite and per claim (the table the docs print)")
    cn.add_argument(
        "--write", type=Path, metavar="DOC", help="replace the table between the counts markers of DOC (docs/suites.md)"
    )
    cn.set_defaults(func=cmd_counts)
    cv = ss.add_parser(
        "coverage",
        help="which coverage points each case hits (coverage: K/N points)",
        description="Decode and inspect every case of the built suites and report which points "
        "of the coverage model (conformance/data/coverage.toml) they hit.",
    )
    cv.add_argument("--json", action="store_true", help="the full report as JSON")
    cv.add_argument("--cases", action="store_true", help="also list the points of each case")
    cv.add_argument(
        "--write",
        action="store_true",
        help="also write each case's points to the package's conformance/data/case-points.json "
        "(what certify reads instead of decoding every case again; conformance/coverage_table.py)",
    )
    cv.set_defaults(func=cmd_coverage)
    mu = ss.add_parser(
        "mutants",
        help="run every mutant decoder against the suites (mutation score)",
        description="Run each mutant decoder (the reference with one realistic bug, "
        "mutation/own.py, mutation/independent/) against the cases "
        "of the claim (required and .fap player cases, with .npz and then .fap "
        "output), each mutant in its own process, and print the case that "
        "kills it; then the score of each family and, last, "
        "`mutation score: K/N` (equivalent mutants listed, not scored).",
    )
    mu.add_argument("names", nargs="*", help="only these mutants")
    mu.add_argument("-j", "--jobs", type=int, default=None, help="mutants run in parallel (default: CPU cores)")
    mu.add_argument("--claim", default="predictable@2", help="claim whose required cases are run")
    mu.add_argument(
        "--all-cases",
        action="store_true",
        help="run every case against each mutant (default: stop at the first killing case)",
    )
    mu.add_argument(
        "--family",
        choices=("suite", "independent"),
        default=None,
        help="only the suite's own mutants, or only the independent ones (written from the spec "
        "notes alone, mutation/independent/; default: both)",
    )
    mu.add_argument("--list", action="store_true", help="only list the mutants")
    mu.add_argument("--json", action="store_true")
    mu.set_defaults(func=cmd_mutants)
    g = sub.add_parser(
        "golden",
        help="regenerate or verify the golden outputs",
        description="Goldens come only from the reference pipeline: `regenerate` writes them and "
        "golden/MANIFEST.json; `verify` checks digests and that regeneration is bit-identical.",
    )
    gs = g.add_subparsers(dest="golden_cmd", metavar="CMD", required=True)
    r = gs.add_parser("regenerate", help="write goldens from the reference")
    r.set_defaults(func=cmd_regenerate)
    v = gs.add_parser("verify", help="check digests and bit-identical regeneration")
    v.add_argument("--no-regenerate", action="store_true", help="only check digests (fast)")
    v.add_argument(
        "--suite",
        action="append",
        default=[],
        metavar="NAME",
        help="regenerate only this suite's goldens (repeatable; every digest is still checked)",
    )
    v.set_defaults(func=cmd_verify)
    m = gs.add_parser(
        "margins",
        help="how far each float golden's values are from a rounding boundary",
        description="Rerun the reference for every case and report, per float golden (vertex "
        "arrays at 6 decimals, 8-bit images), the smallest distance of a value to the "
        "boundary of its rounding step, in ulps: how far another platform's result "
        "may be off before regeneration changes a byte (conformance/precision.py).",
    )
    m.add_argument("--json", action="store_true", help="every golden's margin as JSON")
    m.set_defaults(func=cmd_margins)


def cmd_list(args) -> int:
    from .suite import load_suites

    suites = load_suites()
    if args.json:
        print(
            json.dumps(
                [
                    {
                        "name": s.name,
                        "claim": s.claim,
                        "group": s.group,
                        "version": s.version,
                        "cases": [c.id for c in s.cases],
                    }
                    for s in suites
                ],
                indent=1,
            )
        )
        return 0
    for s in suites:
        print(f"{s.name:28s} {s.claim:16s} {s.group:8s} {len(s.cases):3d} case(s)  {s.description}")
        if args.cases:
            for c in s.cases:
                print(f"    {c.id:34s} {c.kind:7s} {c.frames:4d} frames  {c.description}")
    print(f"{len(suites)} suite(s), {sum(len(s.cases) for s in suites)} case(s)")
    return 0


def cmd_build(args) -> int:
    from fbaconf.generators.suites import build, build_external

    if args.external is not None:
        ext = build_external(args.external, args.external_out)
        if ext is None:
            print(f"external suite: {args.external} holds no .fap files; skipped")
        else:
            print(
                f"external suite: {ext.name}: {len(ext.cases)} case(s) in {ext.path} "
                f"(run: FBACONF_SUITES={ext.path.parent} fbaconf run ...)"
            )
        if not args.names and not args.goldens:
            return 0
    suites = build(names=args.names or None)
    if args.goldens:
        from .golden import regenerate
        from .suite import load_suites

        regenerate(load_suites())
    print(f"{len(suites)} suite(s) built")
    return 0


def cmd_regenerate(args) -> int:
    from .golden import regenerate
    from .suite import load_suites

    m = regenerate(load_suites())
    print(f"wrote {len(m['files'])} golden file(s)")
    return 0


def cmd_verify(args) -> int:
    from .golden import verify

    problems = verify(regenerate_check=not args.no_regenerate, only=args.suite or None)
    for p in problems:
        print(f"golden verify: {p}", file=sys.stderr)
    if problems:
        print(f"golden verify: FAILED ({len(problems)} problem(s))")
        return 1
    print("golden verify: OK")
    return 0


def cmd_margins(args) -> int:
    from dataclasses import asdict

    from .golden import GOLDEN_SUPERSAMPLE
    from .precision import measure, summary
    from .suite import load_suites

    rows = measure(load_suites(), GOLDEN_SUPERSAMPLE, log=(lambda *_: None) if args.json else print)
    print(json.dumps([asdict(r) for r in rows], indent=1) if args.json else summary(rows))
    return 0


def cmd_counts(args) -> int:
    from . import counts
    from .suite import load_suites

    suites = load_suites()
    if args.write:
        changed = counts.write(args.write, suites)
        print(f"{args.write}: {'rewritten' if changed else 'already current'}")
        return 0
    print(counts.table(suites))
    return 0


def cmd_coverage(args) -> int:
    from . import coverage, coverage_table

    computed = coverage.case_coverages()
    rep = coverage.compute(computed=computed)
    if args.write:
        path, n = coverage_table.write(computed)
        print(f"wrote the points of {n} case(s) to {path}", file=sys.stderr)
    if args.json:
        print(json.dumps(rep, indent=1))
        return 0
    if args.cases:
        for c in rep["cases"]:
            print(f"{c['case']}: {len(c['points'])} point(s): {' '.join(c['points'])}")
        print()
    print(coverage.format_table(rep))
    return 0


def cmd_mutants(args) -> int:
    from fbaconf.mutation import own, run

    chosen = [m.name for m in own.MUTANTS_LIST if args.family in (None, m.family)]
    if args.list:
        for n in chosen:
            m = own.MUTANTS[n]
            print(f"{m.name:32s} {m.where:40s} {m.description}")
        print(f"{len(chosen)} mutant(s)")
        return 0
    unknown = [n for n in args.names if n not in own.MUTANTS]
    if unknown:
        print(f"fbaconf suites mutants: error: unknown mutant(s) {', '.join(unknown)}", file=sys.stderr)
        return 2
    results = run.run_all(args.names or chosen, claim=args.claim, jobs=args.jobs, stop_at_first=not args.all_cases)
    if args.json:
        print(json.dumps(results, indent=1))
    else:
        print(run.format_results(results))
    return 0
