"""Decoder speed: per-frame decode and render cost, free of process start-up, against the
claimed level's minimum rates (``decode_rate``, ``render_rate`` in ``profiles.toml``).

Method. The decoder runs the same content at several lengths ``n`` (frames); every run is
timed (wall clock of the whole invocation, or of ``adapter.run(job)`` for in-process
adapters) and a straight line ``time = startup + n * per_frame`` is fitted by least
squares. The series of lengths is repeated ``repeats`` times (alternately ascending and
descending, so slow drift does not bias the slope); the reported per-frame cost and
start-up are the medians over the repeats, and ``fit_r2`` is the coefficient of
determination of that median line over every sample. The measured rate is
``1 / per_frame``; it passes when it is at least the level minimum.

Lengths. Unless given, they adapt to the decoder: after one discarded warm-up run, the
length grows (by the measured slope, at least x2 and at most x8 per step) until the
frame-dependent part of the largest run (its time minus the smallest run's) reaches
``target_s`` and the smallest run's time (mostly start-up) — so it dominates start-up
noise — or a run would pass ``max_run_s`` or the length ``max_frames``. The series is then ``n/10, n/2, n``.

Content. A procedural sequence (all low-level and high-level FAPs, 25 Hz) encoded by the
reference encoder, in files named at random (``content-<random>.fba``;
:mod:`fbaconf.generators.speed_content`), whose reference decoding of any length comes from two
decoded blocks (a 100,000-frame run costs no reference decode).

Operations. ``decode``: the adapter's ``decode`` command with the FAP output (outputs a
command names unconditionally are supplied too and their cost is included; a named
``{images_dir}`` gets a one-frame 8x8 scenario so rendering stays out of the per-frame
cost as far as the decoder honours ``{scenario}``). ``render``: the same command with
``{images_dir}`` and a scenario that renders every frame at ``render_size`` (64x64,
no supersampling); skipped (``None``, see :func:`skip_reason`) for adapters without the
``images`` output. A scene is written (the bundled default head; BT, or BIFS for a decoder
that declares only the ``bifs`` input) only when the command requires ``{scene}``.

The command measured is the one certified: ``decode``. A manifest may declare its
``[commands] serve`` (the persistent protocol, docs/fuzzing.md) equivalent
(``serve_equivalent = true``): a decoder that reads binary streams and writes FAPs is then
measured through it (``persistent=False`` to spawn instead) — one process decodes every run, so
each sample is one answer's round trip and the fitted start-up is the protocol's per-input
cost — after the harness has checked the claim on a sample: the first :data:`EQUIVALENCE_RUNS`
lengths are decoded by ``decode`` too, and the two outputs must be the same frames. A fast
``serve`` beside a slow ``decode`` is measured as ``decode``; one that answers differently
fails. The result's message says which way it was measured.

Output check, on content (issue 29). Every run's FAP output must hold the ``n`` frames it was
given, and a sample of them (the first, the last and six drawn at random per run) must be the
reference decoding of the content (:func:`output_problem`); a render must write an
image per frame, a vertices output must be non-empty — a decoder cannot earn a rate by stopping
early on long streams or by writing ``n`` lines of anything. A fitted per-frame cost that is not
positive is an error, never an infinite rate.

A run that fails (non-zero exit, crash, timeout, missing or short output) raises
:class:`SpeedRunError`; :func:`measure_claim` turns it into a failed :class:`SpeedResult`.
"""
from __future__ import annotations

import math
import os
import secrets
import statistics
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

from fbaconf.bitstreams.faptext import read_fap_text
from fbaconf.bitstreams.frames import FapFrames
from fbaconf.errors import FbaconfInputError
from fbaconf.generators.speed_content import BLOCK_FRAMES, Content, content_stream  # noqa: F401 (re-exported)
from fbaconf.isolation import endings, sandbox
from fbaconf.isolation.persistent import PersistentDecoder
from fbaconf.profiles.model import Claim, load_profiles
from fbaconf.safefs import UnsafeFileError, open_regular, read_regular, remove_tree

