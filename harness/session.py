"""One harness session: run the selected cases of a claim (+ speed), judge the claim, write the
reports. Used by ``fbaconf run`` and ``fbaconf certify`` alike; what comes before the cases is
:mod:`.preflight`, the command line's values :mod:`.usage`."""

from __future__ import annotations

import datetime as _dt
import signal
import threading
import time
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

from fbaconf.conformance import provisional
from fbaconf.conformance.suite import Case, Suite
from fbaconf.isolation import sandbox, setup

from . import baseline as bl, reports
from .adapters import Adapter
from .results import CaseResult, RunRecord
from .runner import run_cases
from .speed.measure import measure_claim
from .sysinfo import system_info
from .verdict import claim_verdict, speed_verdict


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


@dataclass
class RunOptions:
    """How ``run``/``certify`` run the selected cases: parallelism (``jobs`` or a Dask
    ``cluster``), resumption, kept case folders, progress, the baseline and flakes files,
    retries, and whether the speed phase runs."""

    jobs: int | None = None
    cluster: str | None = None
    resume: bool = False
    keep_workdirs: bool = False
    progress: bool | None = None
    baseline: Path | None = None
    flakes: Path | None = None
    retries: int = 0
    allow_fixed: bool = False
    speed: bool = False
    strict: bool = False  # provisional differences fail the claim (conformance/provisional.py)


def execute(
    adapter: Adapter,
    claim: str,
    cases: list[Case],
    suites: list[Suite],
    out_dir: Path,
    options: RunOptions | None = None,
) -> RunRecord:
    """Run cases (+ speed); returns the RunRecord with its exit code set.

    Exit code: 1 when a required case fails or could not be taken (a claim means all of it),
    counting only new failures (and fixed cases, unless ``allow_fixed``) when a baseline or
    flakes file is given; the claim's verdict otherwise (:mod:`.verdict`: what a declared reading
    gives and an unverified tool fail only under ``strict``); 3 only when every required case
    passed and only speed was missed; else 0."""
    o = options or RunOptions()
    jobs, baseline, flakes, retries, speed = o.jobs, o.baseline, o.flakes, o.retries, o.speed
    # read (and check) the baseline and flakes files before any case: a bad line stops the run at once
    known = bl.load(baseline) if baseline is not None else None
    flaky = bl.load_flakes(flakes) if flakes is not None else None
    t0 = time.perf_counter()
    started = _now()
    out_dir = Path(out_dir).resolve()
    with interruptible() as stop:
        results = run_cases(
            adapter,
            cases,
            claim=claim,
            out_dir=out_dir,
            jobs=jobs,
            resume=o.resume,
            keep_workdirs=o.keep_workdirs,
            progress=o.progress,
            cluster=o.cluster,
        )
    if stop.signum is not None:
        return _interrupted_record(adapter, claim, suites, cases, results, started, t0, stop.signum)
    same = setup.identical(adapter.name, adapter.limits, results, {c.full_id for c in cases if c.kind != "error"})
    if same is not None:  # the decoder never ran as set up: one set-up error, no verdict (exit 2)
        raise setup.SetupError(same, file=str(adapter.manifest_path or adapter.name))
    if retries:
        _retry(adapter, cases, results, claim, out_dir, jobs, retries)
    speed_results = []
    if speed:
        speed_results = [s for s in measure_claim(adapter, claim) if s is not None]
    speed_json = [s.to_json() for s in speed_results] if speed else None
    cv = claim_verdict([r.to_json() for r in results], strict=o.strict, speed=speed_json, declared=adapter.readings)
    record = _record(adapter, claim, suites, cases, results, started, t0)
    record.speed = speed_results
    record.missing = missing_summary(results)
    record.provisional_differences, record.strict = cv.differences, o.strict
    record.verdict = cv.to_json()
    record.exit_code = cv.exit_code
    if baseline is not None or flakes is not None or retries:
        # a CI gate: only new failures (and fixed cases) fail; what the claim sets aside is not judged
        judged = results if o.strict else [r for r in results if r.case_id not in cv.set_aside]
        summary = bl.classify(judged, known, flaky)
        record.baseline_summary = summary.line()
        if summary.failing(o.allow_fixed) or (o.strict and cv.differences):
            record.exit_code = 1
        else:
            blocked = speed_verdict(speed_json)
            record.exit_code = blocked[1] if blocked else 0
    return record


