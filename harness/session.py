"""One harness session: select the cases of a claim, execute them (+ speed), write the reports.

Used by ``fbaconf run`` and ``fbaconf certify`` alike (:mod:`.verbs`, :mod:`.certify`).
"""
from __future__ import annotations

import datetime as _dt
import difflib
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
import tomllib
from collections import Counter
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from fbaconf.conformance.suite import CaseKind, load_suites
from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import bounds, sandbox, setup, view
from fbaconf.profiles.model import Claim, load_profiles

from . import baseline as bl
from . import reports
from .adapters import PLACEHOLDERS, CommandAdapter, Job, highest_claim
from .provisional import rests_on
from .results import RunRecord
from .runner import hidden_from_decoders, prepare_job, run_cases
from .selection import capability, required_for, select_cases
from .speed.measure import measure_claim
from .sysinfo import system_info
from .verdict import claim_verdict, speed_verdict


def provisional_statements(claim: str | None) -> list[str]:
    """What a verdict rests on that the public sources leave open (data: harness/data/provisional.toml
    and the provenance of each level limit)."""
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


def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


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
    strict: bool = False  # provisional differences fail the claim (harness/provisional.py)


def execute(adapter, claim: str, cases, suites, out_dir: Path, options: RunOptions | None = None):
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
        results = run_cases(adapter, cases, claim=claim, out_dir=out_dir, jobs=jobs, resume=o.resume,
                            keep_workdirs=o.keep_workdirs, progress=o.progress, cluster=o.cluster)
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


def _retry(adapter, cases, results, claim, out_dir: Path, jobs, retries: int) -> None:
    """Re-run each failing required case up to ``retries`` times; one that passes on a re-run
    is a flake (its first result is kept, annotated ``flake``)."""
    by_id = {c.full_id: c for c in cases}
    todo = [r for r in results if r.required and r.outcome.failing]
    for attempt in range(1, retries + 1):
        if not todo:
            return
        again = run_cases(adapter, [by_id[r.case_id] for r in todo], claim=claim,
                          out_dir=out_dir / "retries" / str(attempt), jobs=jobs, progress=False)
        passed = {r.case_id for r in again if r.outcome.ok}
        for r in todo:
            if r.case_id in passed:
                r.baseline = "flake"
                r.message = f"{bl.RETRY_PASSED} {attempt}; first run: {r.message}"
        todo = [r for r in todo if r.case_id not in passed]