from .adapters import Adapter, CommandAdapter, Job, NotSupportedError, PythonAdapter, highest_claim
from .compare.faps import compare_faps
from .compare.ladder import outcome_for
from .compare.loaders import OutputError, check_output_file, load_output_faps
from .results import Outcome, SpeedResult
from .runner import hidden_from_decoders

OPERATIONS = ("decode", "render")
LIMIT_FOR = {"decode": "decode_rate", "render": "render_rate"}
EQUIVALENCE_RUNS = 2  # lengths decoded by both serve and decode before serve is timed
RANDOM_FRAMES = 6  # frames of a run's output compared besides the first and the last
START_FRAMES = 8  # first length of the adaptive search
SERIES = (0.1, 0.5, 1.0)  # the measured lengths, as fractions of the largest
DEFAULT_RENDER_SIZE = (64, 64)


class SpeedError(FbaconfInputError):
    """The speed measurement cannot be set up (unknown operation or claim, impossible command)."""
    rule = "speed-setup"


class SpeedRunError(Exception):
    """A decoder run failed during the speed measurement (exit code, crash, timeout, no output)."""

    def __init__(self, operation: str, frames: int, outcome: Outcome, message: str,
                 argv: list[str] | None = None, stderr_tail: str = "") -> None:
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


class _Runner:
    def __init__(self, adapter: Adapter, operation: str, content: Content, runs_dir: Path,
                 render_size: tuple[int, int], persistent: bool = True) -> None:
        self.adapter = adapter
        self.persistent = (persistent and operation == "decode" and isinstance(adapter, CommandAdapter)
                           and "serve" in adapter.commands and getattr(adapter, "serve_equivalent", False)
                           and "fba" in adapter.inputs and "faps" in adapter.outputs)
        self._server = None  # the persistent decoder, started at the first run
        self._equivalent: set[int] = set()  # lengths serve's output was checked against decode's on
        self.operation = operation
        self.content = content
        self.runs_dir = runs_dir
        self.render_size = render_size
        self.count = 0
        self.last_cpu_s: float | None = None  # CPU seconds of the last run (command adapters)
        self.extra: set[str] = set()
        self.notes: list[str] = []
        self._planned = False

    def _values(self, n: int, workdir: Path) -> dict[str, str]:
        a, c = self.adapter, self.content
        v: dict[str, str] = {}
        if "fba" in a.inputs:
            v["fba"] = v["input"] = str(c.fba(n))
        else:
            v["fap"] = v["input"] = str(c.fap(n))
        if "fap" in self.extra and "fap" not in v:
            v["fap"] = str(c.fap(n))
        if "fba" in self.extra and "fba" not in v:
            v["fba"] = str(c.fba(n))
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
            v["scenario"] = str(c.scenario(f"render-{w}x{h}", width=w, height=h, supersample=1, frames=None))
        else:
            v["scenario"] = str(c.scenario("decode-one-frame", width=8, height=8, supersample=1, frames=(0,)))
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
        assert isinstance(a, CommandAdapter)
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
                    raise SpeedError(f"{a.name}: the decode command needs {{{name}}}, which a speed "
                                     f"measurement cannot supply") from None
                self.extra.add(name)
                if name in ("vertices_out", "images_dir") or (name == "faps_out" and self.operation == "render"):
                    what = {"vertices_out": "vertices", "images_dir": "images (one 8x8 frame requested)",
                            "faps_out": "FAPs"}[name]
                    self.notes.append(f"the decode command always writes {what}; included in the time")
                elif name == "scene":
                    self.notes.append("the command requires a scene: the bundled default head is given")

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
            self._server = None

    def run(self, n: int) -> float:
        """Time one invocation on ``n`` frames (seconds); raises SpeedRunError on failure."""
        if self.persistent:
            return self._run_persistent(n)
        self.count += 1
        workdir = self.runs_dir / f"run-{self.count:04d}"
        if workdir.exists():
            remove_tree(workdir)
        workdir.mkdir(parents=True)
        try:
            return self._run(n, workdir)
        finally:
            try:
                remove_tree(workdir)
            except OSError:
                pass

    def _run(self, n: int, workdir: Path) -> float:
        a = self.adapter

        def job_for() -> Job:
            return Job(workdir=workdir, values=self._values(n, workdir), frames=n)

        if isinstance(a, CommandAdapter):
            argv, job = self._argv(job_for)
            view = a.sandbox_view(argv, workdir, hidden=hidden_from_decoders())
            view.read_only.append(self.content.root)  # the generated content the decoder reads
            res = sandbox.run(argv, workdir, a.limits, env=a.env or None, view=view)
            self._judge(res, n, argv)
            elapsed = res.elapsed_s
            self.last_cpu_s = res.cpu_s
            self.last_output = job.path("faps_out") if "faps_out" in job.values else None
        elif isinstance(a, PythonAdapter):
            argv = None
            job = job_for()
            t0 = time.perf_counter()
            try:
                a.run(job)
            except NotSupportedError as e:
                raise SpeedRunError(self.operation, n, Outcome.NOT_SUPPORTED, f"not supported: {e}") from None
            except MemoryError:
                raise SpeedRunError(self.operation, n, Outcome.CRASH, "decoder raised MemoryError") from None
            except Exception as e:  # the decoder's own failure
                raise SpeedRunError(self.operation, n, Outcome.FAIL,
                                    f"decoder raised {type(e).__name__}: {e}") from None
            elapsed = time.perf_counter() - t0
            if elapsed > a.limits.timeout_s:
                raise SpeedRunError(self.operation, n, Outcome.TIMEOUT,
                                    f"in-process decoder took {elapsed:.1f} s, over the {a.limits.timeout_s:g} s limit")
        else:  # pragma: no cover - no other adapter kinds
            raise SpeedError(f"unsupported adapter kind {type(a).__name__}")
        self._check_output(job, n, argv)
        return elapsed

    def _run_persistent(self, n: int) -> float:
        """One input to the persistent decoder: the time from sending it to its answer."""
        a = self.adapter
        root = self.runs_dir / "serve"
        workdir = root / "case"
        if self._server is None:
            (workdir / "in").mkdir(parents=True, exist_ok=True)
            job = Job(workdir=workdir, values={}, frames=0)
            argv = a.argv("serve", job)
            view = a.sandbox_view(argv, workdir, hidden=hidden_from_decoders())
            self._server = PersistentDecoder(argv, root, workdir, view, a.limits, env=a.env or None)
            self.notes.append("measured through the persistent protocol ([commands] serve, declared equivalent to "
                              "decode): one process for every run, no process start-up per sample")
        out = workdir / "out"
        if out.exists():
            remove_tree(out)
        out.mkdir(parents=True)
        path = out / f"faps.{'npz' if a.faps_format == 'npz' else 'fap'}"
        res = self._server.run(self.content.stream_bytes(n), str(path))
        self._judge(res, n, self._server.argv)
        self.last_cpu_s = None
        self._check_output(Job(workdir=workdir, values={"faps_out": str(path)}, frames=n), n, self._server.argv)
        if n not in self._equivalent and len(self._equivalent) < EQUIVALENCE_RUNS:
            self._check_equivalent(n, path)
        return res.elapsed_s

    def _check_equivalent(self, n: int, serve_out: Path) -> None:
        """The manifest says serve is decode: decode the same ``n`` frames with ``decode`` and
        compare the two outputs frame for frame (module doc)."""
        self._equivalent.add(n)
        self.count += 1
        workdir = self.runs_dir / f"equivalence-{self.count:04d}"
        workdir.mkdir(parents=True)
        try:
            self._run(n, workdir)
            try:
                by_decode = load_output_faps(self.last_output, max_bytes=self.adapter.limits.output_mb * 2**20)
                by_serve = load_output_faps(serve_out, max_bytes=self.adapter.limits.output_mb * 2**20)
            except OutputError as e:
                raise SpeedRunError(self.operation, n, Outcome.FAIL, f"serve_equivalent: {e}") from None
            r = compare_faps(by_decode, by_serve, text_output=serve_out.suffix == ".fap")
            if not r.outcome.ok:
                raise SpeedRunError(self.operation, n, Outcome.FAIL,
                                    f"the manifest declares [commands] serve equivalent to decode, but on {n} frames "
                                    f"serve's output differs from decode's: {r.message}", self._server.argv)
        finally:
            remove_tree(workdir)
        if len(self._equivalent) == EQUIVALENCE_RUNS:
            self.notes.append(f"serve's output checked against decode's on {EQUIVALENCE_RUNS} lengths "
                              f"({', '.join(map(str, sorted(self._equivalent)))} frames): the same frames")

    def _judge(self, res, n: int, argv) -> None:
        """A run that did not decode (exit code, crash, timeout...) fails the measurement."""
        a = self.adapter
        verdict = outcome_for(endings.classify(res, a.limits, a.reject_exit_codes))
        if verdict is not None:
            raise SpeedRunError(self.operation, n, verdict[0], verdict[1], argv, res.stderr_tail)

    def _check_output(self, job: Job, n: int, argv) -> None:
        key = "images_dir" if self.operation == "render" else next(
            k for k in ("faps_out", "vertices_out", "images_dir") if k in job.values)
        p = job.path(key)
        if key == "faps_out":
            why = output_problem(p, n, self.content, max_bytes=self.adapter.limits.output_mb * 2**20,
                                 player="fba" not in self.adapter.inputs)
            if why is not None:
                raise SpeedRunError(self.operation, n, Outcome.FAIL,
                                    f"the decoder {why.replace('its output', f'its output at {{{key}}}')}", argv)
            return
        ok = p is not None and (any(p.iterdir()) if p.is_dir() else (p.is_file() and p.stat().st_size > 0))
        if not ok:
            raise SpeedRunError(self.operation, n, Outcome.FAIL,
                                f"the decoder finished but wrote no output at {{{key}}} ({p})", argv)
        if self.operation == "render":  # every frame rendered: a file per frame (any face folders below)
            got = sum(1 for _dir, _subdirs, files in os.walk(p) for _f in files)
            if got < n:
                raise SpeedRunError(self.operation, n, Outcome.FAIL,
                                    f"the decoder was asked to render {n} frames but wrote {got} images at "
                                    f"{{{key}}}", argv)


