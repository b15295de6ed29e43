"""Decoder speed: per-frame decode and render cost, free of process start-up, against the
claimed level's minimum rates (``decode_rate``, ``render_rate`` in ``profiles.toml``) — earned
by the certified command on content it cannot know in advance, and judged only when the
machine gave the decoder its CPU (docs/harness.md, "Speed").

Method. The decoder runs content at several lengths ``n`` (frames); every run is timed (wall
clock of the whole invocation, or of ``adapter.run(job)`` for in-process adapters) and a
straight line ``time = startup + n * per_frame`` is fitted by least squares. The series of
lengths is repeated ``repeats`` times (alternately ascending and descending, so slow drift does
not bias the slope); the per-frame cost and start-up are the medians over the repeats, and
``fit_r2`` is the coefficient of determination of that median line over every sample. The rate
is ``1 / per_frame``.

Lengths. Unless given, they adapt to the decoder: after one discarded warm-up run, the
length grows (by the measured slope, at least x2 and at most x8 per step) until the
frame-dependent part of the largest run (its time minus the smallest run's) reaches
``target_s`` and the smallest run's time (mostly start-up) — so it dominates start-up
noise — or a run would pass ``max_run_s`` or the length ``max_frames``. The series is then ``n/10, n/2, n``.

Every run gets fresh content (:mod:`.content`) and its output is judged
on a sample (:mod:`.check`); each run's CPU time, wait and the others' CPU are read around
it (:mod:`.load`), which gives the verdict: pass, fail or inconclusive.

Operations. ``decode``: the adapter's ``decode`` command with the FAP output (outputs a
command names unconditionally are supplied too and their cost is included; a named
``{images_dir}`` gets a 32x32 scenario of two frames, the first and one drawn per run).
``render``: the same command with ``{images_dir}`` and a scenario of every frame at
``render_size`` with 2 x 2 samples per pixel; skipped (``None``, see :func:`skip_reason`) for
adapters without the ``images`` output. A scene (the bundled default head; BT, or BIFS for a
decoder that declares only ``bifs``) is written only when the command requires ``{scene}``.

The command measured is ``decode``. With ``[commands] serve`` declared equivalent
(``serve_equivalent = true``) a decoder of binary streams to FAPs is timed through the
persistent protocol (``persistent=False`` to spawn), then the declaration is proven on the
speed content (:meth:`_Runner.equivalence`): the same frames, and ``decode`` no slower than
:data:`EQUIVALENCE_FACTOR` times ``serve`` — else ``decode`` is measured instead.

A run that fails (non-zero exit, crash, timeout, missing, short or wrong output) raises
:class:`SpeedRunError`; :func:`measure_claim` turns it into a failed :class:`SpeedResult`.
:func:`fbaconf.harness.verdict.speed_verdict` turns a run's speed results into the claim's speed verdict.
"""

from __future__ import annotations

import math
import statistics
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fbaconf.profiles.model import Claim, load_profiles

from .. import sysinfo
from ..adapters import Adapter, highest_claim
from ..results import SpeedResult
from . import load as speed_load
from .content import Content

# the names bench and the tests reach through this module, re-exported (`X as X`)
from .runs import (
    DEFAULT_RENDER_SIZE,
    LIMIT_FOR,
    OPERATIONS as OPERATIONS,
    SERIES,
    START_FRAMES,
    SpeedError as SpeedError,
    SpeedRunError as SpeedRunError,
    _Runner as _Runner,
    skip_reason as skip_reason,
)


def fit_line(frames: Sequence[float], seconds: Sequence[float]) -> tuple[float, float, float]:
    """Least-squares ``seconds = startup + frames * per_frame``: (per_frame, startup, r2)."""
    x = np.asarray(frames, dtype=np.float64)
    y = np.asarray(seconds, dtype=np.float64)
    if len(x) < 2 or np.ptp(x) == 0:
        raise ValueError("a fit needs at least two different lengths")
    slope, icpt = np.polyfit(x, y, 1)
    return float(slope), float(icpt), _r2(x, y, slope, icpt)


def _r2(x: Sequence[float] | np.ndarray, y: Sequence[float] | np.ndarray, slope: float, icpt: float) -> float:
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
    nxt: float
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


