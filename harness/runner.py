"""Run conformance cases against a decoder adapter and judge each one.

Per case: capability check (claim, tools, inputs, outputs — NotSupported before anything
runs) -> own temporary directory with copies of the inputs -> one decoder invocation
under the adapter's limits (:mod:`sandbox`) -> classification of the process (Timeout,
Crash with the signal named, Fail on a non-zero exit or over-size output, NotSupported on
exit 69) -> the comparison ladder (FAPs exactly, vertices within tolerance, images with
OpenImageIO + CIEDE2000) against the case's goldens. Cases run in parallel threads
(``-j``); each result is appended to ``results.jsonl`` as soon as it is known, so an
interrupted run loses nothing and ``--resume`` continues where it stopped.

Error cases (invalid streams) pass when the decoder terminates within its limits — with
any exit code, since rejecting the stream is correct and so is concealment — and fail when
it crashes, hangs or blows its memory or output limit.
"""
from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from fbaconf.conformance.suite import Case, golden_root
from fbaconf.errors import FbaconfInputError
from fbaconf.profiles.model import Claim, load_profiles

from . import exits, sandbox
from fbaconf.safefs import remove_tree
from .adapters import OUTPUT_PLACEHOLDER, Adapter, CommandAdapter, Job, NotSupportedError, PythonAdapter
from .results import CaseResult, Outcome, ResultLog, StageResult

# ------------------------------------------------------------------------ claims


def claim_covers(claimed: str, case_claim: str) -> bool:
    """A decoder claiming ``claimed`` must pass cases of ``case_claim``: the case's profile is
    the claimed one or included in it, and the case's level is at most the claimed level."""
    ps = load_profiles()
    a, b = Claim.parse(claimed, ps), Claim.parse(case_claim, ps)
    return ps.profile_includes(a.profile, b.profile) and b.level <= a.level


INFORMATIVE_GROUPS = ("text",)  # player cases (.fap text): no MPEG-4 profile claim requires them


def required_for(claim: str | None, case: Case, player: bool = False) -> bool:
    """Whether a claim requires ``case``: its profile and level are covered, and — unless the
    program is a player (it reads only .fap text) — it is not a player case (an MPEG-4
    profile claim is about the binary stream; docs/harness.md)."""
    if claim is not None and case.group in INFORMATIVE_GROUPS and not player:
        return False
    return claim is None or claim_covers(claim, case.claim)


def capability(adapter: Adapter, case: Case) -> str | None:
    """Why ``adapter`` cannot run ``case`` (-> NotSupported), or None when it can."""
    if not any(claim_covers(c, case.claim) for c in adapter.claims):
        return f"case requires {case.claim}, outside the decoder's claims ({', '.join(adapter.claims)})"
    if adapter.tools is not None:
        missing = [t for t in case.tools if t not in adapter.tools]
        if missing:
            return f"case uses tool(s) {', '.join(missing)} the decoder does not declare"
    if case.kind == "multi":
        if not case.inputs.get("faces"):
            return "multi-face case without face streams"
        if not adapter.supports_multi:
            return "case decodes several faces at once; the decoder has no decode_multi command"
        if "fba" not in adapter.inputs:
            return "multi-face cases are binary streams; the decoder does not accept fba"
    else:
        if not (("fba" in adapter.inputs and case.inputs.get("fba")) or
                ("fap" in adapter.inputs and case.inputs.get("fap"))):
            forms = [k for k in ("fba", "fap") if case.inputs.get(k)]
            return f"case comes as {'/'.join(forms) or 'nothing'}; the decoder accepts {'/'.join(adapter.inputs)}"
        if case.inputs.get("scene") or case.inputs.get("bifs"):
            if not (("scene" in adapter.inputs and case.inputs.get("scene")) or
                    ("bifs" in adapter.inputs and case.inputs.get("bifs"))):
                return "case carries a scene (FDP/FIT/FaceDefTables/model); the decoder accepts no scene input"
    if case.kind != "error" and case.stages and not set(case.stages) & set(adapter.outputs):
        return f"case compares {', '.join(case.stages)}; the decoder outputs {', '.join(adapter.outputs)}"
    return None


# ------------------------------------------------------------------------ one case