# --------------------------------------------------------------------------- judging an output
# A .fap output is read frame by frame for the sampled frames only when it is laid out as the
# format's writers lay it out (a header, then a mask line of all ones and a data line per
# frame); any other layout is read whole.

def sample(n: int) -> np.ndarray:
    """The frames compared in one run of ``n``: the first, the last, and a fresh random draw."""
    rnd = secrets.SystemRandom()
    inner = rnd.sample(range(1, n - 1), min(RANDOM_FRAMES, max(0, n - 2))) if n > 2 else []
    return np.array(sorted({0, n - 1, *inner}), dtype=np.int64)


def output_problem(path: Path, n: int, content: Content, *, max_bytes: int, player: bool = False) -> str | None:
    """Why the FAP output at ``path`` is not the reference decoding of the ``n``-frame content
    (module doc, "Output check") — a clause to follow "the decoder" — or None. Raises nothing for the
    decoder's output."""
    try:
        check_output_file(path, max_bytes)
        ks = sample(n)
        got, count, text = _sampled(path, n, ks, max_bytes)
    except OutputError as e:
        return (f"finished but wrote no output ({path})" if e.rule == "output-missing" else
                f"finished but its output is unusable: {e}")
    if count != n:
        return f"was given {n} frames but its output holds {count}"
    r = compare_faps(content.expected(n, ks), got, text_output=text, player=player)
    if r.outcome.ok:
        return None
    d = r.first_difference or {}
    k = int(ks[d["frame"]]) if isinstance(d.get("frame"), (int, np.integer)) and d["frame"] < len(ks) else None
    where = f"frame {k}" if k is not None else "a sampled frame"
    return (f"finished but its output is not the decoding of the content it was given ({where} of {n}, "
            f"{d.get('what', 'value')}"
            f"{' of FAP ' + str(d['fap']) if d.get('fap') is not None else ''}: expected {d.get('expected')}, "
            f"got {d.get('got')})")


