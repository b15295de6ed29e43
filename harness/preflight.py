"""Before any case: say how isolated decoders run here, check that a command decoder's program
exists and what its commands would show, and run the canary — the claim's simplest valid stream,
exactly as a case runs — so that a decoder that cannot start is one set-up error, never a Fail per
case (:mod:`fbaconf.isolation.setup`)."""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from fbaconf.conformance.provisional import rests_on
from fbaconf.conformance.suite import Case, CaseKind, load_suites
from fbaconf.isolation import setup
from fbaconf.isolation.report import report

from .adapters import Adapter, CommandAdapter, Job
from .manifest import PLACEHOLDERS
from .runner import hidden_from_decoders, prepare_job
from .selection import capability, required_for, select_cases
from .usage import UsageError


def preflight(adapter: Adapter, claim: str | None = None) -> float | None:
    """Before any case: one line saying whether decoders are isolated here and by which limits;
    a command decoder's program must exist and be executable, and every folder its commands
    would show must pass the view's checks (ViewError, exit 2). With ``claim``: the canary
    (:func:`canary`: SetupError, exit 2, when the decoder does not decode the claim's simplest
    valid stream); returns the seconds it took (None: none ran)."""
    print(report(adapter).notice(), file=sys.stderr)
    if not isinstance(adapter, CommandAdapter):
        return None
    prog = adapter.program()
    # the folders its commands would show (program, the files they name, manifest, --sandbox-ro), case files aside
    at = Path("/nonexistent-case")
    job = Job(
        at,
        {p: str(at / p) for p in PLACEHOLDERS if p not in ("python", "manifest_dir", "workdir", "frames")},
        faces=[str(at / "face.fba")],
        frames=1,
    )
    for name in adapter.commands:
        adapter.sandbox_view(adapter.argv(name, job), at, hidden=hidden_from_decoders())
    if prog is None:
        first = str(adapter.commands["decode"][0])
        where = Path(adapter.manifest_path).resolve().parent if adapter.manifest_path is not None else None
        shown = os.path.normpath(first.replace("{manifest_dir}", str(where))) if where is not None else first
        raise UsageError(
            f"decoder {adapter.name}: program {shown} not found (not a file, and not on PATH)"
            + (f'; [commands] decode names it "{first}": build the decoder first' if shown != first else "")
        )
    if not os.access(prog, os.X_OK):
        raise UsageError(f"decoder {adapter.name}: program {prog} is not executable")
    return canary(adapter, claim) if claim is not None else None


def canary_case(adapter: Adapter, claim: str) -> Case | None:
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


def canary(adapter: CommandAdapter, claim: str) -> float | None:
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
        setup.probe(
            argv,
            job.workdir,
            adapter.limits,
            name=adapter.name,
            env=adapter.env,
            what=f"the claim's simplest valid stream ({case.full_id})",
            file=str(adapter.manifest_path or adapter.name),
            reject_exit_codes=adapter.reject_exit_codes,
            view=adapter.sandbox_view(argv, job.workdir, hidden=hidden),
        )
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return time.perf_counter() - t0