def _retry(
    adapter: Adapter,
    cases: list[Case],
    results: list[CaseResult],
    claim: str,
    out_dir: Path,
    jobs: int | None,
    retries: int,
) -> None:
    """Re-run each failing required case up to ``retries`` times; one that passes on a re-run
    is a flake (its first result is kept, annotated ``flake``)."""
    by_id = {c.full_id: c for c in cases}
    todo = [r for r in results if r.required and r.outcome.failing]
    for attempt in range(1, retries + 1):
        if not todo:
            return
        again = run_cases(
            adapter,
            [by_id[r.case_id] for r in todo],
            claim=claim,
            out_dir=out_dir / "retries" / str(attempt),
            jobs=jobs,
            progress=False,
        )
        passed = {r.case_id for r in again if r.outcome.ok}
        for r in todo:
            if r.case_id in passed:
                r.baseline = "flake"
                r.message = f"{bl.RETRY_PASSED} {attempt}; first run: {r.message}"
        todo = [r for r in todo if r.case_id not in passed]


def write_reports(
    record: RunRecord,
    out_dir: Path,
    *,
    json_path: Path | None = None,
    junit_path: Path | None = None,
    html_dir: Path | None = None,
    heading: str = "fbaconf run",
) -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {
        "json": json_path or out_dir / "report.json",
        "junit": junit_path or out_dir / "junit.xml",
        "html": (html_dir or out_dir) / "index.html",
    }
    reports.write_json(record, paths["json"])
    reports.write_junit(record, paths["junit"])
    paths["html"] = reports.write_html(record, html_dir or out_dir, base_dir=out_dir, heading=heading)
    return paths


def missing_summary(results: Iterable[CaseResult]) -> list[str]:
    """What the decoder could not take among the required cases, grouped by reason
    (tools, inputs, outputs, claims): one line per reason with its count."""
    reasons = Counter(r.message for r in results if r.required and r.outcome.value == "NotSupported")
    return [f"{n} required case(s): {why}" for why, n in reasons.most_common()]


class _Stop:
    signum: int | None = None


class interruptible:
    """Ctrl-C / SIGTERM during a run: kill every running decoder tree at once (the sandbox's
    process groups), start no new case, and let the caller write the partial report. Cases
    cut short are not recorded, so ``--resume`` runs exactly them and those never started."""

    def __enter__(self) -> _Stop:
        self.stop = _Stop()
        self.old: dict[int, Any] = {}  # the handlers before (signal.getsignal's kinds)
        sandbox.reset_stop()
        if threading.current_thread() is threading.main_thread():

            def handler(signum: int, _frame: FrameType | None) -> None:
                self.stop.signum = signum
                sandbox.stop_all()

            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.signal(sig, handler)
        return self.stop

    def __exit__(self, *exc: object) -> None:
        for sig, h in self.old.items():
            signal.signal(sig, h)
        sandbox.reset_stop()


def _record(
    adapter: Adapter,
    claim: str,
    suites: list[Suite],
    cases: list[Case],
    results: list[CaseResult],
    started: str,
    t0: float,
) -> RunRecord:
    """The RunRecord of a session: decoder, claim, the suites that ran, system, results."""
    ran = {c.suite for c in cases}
    return RunRecord(
        decoder=adapter.describe(),
        claim=claim,
        suites=[
            {
                "name": s.name,
                "version": s.version,
                "sha256": s.digest(),
                "claim": s.claim,
                "group": s.group,
                "cases": len(s.cases),
            }
            for s in suites
            if s.name in ran
        ],
        system=system_info(),
        results=results,
        started=started,
        finished=_now(),
        duration_s=time.perf_counter() - t0,
        provisional=provisional.statements(claim),
    )


def _interrupted_record(
    adapter: Adapter,
    claim: str,
    suites: list[Suite],
    cases: list[Case],
    results: list[CaseResult],
    started: str,
    t0: float,
    signum: int,
) -> RunRecord:
    record = _record(adapter, claim, suites, cases, results, started, t0)
    record.missing = [
        f"interrupted by signal {signum}: {len(cases) - len(results)} case(s) not run (--resume continues)"
    ]
    record.exit_code = 128 + signum
    return record