def _sampled(path: Path, n: int, ks: np.ndarray, max_bytes: int) -> tuple[FapFrames, int, bool]:
    """(frames ``ks`` of the output, its frame count, whether it is .fap text)."""
    try:
        with open_regular(path, max_bytes) as f:
            zipped = f.read(4) == b"PK\x03\x04"
        if zipped or path.suffix.lower() == ".npz":
            frames = load_output_faps(path, max_bytes=max_bytes)
            return (frames.select(ks) if len(frames) == n else frames), len(frames), False
        data = read_regular(path, max_bytes)
    except UnsafeFileError as e:
        raise OutputError(f"unusable output: {e}", rule="output-unsafe", file=str(path)) from None
    lines = [ln for ln in data.split(b"\n") if ln.strip() and not ln.lstrip().startswith(b"#")]
    try:
        head = lines[0].split()
        declared = int(head[-1])
    except (IndexError, ValueError):
        raise OutputError("no .fap header with a frame count", rule="output-fap-count", file=str(path)) from None
    ones = b" ".join([b"1"] * 68)
    if declared == n and len(lines) == 1 + 2 * n and all(lines[1 + 2 * k].strip() == ones for k in ks):
        mini = b" ".join(head[:-1] + [str(len(ks)).encode()]) + b"\n" + b"".join(
            lines[1 + 2 * k] + b"\n" + lines[2 + 2 * k] + b"\n" for k in ks)
        try:
            frames, _header, _w = read_fap_text(mini.decode("utf-8"), file=str(path))
        except (FbaconfInputError, UnicodeDecodeError) as e:
            raise OutputError(f"unreadable FAP output: {e}", rule="output-fap-text", file=str(path)) from None
        return frames, n, True
    if declared != n or len(lines) - 1 < n:  # each frame takes at least one line: short, whatever it holds
        return FapFrames.empty(0), min(declared, len(lines) - 1), True
    frames = load_output_faps(path, max_bytes=max_bytes)  # another layout: read whole
    return (frames.select(ks) if len(frames) == n else frames), len(frames), True


