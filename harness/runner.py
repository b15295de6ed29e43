"""Run conformance cases against a decoder adapter and judge each one.

Per case: capability check (:mod:`.selection`: claim, tools, inputs, outputs — NotSupported
before anything runs) -> own temporary directory with copies of the inputs the decoder
accepts -> one decoder invocation under the adapter's limits
(:mod:`fbaconf.isolation.sandbox`) -> how the process ended
(:mod:`fbaconf.isolation.endings`) -> the comparison ladder (:mod:`.compare.ladder`: the
ending's outcome, then FAPs exactly, vertices within tolerance, images with OpenImageIO +
CIEDE2000 against the case's goldens). Cases run in parallel threads (``-j``); each result
is appended to ``results.jsonl`` as soon as it is known, so an interrupted run loses
nothing and ``--resume`` continues where it stopped.

Error cases (invalid streams) pass when the decoder rejects the stream with one of its
documented reject exit codes; exit 0 on an invalid stream is a Fail unless the case allows
concealment (then the outputs decide); crashes, hangs and blown limits fail as everywhere
(:func:`.compare.ladder.outcome_for`).
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
import traceback
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fbaconf.bitstreams import readings
from fbaconf.conformance.golden import REJECT, reading_goldens
from fbaconf.conformance.provisional import readings_for, rests_on
from fbaconf.conformance.suite import Case, CaseKind, golden_root, suites_root
from fbaconf.isolation import endings, sandbox
from fbaconf.isolation.endings import Ending
from fbaconf.isolation.staging import stage
from fbaconf.safefs import remove_tree

from . import cluster as cl
from .adapters import OUTPUT_PLACEHOLDER, Adapter, CommandAdapter, Job, PythonAdapter
from .compare.base import worst
from .compare.ladder import compare_outputs, outcome_for
from .results import CaseResult, Outcome, ResultLog
from .selection import capability, required_for

# ------------------------------------------------------------------------ one case


@dataclass
class RunContext:
    adapter: Adapter
    claim: str | None
    out_dir: Path  # run output folder (artefacts/<case>/ for failing images)
    golden: Path = field(default_factory=golden_root)
    keep_workdirs: bool = False
    work_root: Path | None = None


def prepare_job(a: Adapter, case: Case, workdir: Path) -> Job:
    """A case's folder for ``a`` (:func:`fbaconf.isolation.staging.stage`: ``in/`` with copies of
    the inputs it accepts, ``out/`` for what it writes), as the :class:`Job` its command is filled from."""
    values, faces = stage(a, case, workdir)
    compared = set(case.stages) & set(a.outputs)
    unwanted = frozenset(ph for out, ph in OUTPUT_PLACEHOLDER.items() if out not in compared)
    return Job(workdir=workdir, values=values, faces=faces, frames=case.frames, unwanted=unwanted)


def _remove_quietly(path: Path) -> None:
    """Delete a case folder whatever the decoder left in it (depth, permissions, links)."""
    try:
        remove_tree(path)
    except OSError as e:
        print(f"fbaconf: warning: could not remove {path}: {e}", file=sys.stderr)


def run_case(ctx: RunContext, case: Case) -> CaseResult:
    t0 = time.perf_counter()
    required = required_for(ctx.claim, case, ctx.adapter)
    base: dict[str, Any] = dict(
        case_id=case.full_id,
        suite=case.suite,
        claim=case.claim,
        required=required,
        rests_on=rests_on(case, ctx.golden),
        kind=CaseKind(case.kind).value,
        tools=list(case.tools),
    )
    why = capability(ctx.adapter, case)
    if why:
        return CaseResult(**base, outcome=Outcome.NOT_SUPPORTED, message=why)
    workdir = Path(tempfile.mkdtemp(prefix="case-", dir=ctx.work_root))
    try:
        job = prepare_job(ctx.adapter, case, workdir)
        result = _execute(ctx, case, job, base)
    except Exception as e:  # noqa: BLE001 - a harness problem, never the decoder's verdict
        result = CaseResult(
            **base,
            outcome=Outcome.ERROR,
            message=f"harness error: {type(e).__name__}: {e}",
            stderr_tail=traceback.format_exc(limit=3)[-2000:],
        )
    finally:
        if not ctx.keep_workdirs:
            _remove_quietly(workdir)
    result.duration_s = time.perf_counter() - t0
    return result


def _execute(ctx: RunContext, case: Case, job: Job, base: dict[str, Any]) -> CaseResult:
    a = ctx.adapter
    argv = None
    if isinstance(a, CommandAdapter):
        cmd = "decode_multi" if case.kind == CaseKind.MULTI else "decode"
        try:
            argv = a.argv(cmd, job)
        except KeyError as e:
            return CaseResult(
                **base,
                outcome=Outcome.NOT_SUPPORTED,
                message=f"[commands] {cmd} needs {{{e.args[0]}}}, which this case does not have",
            )
        hidden = hidden_from_decoders(ctx) + ([case.suite_dir.resolve()] if case.suite_dir else [])
        view = a.sandbox_view(argv, job.workdir, hidden=hidden)
        res = sandbox.run(
            argv, job.workdir, a.limits, env=a.env, view=view, keep_io=job.workdir if ctx.keep_workdirs else None
        )
        ending = endings.classify(res, a.limits, a.reject_exit_codes, name=a.name)
        proc: dict[str, Any] = dict(
            command=argv,
            exit_code=res.returncode,
            signal=res.signal,
            stderr_tail=endings.kept_stderr(res.stderr_tail, ending),
        )
    elif isinstance(a, PythonAdapter):
        ex = a.execute(job)
        ending = ex.ending
        proc = dict(command=None, exit_code=ex.exit_code, signal=None, stderr_tail=ex.stderr_tail)
    else:
        raise TypeError(f"an adapter neither a command nor in-process: {type(a).__name__}")
    proc["ending"] = ending.kind.value
    if ending.report is not None:
        proc["crash_kind"] = ending.report.kind
    fields = dict(base, **proc)
    declared = readings_for(case, a.readings, ctx.golden)
    if declared:
        return _judge_by_declared(ctx, case, job, ending, fields, declared)
    result = _judge(ctx, case, job, ending, fields)
    if result.outcome == Outcome.FAIL:
        _hint_other_reading(ctx, case, job, ending, fields, result)
    return result


def _judge(
    ctx: RunContext, case: Case, job: Job, ending: Ending, fields: dict[str, Any], reading_dir: Path | None = None
) -> CaseResult:
    """The case's result from the decoder's ending and outputs: against the case's goldens, or
    against what another reading gives (``reading_dir``: its outputs, or reject.json)."""
    if reading_dir is None:
        invalid, conceal, stages_of_case = case.kind == CaseKind.ERROR, bool(case.expect.get("conceal")), None
    else:  # that reading rejects the stream, or decodes it (an invalid stream's FAPs)
        invalid, conceal = (reading_dir / REJECT).is_file(), False
        stages_of_case = ["faps"] if case.kind == CaseKind.ERROR else None
    verdict = outcome_for(ending, invalid_stream=invalid, conceal_allowed=conceal)
    if verdict is not None:
        outcome, msg = verdict
        return CaseResult(**fields, outcome=outcome, message=msg)
    stages = compare_outputs(
        case,
        job,
        golden=ctx.golden,
        outputs=ctx.adapter.outputs,
        out_dir=ctx.out_dir,
        gdir=reading_dir,
        stages_of_case=stages_of_case,
    )
    outcome = worst(s.outcome for s in stages)
    failing = [s for s in stages if s.outcome != Outcome.PASS]
    msg = (
        "; ".join(f"{s.stage}: {s.message}" for s in failing)
        if failing
        else f"{', '.join(s.stage for s in stages)} match"
    )
    return CaseResult(**fields, outcome=outcome, message=msg, stages=stages)


def _judge_by_declared(
    ctx: RunContext, case: Case, job: Job, ending: Ending, fields: dict[str, Any], declared: dict[str, Path]
) -> CaseResult:
    """A case that a reading the decoder declared changes: judged by what that reading gives (the
    first declared one that the result equals; a decoder follows one reading)."""
    first = None
    for rid, rdir in declared.items():
        r = _judge(ctx, case, job, ending, dict(fields, reading=rid), rdir)
        if r.outcome.ok:
            r.message = f"judged by the declared reading {rid}: {r.message}"
            return r
        first = first or r
    if first is None:  # declared is never empty here (the caller's condition)
        raise ValueError(f"{case.full_id}: no declared reading to judge by")
    if _judge(ctx, case, job, ending, dict(fields)).outcome.ok:
        first.message = (
            f"decoded by fbaconf's reading, not the declared {', '.join(declared)} (which changes "
            f"this case): a decoder follows the reading it declares; {first.message}"
        )
    else:
        first.message = f"judged by the declared reading {', '.join(declared)}: {first.message}"
    first.reading = None  # not a provisional difference: a failure
    return first


def _hint_other_reading(
    ctx: RunContext, case: Case, job: Job, ending: Ending, fields: dict[str, Any], result: CaseResult
) -> None:
    """A failing result that equals what another (undeclared) reading gives says so: the vendor
    learns which reading the decoder follows and how to declare it; it stays a failure."""
    for rid, rdir in reading_goldens(case, ctx.golden).items():
        if _judge(ctx, case, job, ending, fields, rdir).outcome.ok:
            result.other_reading = rid
            result.message += (
                f" — this is what the other reading {rid} gives ({readings.get(rid).text}); a "
                f'decoder that follows it declares readings = ["{rid}"] in its manifest'
            )
            return


def hidden_from_decoders(ctx: RunContext | None = None) -> list[Path]:
    """What a sandboxed decoder must never see even where fbaconf's own files are visible (the
    ``{python}`` view shows the fbaconf package): the goldens, the suites, the run folder
    (results, other cases, reports). The case's own suite folder is added per case, and a
    signing key by :func:`fbaconf.isolation.sandbox.keep_secret`."""
    out = [Path(golden_root()).resolve(), Path(suites_root()).resolve()]
    if ctx is not None:
        out += [Path(ctx.golden).resolve(), Path(ctx.out_dir).resolve()]
    return out


# ------------------------------------------------------------------------ many cases


class Progress:
    """Progress on stderr: a one-line bar on a terminal; plain lines (at most one every
    ``LINE_EVERY_S`` seconds, and the last) in CI logs; nothing when disabled."""

    LINE_EVERY_S = 5.0

    def __init__(self, total: int, enabled: bool | None = None) -> None:
        self.total, self.done = total, 0
        self.counts: dict[str, int] = {}
        self.enabled = enabled is not False
        self.tty = sys.stderr.isatty()
        self.t0 = self.last = time.perf_counter()
        self.lock = threading.Lock()

    def update(self, r: CaseResult) -> None:
        with self.lock:
            self.done += 1
            self.counts[r.outcome.value] = self.counts.get(r.outcome.value, 0) + 1
            if not self.enabled:
                return
            now = time.perf_counter()
            rate = self.done / max(1e-9, now - self.t0)
            counts = " ".join(f"{k} {v}" for k, v in sorted(self.counts.items()))
            if not self.tty:
                if self.done == self.total or now - self.last >= self.LINE_EVERY_S:
                    self.last = now
                    sys.stderr.write(f"fbaconf: {self.done}/{self.total} cases ({rate:.1f}/s) {counts}\n")
                    sys.stderr.flush()
                return
            w = 30
            fill = int(w * self.done / max(1, self.total))
            sys.stderr.write(
                f"\r[{'#' * fill}{'.' * (w - fill)}] {self.done}/{self.total} ({rate:.1f}/s) {counts}\x1b[K"
            )
            if self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def run_cases(  # noqa: PLR0913 - keyword options of a run
    adapter: Adapter,
    cases: list[Case],
    *,
    claim: str | None,
    out_dir: Path,
    jobs: int | None = None,
    resume: bool = False,
    keep_workdirs: bool = False,
    progress: bool | None = None,
    golden: Path | None = None,
    on_result: Callable[[CaseResult], None] | None = None,
    cluster: str | None = None,
) -> list[CaseResult]:
    """Run ``cases``; returns results in case order. ``out_dir/results.jsonl`` is the live log.
    Every path is made absolute first: decoders run in their own folders."""
    out_dir = Path(out_dir).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    log = ResultLog(out_dir / "results.jsonl")
    done = log.read() if resume else {}
    if not resume and log.path.exists():
        log.path.unlink()
    work_root = out_dir / "work"
    work_root.mkdir(exist_ok=True)
    ctx = RunContext(adapter, claim, out_dir, golden or golden_root(), keep_workdirs, work_root)
    todo = [c for c in cases if c.full_id not in done]
    bar = Progress(len(cases), progress)
    for r in done.values():
        bar.update(r)
    results: dict[str, CaseResult] = dict(done)
    jobs = jobs or os.cpu_count() or 1

    def one(case: Case) -> CaseResult | None:
        if sandbox.stopping():
            return None  # interrupted: not run, not logged (--resume runs it)
        r = run_case(ctx, case)
        if sandbox.stopping():
            return None  # killed by the interruption: its result is not the decoder's
        log.append(r)
        bar.update(r)
        if on_result:
            on_result(r)
        return r

    if cluster:

        def record(r: CaseResult) -> None:
            if sandbox.stopping():
                return
            log.append(r)
            bar.update(r)
            if on_result:
                on_result(r)
            results[r.case_id] = r

        with cl.client(cluster) as cli:
            cl.run_on_cluster(cli, run_case, ctx, todo, record, sandbox.stopping)
    elif jobs <= 1:
        for c in todo:
            got = one(c)
            if got is not None:
                results[c.full_id] = got
    else:
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            futs = {ex.submit(one, c): c for c in todo}
            for f in as_completed(futs):
                got = f.result()
                if got is not None:
                    results[futs[f].full_id] = got
    if not keep_workdirs:
        _remove_quietly(work_root)
    return [results[c.full_id] for c in cases if c.full_id in results]
