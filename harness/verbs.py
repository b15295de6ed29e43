"""Verbs ``fbaconf run`` and ``fbaconf certify`` (+ ``certify verify``).

Exit codes (architecture): 0 every required case passes (and the speed requirements when
measured); 1 some required case fails (a new failure, when ``--baseline`` is given);
2 usage or setup error; 3 only speed requirements missed.
"""
from __future__ import annotations

import datetime as _dt
import fnmatch
import json
import sys
import time
import tomllib
from importlib import resources
from pathlib import Path

from .adapters import highest_claim


def register(sub) -> None:
    r = sub.add_parser("run", help="run conformance suites against a decoder",
                       description="Run the conformance suites against a decoder (a manifest .toml or a bundled "
                                   "adapter name: reference, reference-inprocess, dummy) and report per case.")
    _common(r)
    r.add_argument("--suite", action="append", default=[], help="only this suite (repeatable)")
    r.add_argument("--case", action="append", default=[], help="only cases whose id matches this glob (repeatable)")
    r.add_argument("--only-required", action="store_true",
                   help="skip cases outside the claim instead of reporting them NotSupported")
    r.add_argument("-o", "--output", type=Path, default=None, help="run folder (default fbaconf-run/<decoder>)")
    r.add_argument("--resume", action="store_true", help="continue an interrupted run in the same folder")
    r.add_argument("--baseline", type=Path, help="known failures/flakes: only new failures fail the run")
    r.add_argument("--write-baseline", type=Path, help="write the failing cases of this run as a baseline file")
    r.add_argument("--junit", type=Path, help="write JUnit XML here")
    r.add_argument("--json", type=Path, help="write the JSON report here")
    r.add_argument("--html", type=Path, help="write the HTML report into this folder")
    r.add_argument("--speed", action="store_true", help="also measure decode/render speed against the level")
    r.set_defaults(func=cmd_run)

    c = sub.add_parser("certify", help="certify a decoder for a claim (or verify a certificate)",
                       description="`fbaconf certify --decoder D --claim P@L -o DIR` runs exactly the cases the "
                                   "claim requires plus the speed measurement and writes a certification package "
                                   "signed by sha256 digests. `fbaconf certify verify DIR` re-checks a package.")
    c.add_argument("action", nargs="?", choices=("verify",), help="verify an existing package")
    c.add_argument("package", nargs="?", type=Path, help="(verify) the package folder")
    c.add_argument("--decoder", help="decoder manifest .toml or bundled adapter name")
    c.add_argument("--claim", help="profile@level to certify (default: the decoder's highest claim)")
    c.add_argument("-o", "--output", type=Path, help="package folder to write")
    c.add_argument("-j", "--jobs", type=int, default=None, help="parallel cases (default: CPU cores)")
    c.add_argument("--no-speed", action="store_true", help="skip the speed measurement (certificate says so)")
    c.set_defaults(func=cmd_certify)


def _common(p) -> None:
    p.add_argument("--decoder", required=True, help="decoder manifest .toml or bundled adapter name")
    p.add_argument("--claim", help="profile@level under test (default: the decoder's highest claim)")
    p.add_argument("-j", "--jobs", type=int, default=None, help="parallel cases (default: CPU cores)")
    p.add_argument("--keep-workdirs", action="store_true", help="keep each case's working folder")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


# ------------------------------------------------------------------ shared


def provisional_statements(claim: str | None) -> list[str]:
    """What a verdict rests on that the public sources leave open (data: harness/data/provisional.toml
    and the provenance of each level limit)."""
    from fbaconf.profiles.model import Claim, load_profiles
    data = tomllib.loads(resources.files("fbaconf.harness").joinpath("data/provisional.toml").read_text("utf-8"))
    out = [f"{r['id']}: {r['text']} ({r['where']})" for r in data["rule"]]
    ps = load_profiles()
    if claim:
        c = Claim.parse(claim, ps)
        for lim in ps.limits_for(c):
            if lim.provenance == "provisional" and c.level in lim.values:
                out.append(f"level limit {lim.id} = {lim.value(c.level):g} {lim.unit} at {claim} "
                           f"({lim.description}) is provisional")
    return out