# --------------------------------------------------------------------------- fitting

def fit_line(frames, seconds) -> tuple[float, float, float]:
    """Least-squares ``seconds = startup + frames * per_frame``: (per_frame, startup, r2)."""
    x = np.asarray(frames, dtype=np.float64)
    y = np.asarray(seconds, dtype=np.float64)
    if len(x) < 2 or np.ptp(x) == 0:
        raise ValueError("a fit needs at least two different lengths")
    slope, icpt = np.polyfit(x, y, 1)
    return float(slope), float(icpt), _r2(x, y, slope, icpt)


def _r2(x, y, slope, icpt) -> float:
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    ss_res = float(np.sum((y - (icpt + slope * x)) ** 2))
    return 1.0 - ss_res / ss_tot if ss_tot > 0 else 0.0


def _choose_lengths(run: Callable[[int], float], *, target_s: float, max_frames: int, max_run_s: float) -> list[int]:
    """Grow the length until the frame-dependent time reaches ``target_s`` and the start-up
    time (module doc)."""
    n0 = max(1, min(START_FRAMES, max_frames - 1))
    run(n0)  # warm-up (page cache, .pyc, lazy imports): discarded
    t0 = run(n0)
    target_s = max(target_s, t0)  # the frame-dependent part must dominate start-up noise
    slope = t0 / n0  # upper bound until measured (all of t0 taken as per-frame cost)
    n = n0
    while n < max_frames:
        if n == n0:
            nxt = 4 * n0
        elif slope > 0:
            nxt = min(max(n0 + 1.2 * target_s / slope, 2 * n), 8 * n)
        else:
            nxt = 8 * n
        if slope > 0:  # keep the next run under max_run_s
            nxt = min(nxt, max(n0 + (max_run_s - t0) / slope, n + 1))
        n = int(min(max(nxt, n + 1), max_frames))
        t = run(n)
        var = t - t0
        if var >= target_s or t >= max_run_s:
            break
        slope = var / (n - n0)
    return _series(n)