def measure(  # noqa: PLR0913 - keyword options of a measurement
    adapter: Adapter,
    claim: str,
    operation: str,
    *,
    lengths: list[int] | None = None,
    repeats: int = 3,
    work_dir: Path | None = None,
    target_s: float = 0.5,
    max_frames: int = 100_000,
    max_run_s: float | None = None,
    render_size: tuple[int, int] = DEFAULT_RENDER_SIZE,
    persistent: bool = True,
) -> SpeedResult | None:
    """Measure ``operation`` (``decode`` | ``render``) of ``adapter`` against ``claim``'s minimum.

    Returns None when the adapter cannot do the operation (:func:`skip_reason` says why).
    Raises :class:`SpeedError` for setup problems and :class:`SpeedRunError` when a decoder
    run fails. ``lengths`` (frames) fixes the series instead of the adaptive search;
    ``work_dir`` holds the generated content while it is used (default: a temporary folder)."""
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
    tmp = None
    if work_dir is None:
        tmp = tempfile.TemporaryDirectory(prefix="fbaconf-speed-")
        root = Path(tmp.name)
    else:
        root = Path(work_dir)
    content = Content(root / "content")
    size = (int(render_size[0]), int(render_size[1]))

    def series(runner: _Runner) -> dict[str, Any]:
        return _measure_series(
            runner, lengths=lengths, repeats=repeats, target_s=target_s, max_frames=max_frames, max_run_s=max_run_s
        )

    try:
        runner = _Runner(adapter, operation, content, root / f"runs-{operation}", size, persistent=persistent)
        fit = series(runner)
        if runner.persistent:
            try:
                same, note = (
                    runner.equivalence(fit["lengths"], fit["per_frame"])
                    if fit["per_frame"] > 0
                    else (False, "serve's time did not grow with the frames it decoded: decode was timed")
                )
            finally:
                runner.close()
            if same:
                runner.notes.append(note)
            else:
                runner = _Runner(adapter, operation, content, root / f"runs-{operation}-decode", size, persistent=False)
                runner.notes.append(note)
                fit = series(runner)
        runner.close()
    finally:
        if tmp is not None:
            tmp.cleanup()
    fit.update(required=required, provenance=provenance, target_s=target_s, max_frames=max_frames, repeats=repeats)
    return _result(operation, claim, fit, runner.notes)


def _measure_series(
    runner: _Runner, *, lengths: list[int] | None, repeats: int, target_s: float, max_frames: int, max_run_s: float
) -> dict[str, Any]:
    """Run the measurement proper: the lengths (searched unless given) ``repeats`` times,
    each run's time and accounting; the fits."""
    try:
        t_start = time.perf_counter()
        if lengths is None:
            lengths = _choose_lengths(
                lambda n: runner.run(n).seconds, target_s=target_s, max_frames=max_frames, max_run_s=max_run_s
            )
        else:
            runner.run(lengths[0])  # warm-up, discarded
        samples: list[dict[str, Any]] = []
        windows: list[speed_load.Window] = []
        for r in range(repeats):
            order = lengths if r % 2 == 0 else lengths[::-1]
            for n in order:
                w = runner.run(n)
                windows.append(w)
                samples.append(
                    {
                        "frames": n,
                        "seconds": w.seconds,
                        "repeat": r,
                        **{
                            k: v
                            for k, v in (("cpu_s", w.cpu_s), ("stall_s", w.stall_s), ("others_s", w.others_s))
                            if v is not None
                        },
                    }
                )
        wall = time.perf_counter() - t_start
    except BaseException:
        runner.close()
        raise
    cpus = sysinfo.usable_cpus()
    load = speed_load.account(windows, cpus)
    for s, w in zip(samples, windows):
        s["uncontended_s"] = w.uncontended_s(cpus)
    per_frame, startup = _median_fit(samples, "seconds", repeats)
    r2 = _r2([s["frames"] for s in samples], [s["seconds"] for s in samples], per_frame, startup)
    unc = _median_fit(samples, "uncontended_s", repeats)[0]
    return {
        "lengths": lengths,
        "samples": samples,
        "per_frame": per_frame,
        "startup": startup,
        "r2": r2,
        "wall": wall,
        "load": load,
        "uncontended_per_frame": unc,
    }


def _median_fit(samples: list[dict[str, Any]], key: str, repeats: int) -> tuple[float, float]:
    fits = [
        fit_line([s["frames"] for s in samples if s["repeat"] == r], [s[key] for s in samples if s["repeat"] == r])
        for r in range(repeats)
    ]
    return statistics.median(f[0] for f in fits), statistics.median(f[1] for f in fits)