def write_reports(record, out_dir: Path, *, json_path=None, junit_path=None, html_dir=None,  # noqa: PLR0913
                  heading: str = "fbaconf run") -> dict[str, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {"json": json_path or out_dir / "report.json", "junit": junit_path or out_dir / "junit.xml",
             "html": (html_dir or out_dir) / "index.html"}
    reports.write_json(record, paths["json"])
    reports.write_junit(record, paths["junit"])
    paths["html"] = reports.write_html(record, html_dir or out_dir, base_dir=out_dir, heading=heading)
    return paths


def missing_summary(results) -> list[str]:
    """What the decoder could not take among the required cases, grouped by reason
    (tools, inputs, outputs, claims): one line per reason with its count."""
    reasons = Counter(r.message for r in results if r.required and r.outcome.value == "NotSupported")
    return [f"{n} required case(s): {why}" for why, n in reasons.most_common()]


class UsageError(FbaconfInputError):
    """A command-line value is wrong (exit 2, one line)."""
    rule = "usage"


def use_color(stream) -> bool:
    """Colour only on a terminal and never when NO_COLOR is set (https://no-color.org)."""
    return stream.isatty() and not os.environ.get("NO_COLOR")


def resolve_claim(text: str | None, adapter) -> str:
    try:
        return str(Claim.parse(text or highest_claim(adapter)))
    except ValueError as e:
        raise UsageError(f"--claim: {e}") from None


def lab_folders(paths: list[Path]) -> list[Path]:
    """The lab's --sandbox-ro folders, checked: absolute, existing, not too broad, holding none of
    what a decoder never sees (git data, a copy of the goldens or suites: UsageError)."""
    out = []
    for p in paths:
        p = Path(p)
        if not p.is_absolute() or not p.is_dir():
            raise UsageError(f"--sandbox-ro {p}: give an absolute path to an existing folder")
        why = sandbox.view_problem(p) or view.folder_problem(p)
        if why:
            raise UsageError(f"--sandbox-ro {p}: {why}")
        out.append(p)
    return out


def check_suites(suites, names: list[str]) -> None:
    """Unknown ``--suite`` names are a usage error, with the nearest name."""
    known = [s.name for s in suites]
    for n in names:
        if n not in known:
            close = difflib.get_close_matches(n, known, n=1)
            raise UsageError(f"--suite {n!r}: no such suite" + (f" (did you mean {close[0]!r}?)" if close else
                             f" (known: {', '.join(known)})"))


def isolation_notice(adapter) -> str:
    """One line: whether decoders are isolated on this machine and by which limits (``run`` and
    ``certify`` print it) — never "isolated" where a limit holds per process only."""
    if sandbox.isolation() == "bwrap":
        rep = sandbox.isolation_report()
        here = ("decoders run in a bubblewrap sandbox on this machine" +
                ("" if rep.complete else " — NOT fully isolated: " + "; ".join(rep.missing)))
    else:
        why = ("switched off (FBACONF_SANDBOX=none)" if os.environ.get("FBACONF_SANDBOX") == "none"
               else "not available")
        here = (f"WARNING: bubblewrap (bwrap) is {why}: decoders run UNISOLATED on this machine — they can "
                "read the goldens and write outside their folder. Install it (Debian: apt-get install bubblewrap); "
                "certify refuses to run a decoder without it unless told --allow-unisolated")
    if not isinstance(adapter, CommandAdapter):
        return f"fbaconf: isolation: {adapter.name} runs inside fbaconf (no sandbox applies); {here}"
    return f"fbaconf: isolation: {here}; limits in force: " + "; ".join(bounds.limits_in_force(adapter))


def preflight(adapter, claim: str | None = None) -> float | None:
    """Before any case: one line saying whether decoders are isolated here and by which limits;
    a command decoder's program must exist and be executable, and every folder its commands
    would show must pass the view's checks (ViewError, exit 2). With ``claim``: the canary
    (:func:`canary`: SetupError, exit 2, when the decoder does not decode the claim's simplest
    valid stream); returns the seconds it took (None: none ran)."""
    print(isolation_notice(adapter), file=sys.stderr)
    if not isinstance(adapter, CommandAdapter):
        return None
    prog = adapter.program()
    # the folders its commands would show (program, the files they name, manifest, --sandbox-ro), case files aside
    at = Path("/nonexistent-case")
    job = Job(at, {p: str(at / p) for p in PLACEHOLDERS if p not in ("python", "manifest_dir", "workdir", "frames")},
              faces=[str(at / "face.fba")], frames=1)
    for name in adapter.commands:
        adapter.sandbox_view(adapter.argv(name, job), at, hidden=hidden_from_decoders())
    if prog is None:
        first = str(adapter.commands["decode"][0])
        where = Path(adapter.manifest_path).resolve().parent if adapter.manifest_path is not None else None
        shown = os.path.normpath(first.replace("{manifest_dir}", str(where))) if where is not None else first
        raise UsageError(f"decoder {adapter.name}: program {shown} not found (not a file, and not on PATH)"
                         + (f"; [commands] decode names it \"{first}\": build the decoder first" if shown != first
                            else ""))
    if not os.access(prog, os.X_OK):
        raise UsageError(f"decoder {adapter.name}: program {prog} is not executable")
    return canary(adapter, claim) if claim is not None else None


def canary_case(adapter, claim: str):
    """The claim's simplest valid stream for ``adapter``: the smallest required ``decode`` case
    it can take (by the size of the stream it is given) that rests on no provisional decision (a
    decoder may follow another reading there, and then rejects it rightly), or None."""
    best = None
    for c in select_cases(load_suites(), claim, [], [], True, adapter):
        if c.kind != CaseKind.DECODE or capability(adapter, c) or not required_for(claim, c, adapter) or rests_on(c):
            continue
        stream = c.input_path("fba") if "fba" in adapter.inputs else c.input_path("fap")
        if stream is not None and stream.is_file() and (best is None or (stream.stat().st_size, c.full_id) < best[0]):
            best = ((stream.stat().st_size, c.full_id), c)
    return best[1] if best else None


def canary(adapter, claim: str) -> float | None:
    """Run the decoder on :func:`canary_case` exactly as a case runs (:func:`fbaconf.isolation.setup.probe`:
    SetupError when it does not decode); the seconds it took, or None when there was none to run
    (an in-process adapter, no case it can take, a command the case cannot fill)."""
    case = canary_case(adapter, claim) if isinstance(adapter, CommandAdapter) else None
    if case is None:
        return None
    t0, work = time.perf_counter(), Path(tempfile.mkdtemp(prefix="fbaconf-canary-"))
    try:
        job = prepare_job(adapter, case, work / "case")
        try:
            argv = adapter.argv("decode", job)
        except KeyError:  # a placeholder the case has no value for: NotSupported, no canary
            return None
        hidden = hidden_from_decoders() + ([case.suite_dir.resolve()] if case.suite_dir else [])
        setup.probe(argv, job.workdir, adapter.limits, name=adapter.name, env=adapter.env,
                    what=f"the claim's simplest valid stream ({case.full_id})",
                    file=str(adapter.manifest_path or adapter.name), reject_exit_codes=adapter.reject_exit_codes,
                    view=adapter.sandbox_view(argv, job.workdir, hidden=hidden))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return time.perf_counter() - t0


class _Stop:
    signum: int | None = None


class interruptible:
    """Ctrl-C / SIGTERM during a run: kill every running decoder tree at once (the sandbox's
    process groups), start no new case, and let the caller write the partial report. Cases
    cut short are not recorded, so ``--resume`` runs exactly them and those never started."""

    def __enter__(self) -> _Stop:
        self.stop = _Stop()
        self.old = {}
        sandbox.reset_stop()
        if threading.current_thread() is threading.main_thread():
            def handler(signum, _frame):
                self.stop.signum = signum
                sandbox.stop_all()
            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.signal(sig, handler)
        return self.stop

    def __exit__(self, *exc) -> None:
        for sig, h in self.old.items():
            signal.signal(sig, h)
        sandbox.reset_stop()


def _record(adapter, claim, suites, cases, results, started, t0):
    """The RunRecord of a session: decoder, claim, the suites that ran, system, results."""
    ran = {c.suite for c in cases}
    return RunRecord(
        decoder=adapter.describe(), claim=claim,
        suites=[{"name": s.name, "version": s.version, "sha256": s.digest(), "claim": s.claim, "group": s.group,
                 "cases": len(s.cases)} for s in suites if s.name in ran],
        system=system_info(), results=results, started=started, finished=_now(),
        duration_s=time.perf_counter() - t0, provisional=provisional_statements(claim))


def _interrupted_record(adapter, claim, suites, cases, results, started, t0, signum):
    record = _record(adapter, claim, suites, cases, results, started, t0)
    record.missing = [f"interrupted by signal {signum}: {len(cases) - len(results)} case(s) not run "
                      f"(--resume continues)"]
    record.exit_code = 128 + signum
    return record