def _series(n: int) -> list[int]:
    return sorted({max(1, int(round(n * f))) for f in SERIES})


# --------------------------------------------------------------------------- public API

def required_rate(claim: str, operation: str) -> tuple[float, str, str]:
    """(minimum rate in frames/s, provenance, limit description) for ``claim`` and ``operation``;
    the rate is 0 when the limit does not apply to the claimed profile."""
    ps = load_profiles()
    try:
        c = Claim.parse(claim, ps)
    except ValueError as e:
        raise SpeedError(f"claim: {e}", rule="speed-claim") from None
    lim = ps.limits.get(LIMIT_FOR[operation])
    if lim is None or lim not in ps.limits_for(c):
        return 0.0, "none", "no minimum for this claim"
    return float(lim.value(c.level)), lim.provenance, lim.description


def measure(adapter: Adapter, claim: str, operation: str, *, lengths: list[int] | None = None,  # noqa: PLR0913
            repeats: int = 3, work_dir: Path | None = None, target_s: float = 0.5,
            max_frames: int = 100_000, max_run_s: float | None = None,
            render_size: tuple[int, int] = DEFAULT_RENDER_SIZE, persistent: bool = True) -> SpeedResult | None:
    """Measure ``operation`` (``decode`` | ``render``) of ``adapter`` against ``claim``'s minimum.

    Returns None when the adapter cannot do the operation (:func:`skip_reason` says why).
    Raises :class:`SpeedError` for setup problems and :class:`SpeedRunError` when a decoder
    run fails. ``lengths`` (frames) fixes the series instead of the adaptive search;
    ``work_dir`` keeps the generated content there (default: a temporary folder)."""
    if operation not in OPERATIONS:
        raise SpeedError(f"unknown operation {operation!r} (decode, render)")
    if skip_reason(adapter, operation) is not None:
        return None
    if repeats < 1:
        raise SpeedError("repeats must be >= 1")
    if lengths is not None:
        lengths = sorted({int(n) for n in lengths})
        if len(lengths) < 2 or lengths[0] < 1:
            raise SpeedError(f"lengths must hold at least two different frame counts >= 1, got {lengths}")
    required, provenance, _desc = required_rate(claim, operation)
    if max_run_s is None:
        max_run_s = min(20.0, 0.4 * adapter.limits.timeout_s)
    tmp = runner = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="fbaconf-speed-")
        root = Path(tmp.name)
    else:
        root = Path(work_dir)
    try:
        runner = _Runner(adapter, operation, Content(root / "content"), root / f"runs-{operation}",
                         tuple(render_size), persistent=persistent)
        t_start = time.perf_counter()
        if lengths is None:
            lengths = _choose_lengths(runner.run, target_s=target_s, max_frames=max_frames, max_run_s=max_run_s)
        else:
            runner.run(lengths[0])  # warm-up, discarded
        samples: list[dict] = []
        fits: list[tuple[float, float, float]] = []
        for r in range(repeats):
            order = lengths if r % 2 == 0 else lengths[::-1]
            xs, ys = [], []
            for n in order:
                t = runner.run(n)
                sample = {"frames": n, "seconds": t, "repeat": r}
                if runner.last_cpu_s is not None:
                    sample["cpu_s"] = runner.last_cpu_s
                samples.append(sample)
                xs.append(n)
                ys.append(t)
            fits.append(fit_line(xs, ys))
        per_frame = statistics.median(f[0] for f in fits)
        startup = statistics.median(f[1] for f in fits)
        r2 = _r2([s["frames"] for s in samples], [s["seconds"] for s in samples], per_frame, startup)
        wall = time.perf_counter() - t_start
    finally:
        if runner is not None:
            runner.close()
        if tmp is not None:
            tmp.cleanup()
    notes = list(runner.notes)
    if not per_frame > 0:  # never an infinite rate: the time did not grow with the frames decoded
        return SpeedResult(operation=operation, claim=claim, per_frame_s=per_frame, startup_s=startup, rate_fps=0.0,
                           required_fps=required, passed=False, provenance=provenance, samples=samples, fit_r2=r2,
                           message=f"no decode rate: the fitted per-frame cost is {per_frame * 1000:.4f} ms, not "
                                   f"positive — the run time did not grow with the {lengths} frames decoded (a "
                                   f"decoder's time must; the measurement cannot resolve it, or the decoder does "
                                   f"not decode what it is given); lengths {lengths} x {repeats}"
                                   + "".join(f"; {n}" for n in notes))
    rate = 1.0 / per_frame
    passed = rate >= required
    span = per_frame * (lengths[-1] - lengths[0])
    if span < 0.1 * target_s and lengths[-1] < max_frames:
        notes.append(f"frame-dependent time only {span * 1000:.0f} ms: low precision")
    if r2 < 0.9:
        note = f"poor linear fit (r2 {r2:.3f}): wall-clock timings are noisy (a loaded machine?)"
        if all("cpu_s" in s for s in samples):
            try:
                cpf, _cst, cr2 = fit_line([s["frames"] for s in samples], [s["cpu_s"] for s in samples])
                note += f"; CPU time gives {cpf * 1000:.3f} ms/frame (r2 {cr2:.3f})"
            except ValueError:
                pass
        notes.append(note)
    verdict = "meets" if passed else "is below"
    what = {"decode": "decode rate (all faces together)", "render": "render rate per face"}[operation]
    msg = (f"{what} {_fmt_rate(rate)} fps {verdict} the {claim} minimum {required:g} fps ({provenance}); "
           f"{per_frame * 1000:.3f} ms/frame, fitted start-up {startup:+.3f} s, lengths {lengths} x {repeats}, "
           f"{wall:.1f} s")
    if notes:
        msg += "; " + "; ".join(notes)
    return SpeedResult(operation=operation, claim=claim, per_frame_s=per_frame, startup_s=startup,
                       rate_fps=rate, required_fps=required, passed=passed, provenance=provenance,
                       samples=samples, fit_r2=r2, message=msg)