def _result(operation: str, claim: str, fit: dict[str, Any], notes: list[str]) -> SpeedResult:
    required, provenance, target_s, max_frames, repeats = (
        fit["required"],
        fit["provenance"],
        fit["target_s"],
        fit["max_frames"],
        fit["repeats"],
    )
    per_frame, startup, r2, lengths, samples = (
        fit["per_frame"],
        fit["startup"],
        fit["r2"],
        fit["lengths"],
        fit["samples"],
    )
    load: speed_load.Load = fit["load"]
    notes = list(notes)
    numbers: dict[str, Any] = dict(
        cpu_s=load.cpu_s,
        wall_s=load.wall_s,
        stall_s=load.stall_s,
        stall_source=load.stall_source,
        others_share=load.others_share,
        others_share_between=load.others_share_between,
        load=load.load,
        cpus=load.cpus,
    )
    if not per_frame > 0:  # never an infinite rate: the time did not grow with the frames decoded
        reason = (
            f"no {operation} rate: the fitted per-frame cost is {per_frame * 1000:.4f} ms, not positive — the "
            f"run time did not grow with the {lengths} frames decoded (a decoder's time must; the measurement "
            f"cannot resolve it, or the decoder does not decode what it is given)"
        )
        # on a busy machine the other processes' time can swamp the slope (an honest renderer measured -2.4 ms a
        # frame at load 6 on 2 cores): that is the lab's noise, not the decoder's speed
        busy = load.busy
        if busy:
            reason += f"; the machine was busy ({load.describe()}): measure again on a machine that is not busy"
        return SpeedResult(
            operation=operation,
            claim=claim,
            per_frame_s=per_frame,
            startup_s=startup,
            rate_fps=0.0,
            required_fps=required,
            passed=False,
            provenance=provenance,
            samples=samples,
            fit_r2=r2,
            message=f"{reason}; lengths {lengths} x {repeats}" + "".join(f"; {n}" for n in notes),
            verdict="inconclusive" if busy else "fail",
            reason=reason,
            **numbers,
        )
    rate = 1.0 / per_frame
    unc = fit["uncontended_per_frame"]
    unc_rate = (1.0 / unc) if unc > 0 else None
    verdict, reason = speed_load.verdict(rate, required, unc_rate, load)
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
    word = {"pass": "meets", "fail": "is below", "inconclusive": "is below (inconclusive: the machine was busy)"}
    what = {"decode": "decode rate (all faces together)", "render": "render rate per face"}[operation]
    msg = (
        f"{what} {_fmt_rate(rate)} fps {word[verdict]} the {claim} minimum {required:g} fps ({provenance}); "
        f"{per_frame * 1000:.3f} ms/frame, fitted start-up {startup:+.3f} s, lengths {lengths} x {repeats}, "
        f"{fit['wall']:.1f} s; {reason}"
    )
    if notes:
        msg += "; " + "; ".join(notes)
    return SpeedResult(
        operation=operation,
        claim=claim,
        per_frame_s=per_frame,
        startup_s=startup,
        rate_fps=rate,
        required_fps=required,
        passed=verdict == "pass",
        provenance=provenance,
        samples=samples,
        fit_r2=r2,
        message=msg,
        verdict=verdict,
        reason=reason,
        uncontended_fps=unc_rate,
        **numbers,
    )


def _fmt_rate(rate: float) -> str:
    return "inf" if math.isinf(rate) else f"{rate:.1f}"


def failed_result(err: SpeedRunError, claim: str) -> SpeedResult:
    """A failed SpeedResult for a decoder run that did not complete."""
    try:
        required, provenance, _ = required_rate(claim, err.operation)
    except SpeedError:
        required, provenance = math.nan, "none"
    reason = f"decoder run failed ({err.outcome.value}) on {err.frames} frames: {err.message}"
    return SpeedResult(
        operation=err.operation,
        claim=claim,
        per_frame_s=math.nan,
        startup_s=math.nan,
        rate_fps=0.0,
        required_fps=required,
        passed=False,
        provenance=provenance,
        message=reason,
        verdict="fail",
        reason=reason,
    )


def measure_claim(adapter: Adapter, claim: str | None = None, **kwargs: Any) -> list[SpeedResult]:
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
