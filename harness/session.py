"""One harness session: select the cases of a claim, execute them (+ speed), write the reports.

Used by ``fbaconf run`` and ``fbaconf certify`` alike (:mod:`.verbs`, :mod:`.certify`).
"""
from __future__ import annotations

import datetime as _dt
import fnmatch
import time
import tomllib
from importlib import resources
from pathlib import Path


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
