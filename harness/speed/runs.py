"""The runs of one speed measurement: the decoder on fresh content of a given length — spawned as
the certified ``decode`` command, through ``serve`` when declared equivalent and proven so, or
in-process — each timed with the machine read around it and its output judged on a sample
(:mod:`.check`); :mod:`.measure` fits the line through them."""

from __future__ import annotations

import math
import os
import secrets
from collections.abc import Callable
from pathlib import Path

from fbaconf.errors import FbaconfInputError
from fbaconf.isolation import endings, sandbox
from fbaconf.isolation.persistent import PersistentDecoder
from fbaconf.isolation.process import ProcResult
from fbaconf.safefs import remove_tree

from .. import sysinfo
from ..adapters import Adapter, CommandAdapter, Job, PythonAdapter
from ..compare.base import OutputError
from ..compare.faps import compare_faps
from ..compare.ladder import outcome_for
from ..compare.loaders import load_output_faps
from ..results import Outcome
from ..runner import hidden_from_decoders
from . import load as speed_load
from .check import RANDOM_IMAGES, faps_problem, images_problem, sample
from .content import Content, Run

OPERATIONS = ("decode", "render")
LIMIT_FOR = {"decode": "decode_rate", "render": "render_rate"}
EQUIVALENCE_FACTOR = 1.5  # decode's per-frame cost may exceed serve's by this much (timing noise)
START_FRAMES = 8  # first length of the adaptive search
SERIES = (0.1, 0.5, 1.0)  # the measured lengths, as fractions of the largest
DEFAULT_RENDER_SIZE = (64, 64)
RENDER_SUPERSAMPLE = 2  # samples per pixel side the render scenario asks for (the image cases')
# the decode operation's images, when its command always writes some: at 8 x 8 the head's edges are
# most of the picture, and a faithful renderer at 2 x 2 samples per pixel missed the image stage's
# mean-colour-difference bound on 1 of 40 random contents (ΔE2000 mean up to 1.63 over 60, bound 1.5);
# at 32 x 32 the worst of 60 was 0.45
DECODE_IMAGE_SIZE = 32


class SpeedError(FbaconfInputError):
    """The speed measurement cannot be set up (unknown operation or claim, impossible command)."""

    rule = "speed-setup"


class SpeedRunError(Exception):
    """A decoder run failed during the speed measurement (exit code, crash, timeout, no output)."""

    def __init__(
        self,
        operation: str,
        frames: int,
        outcome: Outcome,
        message: str,
        argv: list[str] | None = None,
        stderr_tail: str = "",
    ) -> None:
        super().__init__(f"{operation} of {frames} frames: {message}")
        self.operation = operation
        self.frames = frames
        self.outcome = outcome
        self.message = message
        self.argv = argv
        self.stderr_tail = stderr_tail


# --------------------------------------------------------------------------- one run


def skip_reason(adapter: Adapter, operation: str) -> str | None:
    """Why ``operation`` cannot be measured for this adapter (None when it can)."""
    if operation not in OPERATIONS:
        raise SpeedError(f"unknown operation {operation!r} (decode, render)")
    if operation == "render" and "images" not in adapter.outputs:
        return f"{adapter.name} does not output images (outputs: {', '.join(adapter.outputs)})"
    if not ({"fba", "fap"} & set(adapter.inputs)):
        return f"{adapter.name} accepts no stream input (fba or fap)"
    return None


def _spawned_stall(
    watch: sysinfo.TreeWatch, cpu_s: float, before: sysinfo.MachineSample, after: sysinfo.MachineSample
) -> tuple[float | None, str]:
    """(the time a spawned decoder's tree waited for a CPU, how it is known): its threads' run-queue
    wait as sampled while they lived, scaled up by the share of its CPU time the samples missed
    (processes too short to be seen); where they saw less than half of it, the machine's PSI
    "some" stall over the run — an upper bound — else unknown."""
    if cpu_s > 0 and watch.cpu_s >= 0.5 * cpu_s:
        return watch.wait_s * max(1.0, cpu_s / watch.cpu_s), "process tree"
    if before.pressure_s is not None and after.pressure_s is not None:
        return after.pressure_s - before.pressure_s, "machine PSI"
    return None, "none"