@dataclass
class RunContext:
    adapter: Adapter
    claim: str | None
    out_dir: Path  # run output folder (artefacts/<case>/ for failing images)
    golden: Path = field(default_factory=golden_root)
    keep_workdirs: bool = False
    work_root: Path | None = None


def _prepare(ctx: RunContext, case: Case, workdir: Path) -> Job:
    ind = workdir / "in"
    outd = workdir / "out"
    ind.mkdir(parents=True)
    outd.mkdir()
    values: dict[str, str] = {}

    def copy(key: str) -> str | None:
        src = case.input_path(key)
        if src is None:
            return None
        dst = ind / src.name
        shutil.copyfile(src, dst)
        return str(dst)

    for key, ph in (("fba", "fba"), ("fap", "fap"), ("scene", "scene_bt"), ("bifs", "scene_bifs"),
                    ("scenario", "scenario")):
        v = copy(key)
        if v is not None:
            values[ph] = v
    a = ctx.adapter
    if "fba" in a.inputs and "fba" in values:
        # A decoder of the binary stream never gets the .fap form of the case: that text is
        # what the reference decoded, i.e. the expected output.
        values["input"] = values["fba"]
        fap = values.pop("fap", None)
        if fap is not None:
            Path(fap).unlink()
    elif "fap" in a.inputs and "fap" in values:
        values["input"] = values["fap"]
    if "scene" in a.inputs and "scene_bt" in values:
        values["scene"] = values["scene_bt"]
    elif "bifs" in a.inputs and "scene_bifs" in values:
        values["scene"] = values["scene_bifs"]
    # auxiliary files of the case (e.g. a texture the scene names by a relative URL) travel with it
    if case.suite_dir is not None:
        named = {Path(v).name for k, v in values.items()}
        for rel in case.sha256:
            src = case.suite_dir / rel
            if src.name not in named and rel not in case.inputs.get("faces", []) and src.is_file() \
                    and not (ind / src.name).exists():
                shutil.copyfile(src, ind / src.name)
    ext = "fap" if a.faps_format == "fap" else "npz"
    values["faps_out"] = str(outd / f"faps.{ext}")
    values["vertices_out"] = str(outd / "vertices.npz")
    values["images_dir"] = str(outd / "images")
    values["faps_out_dir"] = str(outd / "faces")
    (outd / "images").mkdir()
    (outd / "faces").mkdir()
    faces = []
    for src in case.face_paths():
        dst = ind / src.name
        shutil.copyfile(src, dst)
        faces.append(str(dst))
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
    required = required_for(ctx.claim, case, player="fba" not in ctx.adapter.inputs)
    base = dict(case_id=case.full_id, suite=case.suite, claim=case.claim, required=required)
    why = capability(ctx.adapter, case)
    if why:
        return CaseResult(**base, outcome=Outcome.NOT_SUPPORTED, message=why)
    workdir = Path(tempfile.mkdtemp(prefix="case-", dir=ctx.work_root))
    try:
        job = _prepare(ctx, case, workdir)
        result = _execute(ctx, case, job, base)
    except Exception as e:  # a harness problem, never the decoder's verdict
        result = CaseResult(**base, outcome=Outcome.ERROR,
                            message=f"harness error: {type(e).__name__}: {e}",
                            stderr_tail=traceback.format_exc(limit=3)[-2000:])
    finally:
        if not ctx.keep_workdirs:
            _remove_quietly(workdir)
    result.duration_s = time.perf_counter() - t0
    return result