def select_cases(suites, claim: str | None, suite_names: list[str], case_globs: list[str], only_required: bool):
    from .runner import required_for
    cases = []
    for s in suites:
        if suite_names and s.name not in suite_names:
            continue
        for c in s.cases:
            if case_globs and not any(fnmatch.fnmatch(c.id, g) or fnmatch.fnmatch(c.full_id, g) for g in case_globs):
                continue
            if only_required and not required_for(claim, c):
                continue
            cases.append(c)
    return cases


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def execute(adapter, claim: str, cases, suites, out_dir: Path, *, jobs=None, resume=False, keep=False,
            progress=None, baseline=None, speed=False):
    """Run cases (+ speed); returns the RunRecord with its exit code set."""
    from . import baseline as bl
    from .results import RunRecord
    from .runner import run_cases
    from .sysinfo import system_info
    t0 = time.perf_counter()
    started = _now()
    results = run_cases(adapter, cases, claim=claim, out_dir=out_dir, jobs=jobs, resume=resume,
                        keep_workdirs=keep, progress=progress)
    new_failures = [r for r in results if r.required and r.outcome.failing]
    if baseline is not None:
        new_failures = bl.apply(results, bl.load(baseline))
    speed_results = []
    if speed:
        from .speed import measure_claim
        speed_results = [s for s in measure_claim(adapter, claim) if s is not None]
    ran = {c.suite for c in cases}
    record = RunRecord(
        decoder=adapter.describe(), claim=claim,
        suites=[{"name": s.name, "version": s.version, "sha256": s.digest(), "claim": s.claim, "group": s.group,
                 "cases": len(s.cases)} for s in suites if s.name in ran],
        system=system_info(), results=results, speed=speed_results, started=started, finished=_now(),
        duration_s=time.perf_counter() - t0, provisional=provisional_statements(claim))
    if new_failures:
        record.exit_code = 1
    elif any(not s.passed for s in speed_results):
        record.exit_code = 3
    else:
        record.exit_code = 0
    return record


def write_reports(record, out_dir: Path, *, json_path=None, junit_path=None, html_dir=None) -> dict[str, Path]:
    from . import reports
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": json_path or out_dir / "report.json", "junit": junit_path or out_dir / "junit.xml",
             "html": (html_dir or out_dir) / "index.html"}
    reports.write_json(record, paths["json"])
    reports.write_junit(record, paths["junit"])
    paths["html"] = reports.write_html(record, html_dir or out_dir, base_dir=out_dir)
    return paths


# ------------------------------------------------------------------ run


def cmd_run(args) -> int:
    from fbaconf.conformance.suite import load_suites
    from fbaconf.profiles.model import Claim
    from . import baseline as bl
    from . import reports
    from .adapters import resolve
    adapter = resolve(args.decoder)
    claim = args.claim or highest_claim(adapter)
    try:
        claim = str(Claim.parse(claim))
    except ValueError as e:
        print(f"fbaconf run: error: --claim: {e}", file=sys.stderr)
        return 2
    suites = load_suites()
    cases = select_cases(suites, claim, args.suite, args.case, args.only_required)
    if not cases:
        print("fbaconf run: error: no case selected", file=sys.stderr)
        return 2
    out_dir = args.output or Path("fbaconf-run") / adapter.name
    record = execute(adapter, claim, cases, suites, out_dir, jobs=args.jobs, resume=args.resume,
                     keep=args.keep_workdirs, progress=False if args.no_progress else None,
                     baseline=args.baseline, speed=args.speed)
    paths = write_reports(record, out_dir, json_path=args.json, junit_path=args.junit, html_dir=args.html)
    if args.write_baseline:
        n = bl.write(record.results, args.write_baseline)
        print(f"wrote baseline with {n} known failure(s) to {args.write_baseline}")
    print(reports.terminal_summary(record, color=sys.stdout.isatty()))
    print(f"reports: {paths['html']}  {paths['json']}  {paths['junit']}")
    return record.exit_code


# ------------------------------------------------------------------ certify


def cmd_certify(args) -> int:
    from . import certify
    if args.action == "verify":
        if args.package is None:
            print("fbaconf certify verify: error: give the package folder", file=sys.stderr)
            return 2
        problems = certify.verify_package(args.package)
        for p in problems:
            print(f"certify verify: {p}", file=sys.stderr)
        if problems:
            print(f"certify verify: FAILED ({len(problems)} problem(s))")
            return 1
        info = json.loads((args.package / certify.CERTIFICATE).read_text(encoding="utf-8"))
        print(f"certify verify: OK — {info['decoder']} {info['claim']}: {info['verdict']}")
        return 0
    if not args.decoder or not args.output:
        print("fbaconf certify: error: --decoder and -o/--output are required", file=sys.stderr)
        return 2
    return certify.certify(args.decoder, args.claim, args.output, jobs=args.jobs, speed=not args.no_speed)