class _Runner:
    def __init__(
        self,
        adapter: Adapter,
        operation: str,
        content: Content,
        runs_dir: Path,
        render_size: tuple[int, int],
        persistent: bool = True,
    ) -> None:
        self.adapter = adapter
        self.serve_declared = (
            operation == "decode"
            and isinstance(adapter, CommandAdapter)
            and "serve" in adapter.commands
            and getattr(adapter, "serve_equivalent", False)
            and "fba" in adapter.inputs
            and "faps" in adapter.outputs
        )
        self.persistent = persistent and self.serve_declared
        self._server: PersistentDecoder | None = None  # the persistent decoder, started at the first run
        self._watch: sysinfo.TreeWatch | None = None
        self.operation = operation
        self.content = content
        self.runs_dir = runs_dir
        self.render_size = render_size
        self.count = 0
        self.extra: set[str] = set()
        self.notes: list[str] = []
        self._image_frames: list[int] = []  # the frames the current run's scenario asks images of

    def _values(self, run: Run, workdir: Path) -> dict[str, str]:
        a, c, n = self.adapter, self.content, run.n
        v: dict[str, str] = {}
        if "fba" in a.inputs:
            v["fba"] = v["input"] = str(run.fba())
        else:
            v["fap"] = v["input"] = str(run.fap())
        if "fap" in self.extra and "fap" not in v:
            v["fap"] = str(run.fap())
        if "fba" in self.extra and "fba" not in v:
            v["fba"] = str(run.fba())
        out = workdir / "out"
        out.mkdir(parents=True, exist_ok=True)
        ext = "npz" if a.faps_format == "npz" else "fap"
        wanted = set(self.extra)
        if self.operation == "render":
            wanted.add("images_dir")
        elif "faps" in a.outputs:
            wanted.add("faps_out")
        elif "vertices" in a.outputs:
            wanted.add("vertices_out")
        else:
            wanted.add("images_dir")
        if "faps_out" in wanted:
            v["faps_out"] = str(out / f"faps.{ext}")
        if "vertices_out" in wanted:
            v["vertices_out"] = str(out / "vertices.npz")
        if "images_dir" in wanted:
            v["images_dir"] = str(out / "images")
        if self.operation == "render":
            w, h = self.render_size
            self._image_frames = []  # every frame; the sample is drawn after the run
            v["scenario"] = str(
                c.scenario(f"render-{w}x{h}", width=w, height=h, supersample=RENDER_SUPERSAMPLE, frames=None)
            )
        else:  # two small frames: the first (it places the camera) and one drawn for this run
            k = secrets.SystemRandom().randrange(1, n) if n > 1 else 0
            self._image_frames = sorted({0, k})
            s = DECODE_IMAGE_SIZE
            v["scenario"] = str(
                c.scenario(
                    f"decode-frames-{'-'.join(map(str, self._image_frames))}",
                    width=s,
                    height=s,
                    supersample=RENDER_SUPERSAMPLE,
                    frames=tuple(self._image_frames),
                )
            )
        if "scene" in wanted:
            # the form the decoder reads: BT unless it declares only the binary BIFS input
            kind = "bifs" if "bifs" in a.inputs and "scene" not in a.inputs else "bt"
            v["scene"] = v[f"scene_{kind}"] = str(c.scene(kind))
        if "faps_out_dir" in wanted:
            v["faps_out_dir"] = str(out / "faces")
        return v

    def _argv(self, job_for: Callable[[], Job]) -> tuple[list[str], Job]:
        """Expand the decode command, adding the placeholders it requires (first call plans)."""
        a = self.adapter
        if not isinstance(a, CommandAdapter):
            raise TypeError(f"{a.name}: an in-process adapter has no command to expand")
        supplied = {"fba", "fap", "vertices_out", "images_dir", "faps_out", "scene", "faps_out_dir"}
        if "fba" in a.inputs:  # the content's .fap is its expected output: never shown to a decoder of the stream
            supplied.discard("fap")
        while True:
            job = job_for()
            try:
                return a.argv("decode", job), job
            except KeyError as e:
                name = e.args[0]
                if name in self.extra or name not in supplied:
                    raise SpeedError(
                        f"{a.name}: the decode command needs {{{name}}}, which a speed measurement cannot supply"
                    ) from None
                self.extra.add(name)
                if name in ("vertices_out", "images_dir") or (name == "faps_out" and self.operation == "render"):
                    what = {
                        "vertices_out": "vertices",
                        "images_dir": f"images (two {DECODE_IMAGE_SIZE}x{DECODE_IMAGE_SIZE} frames requested)",
                        "faps_out": "FAPs",
                    }[name]
                    self.notes.append(f"the decode command always writes {what}; included in the time")
                elif name == "scene":
                    self.notes.append("the command requires a scene: the bundled default head is given")

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None
        if self._watch is not None:
            self._watch.__exit__()
            self._watch = None

    def run(self, n: int) -> speed_load.Window:
        """Time one invocation on ``n`` frames of fresh content: its time and accounting;
        raises SpeedRunError on failure."""
        run = self.content.make(n)
        try:
            if self.persistent:
                return self._serve(run)[0]
            return self._once(run)
        finally:
            run.remove()

    def _once(self, run: Run) -> speed_load.Window:
        """One spawned (or in-process) run of ``decode`` on ``run``, its output judged."""
        self.count += 1
        workdir = self.runs_dir / f"run-{self.count:04d}"
        if workdir.exists():
            remove_tree(workdir)
        workdir.mkdir(parents=True)
        try:
            window, job, argv = self._decode(run, workdir)
            self._check_output(job, run, argv)
            return window
        finally:
            try:
                remove_tree(workdir)
            except OSError:
                pass

    def _decode(self, run: Run, workdir: Path) -> tuple[speed_load.Window, Job, list[str] | None]:
        a, n = self.adapter, run.n

        def job_for() -> Job:
            return Job(workdir=workdir, values=self._values(run, workdir), frames=n)

        if isinstance(a, CommandAdapter):
            argv, job = self._argv(job_for)
            view = a.sandbox_view(argv, workdir, hidden=hidden_from_decoders())
            view.read_only.append(self.content.root)  # the generated content the decoder reads
            before = sysinfo.machine_sample()
            with sysinfo.TreeWatch(os.getpid()) as watch:
                res = sandbox.run(argv, workdir, a.limits, env=a.env or None, view=view)
            after = sysinfo.machine_sample()
            self._judge(res, n, argv)
            # the sandbox's rusage misses its inner processes (they are not reaped by a process
            # the harness waits for): the tree's own readings are the decoder's CPU time
            cpu = max(res.cpu_s, watch.cpu_s)
            stall, source = _spawned_stall(watch, cpu, before, after)
            return (
                speed_load.Window(
                    n,
                    res.elapsed_s,
                    before,
                    after,
                    cpu_s=cpu,
                    stall_s=stall,
                    stall_source=source,
                    outside_own_s=cpu - res.cpu_s,
                ),
                job,
                argv,
            )
        if not isinstance(a, PythonAdapter):  # pragma: no cover - no other adapter kinds
            raise SpeedError(f"unsupported adapter kind {type(a).__name__}")
        job = job_for()
        before, th0 = sysinfo.machine_sample(), sysinfo.thread_cpu_wait()
        ex = a.execute(job)  # the one way an in-process decoder is called (run, speed and fuzz alike)
        elapsed = ex.elapsed_s
        th1, after = sysinfo.thread_cpu_wait(), sysinfo.machine_sample()
        judged = outcome_for(ex.ending)
        if judged is not None:
            raise SpeedRunError(self.operation, n, judged[0], judged[1])
        cpu_s = stall_s = None
        if th0 is not None and th1 is not None:
            cpu_s, stall_s = th1[0] - th0[0], th1[1] - th0[1]
        return (
            speed_load.Window(
                n,
                elapsed,
                before,
                after,
                cpu_s=cpu_s,
                stall_s=stall_s,
                stall_source="thread" if cpu_s is not None else "none",
            ),
            job,
            None,
        )

    def _serve(self, run: Run) -> tuple[speed_load.Window, Path]:
        """One input to the persistent decoder: the time from sending it to its answer; the
        output judged (and left at the returned path until the next input)."""
        a, n = self.adapter, run.n
        if not isinstance(a, CommandAdapter):  # serve is a command's (skip_reason and the manifest say so)
            raise SpeedError(f"{a.name}: only a command decoder has a serve command")
        root = self.runs_dir / "serve"
        workdir = root / "case"
        if self._server is None:
            (workdir / "in").mkdir(parents=True, exist_ok=True)
            job = Job(workdir=workdir, values={}, frames=0)
            argv = a.argv("serve", job)
            view = a.sandbox_view(argv, workdir, hidden=hidden_from_decoders())
            self._server = PersistentDecoder(argv, root, workdir, view, a.limits, env=a.env or None)
            # the serve tree (this process's only children while it runs): its CPU time and wait
            self._watch = sysinfo.TreeWatch(os.getpid()).__enter__()
            self.notes.append(
                "measured through the persistent protocol ([commands] serve, declared equivalent to "
                "decode): one process for every run, no process start-up per sample"
            )
        out = workdir / "out"
        if out.exists():
            remove_tree(out)
        out.mkdir(parents=True)
        path = out / f"faps.{'npz' if a.faps_format == 'npz' else 'fap'}"
        watch, server = self._watch, self._server
        if watch is None:  # started with the server above
            raise SpeedError("the serve process's watch was not started")
        watch.poll()
        tree0, before = (watch.cpu_s, watch.wait_s), sysinfo.machine_sample()
        res = server.run(run.stream_bytes(), str(path))
        watch.poll()
        tree1, after = (watch.cpu_s, watch.wait_s), sysinfo.machine_sample()
        self._judge(res, n, server.argv)
        cpu = tree1[0] - tree0[0]
        window = speed_load.Window(
            n,
            res.elapsed_s,
            before,
            after,
            cpu_s=cpu,
            stall_s=tree1[1] - tree0[1],
            stall_source="process tree",
            outside_own_s=cpu,
            tree_before=tree0[0],
            tree_after=tree1[0],
        )
        self._check_output(Job(workdir=workdir, values={"faps_out": str(path)}, frames=n), run, server.argv)
        return window, path

    def equivalence(self, lengths: list[int], serve_per_frame: float) -> tuple[bool, str]:
        """Prove ``serve_equivalent`` on the speed content (module doc): (whether ``decode``
        is what was timed through ``serve``, what was found). Raises SpeedRunError when a
        run fails or the two outputs differ."""
        best: dict[int, float] = {}
        for n in (lengths[0], lengths[-1]):
            for _ in range(2):
                run = self.content.make(n)
                self.count += 1
                workdir = self.runs_dir / f"equivalence-{self.count:04d}"
                workdir.mkdir(parents=True)
                try:
                    _w, by_serve = self._serve(run)
                    window, job, argv = self._decode(run, workdir)
                    self._check_output(job, run, argv)
                    self._same_frames(job.need("faps_out"), by_serve, n)
                    best[n] = min(best.get(n, math.inf), window.seconds)
                finally:
                    run.remove()
                    remove_tree(workdir)
        lo, hi = lengths[0], lengths[-1]
        slope = (best[hi] - best[lo]) / (hi - lo)
        what = (
            f"decode's per-frame cost {slope * 1000:.3f} ms ({lo} and {hi} frames, fastest of two each) "
            f"against serve's {serve_per_frame * 1000:.3f} ms"
        )
        if slope <= EQUIVALENCE_FACTOR * serve_per_frame:
            return True, (
                f"serve checked against decode on fresh content of {lo} and {hi} frames: the same frames; {what}"
            )
        return False, (
            f"the manifest declares serve equivalent to decode, but {what} (more than "
            f"{EQUIVALENCE_FACTOR:g} x): serve is not what is certified, decode was timed"
        )

    def _same_frames(self, by_decode: Path, by_serve: Path, n: int) -> None:
        limit = self.adapter.limits.output_mb * 2**20
        try:
            d = load_output_faps(by_decode, max_bytes=limit)
            s = load_output_faps(by_serve, max_bytes=limit)
        except OutputError as e:
            raise SpeedRunError(self.operation, n, Outcome.FAIL, f"serve_equivalent: {e}") from None
        r = compare_faps(d, s, text_output=by_serve.suffix == ".fap")
        if not r.outcome.ok:
            raise SpeedRunError(
                self.operation,
                n,
                Outcome.FAIL,
                f"the manifest declares [commands] serve equivalent to decode, but on {n} frames "
                f"serve's output differs from decode's: {r.message}",
                self._server.argv if self._server is not None else None,
            )

    def _judge(self, res: ProcResult, n: int, argv: list[str] | None) -> None:
        """A run that did not decode (exit code, crash, timeout...) fails the measurement."""
        a = self.adapter
        verdict = outcome_for(endings.classify(res, a.limits, a.reject_exit_codes, name=a.name))
        if verdict is not None:
            raise SpeedRunError(self.operation, n, verdict[0], verdict[1], argv, res.stderr_tail)

    def _check_output(self, job: Job, run: Run, argv: list[str] | None) -> None:
        n = run.n
        key = (
            "images_dir"
            if self.operation == "render"
            else next(k for k in ("faps_out", "vertices_out", "images_dir") if k in job.values)
        )
        p = job.need(key)
        limit = self.adapter.limits.output_mb * 2**20
        why = None
        if key == "faps_out":
            why = faps_problem(p, run, max_bytes=limit, player="fba" not in self.adapter.inputs)
            if why is not None:
                why = why.replace("its output", f"its output at {{{key}}}")
        elif key == "vertices_out":
            if not (p.is_file() and p.stat().st_size > 0):
                why = f"finished but wrote no output at {{{key}}} ({p})"
        else:
            ks = self._image_frames or sample(n, RANDOM_IMAGES).tolist()
            size = self.render_size if self.operation == "render" else (DECODE_IMAGE_SIZE, DECODE_IMAGE_SIZE)
            # the reference renders the bundled default head: the scene a command that asks for one is given
            why = images_problem(p, run, ks, width=size[0], height=size[1], max_bytes=limit)
        if why is not None:
            raise SpeedRunError(self.operation, n, Outcome.FAIL, f"the decoder {why}", argv)


# --------------------------------------------------------------------------- fitting