def _execute(ctx: RunContext, case: Case, job: Job, base: dict) -> CaseResult:
    a = ctx.adapter
    argv = None
    if isinstance(a, CommandAdapter):
        cmd = "decode_multi" if case.kind == "multi" else "decode"
        try:
            argv = a.argv(cmd, job)
        except KeyError as e:
            return CaseResult(**base, outcome=Outcome.NOT_SUPPORTED,
                              message=f"[commands] {cmd} needs {{{e.args[0]}}}, which this case does not have")
        view = a.sandbox_view(argv, job.workdir, hidden=hidden_from_decoders(ctx))
        res = sandbox.run(argv, job.workdir, a.limits, env=a.env, view=view)
        ending = exits.classify(res, a.limits, a.reject_exit_codes)
        proc = dict(command=argv, exit_code=res.returncode, signal=res.signal, stderr_tail=res.stderr_tail[-2000:])
    else:
        ending, proc = _run_python(a, job)
    verdict = exits.outcome_for(ending, invalid_stream=case.kind == "error",
                                conceal_allowed=bool(case.expect.get("conceal")))
    if ending.report is not None:
        proc["crash_kind"] = ending.report.kind
    if verdict is not None:
        outcome, msg = verdict
        return CaseResult(**base, outcome=outcome, message=msg, **proc)
    stages = compare_outputs(ctx, case, job)
    from .compare import worst
    outcome = worst(s.outcome for s in stages)
    failing = [s for s in stages if s.outcome != Outcome.PASS]
    msg = "; ".join(f"{s.stage}: {s.message}" for s in failing) if failing else \
        f"{', '.join(s.stage for s in stages)} match"
    return CaseResult(**base, outcome=outcome, message=msg, stages=stages, **proc)


def hidden_from_decoders(ctx: RunContext | None = None) -> list[Path]:
    """What a sandboxed decoder must never see even where fbaconf's own files are visible:
    the goldens, the suites, the run folder (results, other cases, reports), the git tree."""
    from fbaconf.conformance.suite import suites_root
    import fbaconf
    root = Path(fbaconf.__file__).resolve().parent.parent
    out = [Path(golden_root()).resolve(), Path(suites_root()).resolve(), root / ".git"]
    if ctx is not None:
        out += [Path(ctx.golden).resolve(), Path(ctx.out_dir).resolve()]
    return out


def _run_python(a: PythonAdapter, job: Job):
    """Call an in-process adapter; its ending in the terms of :mod:`.exits` (a typed input
    error is its reject, an uncaught exception its crash)."""
    t0 = time.perf_counter()
    proc = dict(command=None, exit_code=None, signal=None, stderr_tail="")
    try:
        a.run(job)
    except NotSupportedError as e:
        return exits.Ending("not-supported", f"decoder: not supported: {e}"), proc
    except MemoryError:
        return exits.Ending("memory", "in-process decoder raised MemoryError"), proc
    except FbaconfInputError as e:
        proc["exit_code"] = 2
        proc["stderr_tail"] = str(e)[-2000:]
        if e.rule == "io":
            return exits.Ending("setup", f"in-process decoder could not read its input: {e}"), proc
        return exits.Ending("reject", f"in-process decoder rejected the stream: {e}"), proc
    except Exception as e:
        tb = traceback.format_exc(limit=5)
        proc["stderr_tail"] = tb[-2000:]
        proc["exit_code"] = 1
        return exits.Ending("crash", f"in-process decoder raised {type(e).__name__}: {e}",
                            exits.crash_report(traceback.format_exc())), proc
    dt = time.perf_counter() - t0
    if dt > a.limits.timeout_s:
        return exits.Ending("timeout", f"in-process decoder took {dt:.1f} s, over the {a.limits.timeout_s:g} s "
                                       f"limit"), proc
    proc["exit_code"] = 0
    return exits.Ending("decoded", "in-process decoder returned"), proc


# ------------------------------------------------------------------------ comparison


def compare_outputs(ctx: RunContext, case: Case, job: Job) -> list[StageResult]:
    from . import compare as cmp
    gdir = case.golden_dir(ctx.golden)
    a = ctx.adapter
    stages: list[StageResult] = []
    if case.kind == "multi":
        from fbaconf.bitstreams.frames import FapFrames
        outd = job.path("faps_out_dir")
        for i, (src, gold) in enumerate(zip(case.face_paths(), case.goldens.get("faces", []))):
            expected = FapFrames.load_npz(gdir / gold)
            cand = [outd / f"{src.stem}.{ext}" for ext in ("npz", "fap")]
            got_path = next((p for p in cand if os.path.lexists(p)), None)
            if got_path is None:
                stages.append(StageResult(f"faps[face {i}]", Outcome.FAIL,
                                          f"no output for face {i} ({src.name}): expected {cand[0].name} or "
                                          f"{cand[1].name} in the output folder"))
                continue
            stages.append(_faps_stage(cmp, expected, got_path, f"faps[face {i}]"))
        return stages
    for stage in case.stages:
        if stage not in a.outputs:
            continue
        if stage == "faps":
            from fbaconf.bitstreams.frames import FapFrames
            gp = gdir / case.goldens["faps"]
            if not gp.is_file():
                stages.append(StageResult("faps", Outcome.ERROR, f"golden missing: {gp} (run fbaconf golden regenerate)"))
                continue
            text_in = job.values.get("input", "").lower().endswith(".fap")
            stages.append(_faps_stage(cmp, FapFrames.load_npz(gp), job.path("faps_out"), "faps", text_in))
        elif stage == "vertices":
            stages.append(_vertices_stage(cmp, case, gdir, job))
        elif stage == "images":
            stages.append(_images_stage(cmp, ctx, case, gdir, job))
    return stages