def _fmt_rate(rate: float) -> str:
    return "inf" if math.isinf(rate) else f"{rate:.1f}"


def failed_result(err: SpeedRunError, claim: str) -> SpeedResult:
    """A failed SpeedResult for a decoder run that did not complete."""
    try:
        required, provenance, _ = required_rate(claim, err.operation)
    except SpeedError:
        required, provenance = math.nan, "none"
    return SpeedResult(operation=err.operation, claim=claim, per_frame_s=math.nan, startup_s=math.nan,
                       rate_fps=0.0, required_fps=required, passed=False, provenance=provenance,
                       message=f"decoder run failed ({err.outcome.value}) on {err.frames} frames: {err.message}")


def measure_claim(adapter: Adapter, claim: str | None = None, **kwargs) -> list[SpeedResult]:
    """Decode and (when the adapter outputs images) render speed for ``claim`` (default: the
    adapter's highest claim). A failing decoder run gives a failed result rather than raising;
    setup problems raise :class:`SpeedError`. ``kwargs`` go to :func:`measure`."""
    claim = claim or highest_claim(adapter)
    out: list[SpeedResult] = []
    for op in OPERATIONS:
        try:
            r = measure(adapter, claim, op, **kwargs)
        except SpeedRunError as e:
            r = failed_result(e, claim)
        if r is not None:
            out.append(r)
    return out
