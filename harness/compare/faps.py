"""The FAP stage: exact, normative comparison of decoded FAP frames (values, statuses, frame numbers,
times, the .fap header rate)."""

from __future__ import annotations

from typing import Any

import numpy as np

from fbaconf.bitstreams.frames import FREE, HIGH_LEVEL_FIELDS, SET, STATUS_NAMES, VISEME_FIELDS, FapFrames
from fbaconf.bitstreams.tables import fap_table
from fbaconf.harness.results import Outcome, StageResult

from .tolerances import load_tolerances


def _fap_name(number: int) -> str:
    return fap_table()[number - 1].name


def compare_faps(expected: FapFrames, got: FapFrames, *, text_output: bool, player: bool = False) -> StageResult:
    """Exact normative comparison of a decoder's FapFrames with the golden ones.

    Per frame (of the frames both have): frame number; every FAP whose expected status is
    not FREE must have the expected value (FAP 1/2: the viseme / expression fields); FREE
    FAPs are not compared. ``text_output=False`` (.npz): the status of every FAP must match
    too. ``text_output=True`` (.fap text carries no SET/RETAINED distinction): a non-FREE
    expected FAP that is FREE in ``got`` is a difference ("expected a value, got none").
    A different frame count fails (reported as the first difference unless an earlier
    frame already differs). With ``.npz`` output plane times must match within
    ``[faps] time_tol_ms`` of the tolerance file. With ``.fap`` output the header's frame
    rate must equal the coded rate within ``[faps] header_rate_tol_hz`` and
    ``header_rate_rel_tol`` (a dropped or added 1000/1001 factor fails at every rate), and
    frame numbers — which carry the skips — may count from 0 or from 1 (one offset for the
    whole file, reported in the metrics); the plane times a ``.fap`` cannot carry (a time
    code, a rate change: a time that is not frame number / rate) are counted in
    ``metrics["times_unverified"]`` (the certificate says timing was not verified).
    ``player=True`` (the decoder was given .fap text: a player): its output is its state, so
    every FAP that holds a value must be written in every frame (mask 1); one left to the
    reader's hold counts as missing — the input text was sparse, and copying it is no playing.
    A player's ``.npz`` state is compared the same way (SET exactly where the golden holds a
    value, FREE where it has none), and its plane times as for any ``.npz`` output.

    ``first_difference``: frame (index), frame_number, fap, name, what ("value", "status",
    "missing", a high-level field name, "frame number", "frame count"), expected, got.
    ``series``: per compared frame ``faps_differing`` and ``max_abs_diff`` (over the
    compared FAPs/fields). ``metrics``: frames_compared, frames_differing, faps_differing,
    max_abs_diff, expected_frames, got_frames."""
    ne, ng = len(expected), len(got)
    n = min(ne, ng)
    e, g = expected.select(slice(0, n)), got.select(slice(0, n))
    norm = e.status != FREE
    nv = len(VISEME_FIELDS)
    vdiff = (e.values != g.values) & norm
    vdiff[:, :2] = False  # FAP 1/2 live in the high-level fields
    hdiff = e.high != g.high
    hnorm = np.concatenate(
        [np.repeat(norm[:, [0]], nv, axis=1), np.repeat(norm[:, [1]], len(HIGH_LEVEL_FIELDS) - nv, axis=1)], axis=1
    )
    hdiff &= hnorm
    vdiff[:, 0] |= hdiff[:, :nv].any(axis=1)
    vdiff[:, 1] |= hdiff[:, nv:].any(axis=1)
    if text_output:
        missing = norm & ((g.status != SET) if player else (g.status == FREE))
        sdiff = np.zeros_like(norm)
    elif player:  # a player's .npz state: SET where the golden holds a value, FREE where it has none
        missing = norm & (g.status != SET)
        sdiff = ~norm & (g.status != FREE)
    else:
        missing = np.zeros_like(norm)
        sdiff = e.status != g.status
    offset = 0
    if text_output and n and np.array_equal(g.frame_number, e.frame_number + 1):
        offset = 1  # a player numbering frames from 1, as the .fap notes allow
    fndiff = e.frame_number + offset != g.frame_number
    rate_bad = False
    tol = load_tolerances().get("faps", {})
    time_tol = float(tol.get("time_tol_ms", 0.5))
    times_unverified = 0
    if text_output:
        er = float(expected.frame_rate)
        rate_tol = min(float(tol.get("header_rate_tol_hz", 0.005)), float(tol.get("header_rate_rel_tol", 2e-4)) * er)
        rate_bad = not abs(er - float(got.frame_rate)) <= rate_tol
        with np.errstate(invalid="ignore", divide="ignore"):
            implied = np.asarray(expected.frame_number, np.float64) * 1000.0 / er
            times_unverified = int((~(np.abs(implied - np.asarray(expected.time_ms, np.float64)) <= time_tol)).sum())
    per_fap = vdiff | sdiff | missing
    # plane times (frame rate, skips, time codes, 1000/1001) are normative too (decision D6);
    # .fap text carries only frame numbers and one rate, so times are compared for .npz output
    with np.errstate(invalid="ignore"):
        tdiff = ~(np.abs(np.asarray(e.time_ms, np.float64) - np.asarray(g.time_ms, np.float64)) <= time_tol)
    if text_output:
        tdiff[:] = False
    bad_frame = per_fap.any(axis=1) | fndiff | tdiff

    absd = np.where(norm, np.abs(e.values.astype(np.int64) - g.values.astype(np.int64)), 0)
    habs = np.where(hnorm, np.abs(e.high.astype(np.int64) - g.high.astype(np.int64)), 0)
    max_abs = np.maximum(absd.max(axis=1, initial=0), habs.max(axis=1, initial=0))
    series = {"faps_differing": [float(x) for x in per_fap.sum(axis=1)], "max_abs_diff": [float(x) for x in max_abs]}
    metrics = {
        "frames_compared": float(n),
        "frames_differing": float(bad_frame.sum()),
        "faps_differing": float(per_fap.sum()),
        "max_abs_diff": float(max_abs.max(initial=0)),
        "expected_frames": float(ne),
        "got_frames": float(ng),
        "frame_number_offset": float(offset),
    }
    # what kind of difference (conformance/provisional.py: which provisional decision could explain it)
    metrics.update(
        values_differing=float((vdiff | missing).sum()),
        status_differing=float(sdiff.sum()),
        frame_numbers_differing=float(fndiff.sum()),
        times_differing=float(tdiff.sum()),
        rate_differs=float(rate_bad),
    )
    if text_output:
        metrics["times_unverified"] = float(times_unverified)

    first: dict[str, Any] | None = None
    detail = ""
    if bad_frame.any():
        k = int(np.nonzero(bad_frame)[0][0])
        fn = int(e.frame_number[k])
        where = f"frame {k} (frame_number {fn})"
        if fndiff[k]:
            first = {
                "frame": k,
                "frame_number": fn,
                "what": "frame number",
                "expected": fn,
                "got": int(g.frame_number[k]),
            }
            detail = f"{where}: frame number: expected {fn}, got {int(g.frame_number[k])}"
        elif not per_fap[k].any():
            et, gt = float(e.time_ms[k]), float(g.time_ms[k])
            first = {"frame": k, "frame_number": fn, "what": "time_ms", "expected": et, "got": gt}
            detail = f"{where}: time: expected {et:.3f} ms, got {gt:.3f} ms (tolerance {time_tol:g} ms)"
        else:
            j = int(np.nonzero(per_fap[k])[0][0])
            num, name = j + 1, _fap_name(j + 1)
            first = {"frame": k, "frame_number": fn, "fap": num, "name": name}
            if missing[k, j]:
                exp = _fap_value(e, k, j)
                first.update(what="missing", expected=exp, got=None)
                detail = f"{where}: FAP {num} {name}: expected a value ({exp}), got none"
            elif vdiff[k, j] and j >= 2:
                first.update(what="value", expected=int(e.values[k, j]), got=int(g.values[k, j]))
                detail = f"{where}: FAP {num} {name}: expected {int(e.values[k, j])}, got {int(g.values[k, j])}"
            elif vdiff[k, j]:
                cols = range(0, nv) if j == 0 else range(nv, len(HIGH_LEVEL_FIELDS))
                c = next(c for c in cols if hdiff[k, c])
                field_name = HIGH_LEVEL_FIELDS[c]
                first.update(what=field_name, expected=int(e.high[k, c]), got=int(g.high[k, c]))
                detail = (
                    f"{where}: FAP {num} {name} {field_name}: expected {int(e.high[k, c])}, got {int(g.high[k, c])}"
                )
            else:
                es, gs = int(e.status[k, j]), int(g.status[k, j])
                first.update(what="status", expected=STATUS_NAMES.get(es, str(es)), got=STATUS_NAMES.get(gs, str(gs)))
                detail = f"{where}: FAP {num} {name} status: expected {first['expected']}, got {first['got']}"
    if rate_bad:
        er, gr = float(expected.frame_rate), float(got.frame_rate)
        first = {"what": "frame rate", "expected": er, "got": gr}
        return StageResult(
            "faps",
            Outcome.FAIL,
            f"header frame rate: expected {er:.6g} Hz (the coded rate), got {gr:.6g} Hz",
            first,
            metrics,
            series,
        )
    count_msg = ""
    if ne != ng:
        count_msg = f"frame count: expected {ne}, got {ng}"
        if first is None:
            first = {"frame": n, "what": "frame count", "expected": ne, "got": ng}
    if first is None:
        note = " (frames numbered from 1)" if offset else ""
        return StageResult("faps", Outcome.PASS, f"{n} frame(s) match{note}", None, metrics, series)
    parts = [p for p in (count_msg,) if p]
    if detail:
        parts.append(f"{int(bad_frame.sum())} of {n} frame(s) differ; first at {detail}")
    # every differing FAP, with how many frames and the first and last (a pattern such as one
    # FAP always copied from another shows here, not in the first difference alone)
    differing = np.nonzero(per_fap.any(axis=0))[0]
    if len(differing):
        rows = []
        for j in map(int, differing):
            ks = np.nonzero(per_fap[:, j])[0]
            rows.append(
                {
                    "fap": int(j + 1),
                    "name": _fap_name(int(j + 1)),
                    "frames": int(len(ks)),
                    "first": int(ks[0]),
                    "last": int(ks[-1]),
                }
            )
        first = dict(first, faps=rows)
        shown = ", ".join(
            f"{r['fap']} {r['name']} ({r['frames']} frame(s), {r['first']}..{r['last']})" for r in rows[:8]
        )
        parts.append(f"differing FAPs: {shown}" + (f", and {len(rows) - 8} more" if len(rows) > 8 else ""))
    return StageResult("faps", Outcome.FAIL, "; ".join(parts), first, metrics, series)


def _fap_value(f: FapFrames, k: int, j: int) -> int | dict[str, int]:
    if j >= 2:
        return int(f.values[k, j])
    nv = len(VISEME_FIELDS)
    cols = range(0, nv) if j == 0 else range(nv, len(HIGH_LEVEL_FIELDS))
    return {HIGH_LEVEL_FIELDS[c]: int(f.high[k, c]) for c in cols}