def _faps_stage(cmp, expected, got_path: Path, name: str, text_input: bool = False) -> StageResult:
    """Decoded FAPs, exactly. With ``.fap`` text output there is no SET/RETAINED distinction to
    compare, only the values of every FAP the standard fixes; a player (``.fap`` input) is
    compared on its state (harness/compare/faps.py)."""
    if got_path is None or not os.path.lexists(got_path):
        return StageResult(name, Outcome.FAIL, "decoder exited 0 but wrote no FAP output"
                           + (f" ({got_path.name})" if got_path else ""))
    try:
        # A generous cap from the expected length keeps a hostile output from costing the
        # harness memory far beyond what the case can need.
        got = cmp.load_output_faps(got_path, max_bytes=min(cmp.DEFAULT_MAX_BYTES,
                                                            (1 << 20) + 8192 * len(expected.values)))
    except cmp.OutputError as e:
        return StageResult(name, Outcome.FAIL, f"unreadable FAP output: {e}")
    r = cmp.compare_faps(expected, got, text_output=got_path.suffix.lower() == ".fap", player=text_input)
    r.stage = name
    return r


def _vertices_stage(cmp, case: Case, gdir: Path, job: Job) -> StageResult:
    tol = dict(case.tolerances.get("vertices", {}))
    key = tol.pop("key", "vertices")
    gp = gdir / case.goldens["vertices"]
    if not gp.is_file():
        return StageResult("vertices", Outcome.ERROR, f"golden missing: {gp} (run fbaconf golden regenerate)")
    got_path = job.path("vertices_out")
    if not os.path.lexists(got_path):
        return StageResult("vertices", Outcome.FAIL, "decoder exited 0 but wrote no vertices output")
    if key == "extra_fap_values":
        return _effective_faps_stage(cmp, gp, got_path, tol)
    expected = cmp.load_output_vertices(gp, key=key)
    try:
        got = cmp.load_output_vertices(got_path, key=key)
    except cmp.OutputError as e:
        return StageResult("vertices", Outcome.FAIL, f"unreadable vertices output: {e}")
    vt = cmp.VertexTolerances.from_dict(None, tol)
    part_of = _part_lookup(gp) if key == "vertices" else None
    what = "vertices" if key == "vertices" else key.removeprefix("extra_")
    r = cmp.compare_vertices(expected, got, max_tol=vt.max_tol, rms_tol=vt.rms_tol, part_of=part_of, what=what)
    r.stage = what if what == "vertices" else f"vertices[{what}]"
    return r


def _load_effective(path: Path):
    """``extra_fap_values`` of a vertices output, read as defensively as every output."""
    import numpy as np
    from . import compare as cmp
    cmp.check_output_file(path, cmp.DEFAULT_MAX_BYTES)
    with cmp.open_npz(path, cmp.DEFAULT_MAX_BYTES) as z:
        if "extra_fap_values" not in z:
            raise ValueError("no array 'extra_fap_values' (effective FAP values after FIT and left/right fill)")
        a = z.get("extra_fap_values")
    if a.ndim != 2 or a.shape[1] != 68 or a.dtype.kind not in "fiu":
        raise ValueError(f"'extra_fap_values' must be numbers [frames, 68], not {a.dtype}{list(a.shape)}")
    return a.astype(np.float64)


def _effective_faps_stage(cmp, golden: Path, got_path: Path, tol: dict) -> StageResult:
    """Effective FAPs after FIT / left-right fill (FaceState extra ``fap_values``), float tolerance."""
    import numpy as np
    from fbaconf.bitstreams.tables import fap_table
    name = "effective_faps"
    exp = _load_effective(golden)
    try:
        got = _load_effective(got_path)
    except Exception as e:  # untrusted file
        return StageResult(name, Outcome.FAIL, f"unreadable effective FAP output: {type(e).__name__}: {e}")
    if got.shape != exp.shape:
        return StageResult(name, Outcome.FAIL, f"shape {list(got.shape)}, expected {list(exp.shape)}",
                           first_difference={"what": "shape", "expected": list(exp.shape), "got": list(got.shape)})
    atol = float(tol.get("max_tol", 1e-6))
    diff = np.abs(np.nan_to_num(got - exp, nan=np.inf))
    per_frame = diff.max(axis=1) if diff.size else np.zeros(0)
    series = {"max |effective FAP error|": [float(x) for x in np.minimum(per_frame, 1e30)]}
    bad = np.argwhere(diff > atol)
    if len(bad) == 0:
        return StageResult(name, Outcome.PASS, "effective FAPs match", metrics={"max_abs_diff": float(diff.max(initial=0))},
                           series=series)
    f, j = (int(x) for x in bad[0])
    fd = {"frame": f, "fap": j + 1, "name": fap_table()[j].name, "expected": float(exp[f, j]), "got": float(got[f, j])}
    return StageResult(name, Outcome.FAIL,
                       f"frame {f}, FAP {j + 1} ({fd['name']}): expected {exp[f, j]:g}, got {got[f, j]:g} "
                       f"(tolerance {atol:g}); {len(bad)} value(s) off", first_difference=fd,
                       metrics={"max_abs_diff": float(diff.max()), "values_differing": float(len(bad))}, series=series)


def _part_lookup(golden_vertices: Path) -> Callable[[int], str] | None:
    """Mesh part names of the golden FaceState, for naming a diverging vertex."""
    from fbaconf.animation.stateio import load_npz
    from .compare import part_namer
    try:
        return part_namer(load_npz(golden_vertices).parts)
    except (OSError, ValueError, KeyError):
        return None


def image_frame_numbers(names: list[str]) -> list[int] | None:
    """The sequence frame number of each image (``frame_00010.png`` -> 10), so reports name
    the frames the scenario lists, not their positions; None if a name does not say."""
    out = []
    for n in names:
        m = re.fullmatch(r"frame_(\d+)\.png", n)
        if not m:
            return None
        out.append(int(m.group(1)))
    return out


def _images_stage(cmp, ctx: RunContext, case: Case, gdir: Path, job: Job) -> StageResult:
    names = case.goldens.get("images", [])
    expected = [gdir / n for n in names]
    missing = [p for p in expected if not p.is_file()]
    if missing:
        return StageResult("images", Outcome.ERROR, f"golden missing: {missing[0]} (run fbaconf golden regenerate)")
    got = [job.path("images_dir") / n for n in names]
    tol = cmp.ImageTolerances.from_dict(None, case.tolerances.get("images", {}))
    art = ctx.out_dir / "artefacts" / case.suite / case.id
    r = cmp.compare_images(expected, got, tol, art, relative_to=ctx.out_dir, frames=image_frame_numbers(names))
    if r.outcome == Outcome.PASS:
        shutil.rmtree(art, ignore_errors=True)
    return r


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
            sys.stderr.write(f"\r[{'#' * fill}{'.' * (w - fill)}] {self.done}/{self.total} "
                             f"({rate:.1f}/s) {counts}\x1b[K")
            if self.done == self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()


def run_cases(adapter: Adapter, cases: list[Case], *, claim: str | None, out_dir: Path, jobs: int | None = None,
              resume: bool = False, keep_workdirs: bool = False, progress: bool | None = None,
              golden: Path | None = None, on_result: Callable[[CaseResult], None] | None = None,
              cluster: str | None = None) -> list[CaseResult]:
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
        from . import cluster as cl

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
            r = one(c)
            if r is not None:
                results[c.full_id] = r
    else:
        with ThreadPoolExecutor(max_workers=jobs) as ex:
            futs = {ex.submit(one, c): c for c in todo}
            for f in as_completed(futs):
                r = f.result()
                if r is not None:
                    results[futs[f].full_id] = r
    if not keep_workdirs:
        _remove_quietly(work_root)
    return [results[c.full_id] for c in cases if c.full_id in results]
