"""``fbaconf bench``: a decoder's decode and render speed against the claimed level's minimums
(the measurement itself is :mod:`.speed`)."""

from __future__ import annotations

import argparse
import json
import math
import sys

from fbaconf.isolation.bounds import ceilings_from

from ..adapters import resolve
from ..preflight import preflight
from ..reports.jsonreport import jsonable
from ..results import SpeedResult
from ..usage import resolve_claim
from ..verdict import speed_verdict
from .measure import OPERATIONS, SpeedError, SpeedRunError, failed_result, measure, skip_reason


def _parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
        if w < 1 or h < 1:
            raise ValueError
        return w, h
    except ValueError:
        raise ValueError(f"--render-size must be WxH, e.g. 64x64, not {text!r}") from None


def _usage(msg: str) -> int:
    print(f"fbaconf bench: error: {msg}", file=sys.stderr)
    return 2


def run(args: argparse.Namespace) -> int:
    """``fbaconf bench``: exit 0 every measured rate meets its minimum; 1 a decoder run failed (exit
    code, crash, timeout, missing or wrong output); 2 usage or setup error; 3 a speed requirement is
    missed; 4 a rate missed its minimum on a machine busy with other work (inconclusive)."""
    adapter = resolve(args.decoder, ceilings=ceilings_from(args))  # ManifestError -> exit 2 (cli.main)
    claim = resolve_claim(args.claim, adapter)
    preflight(adapter)
    if args.work_dir:
        args.work_dir = args.work_dir.resolve()
    if args.repeats < 1:
        return _usage("--repeats must be >= 1")
    lengths = None
    if args.lengths:
        try:
            lengths = [int(x) for x in args.lengths.split(",") if x.strip()]
        except ValueError:
            return _usage(f"--lengths must be comma-separated frame counts, not {args.lengths!r}")
    try:
        size = _parse_size(args.render_size)
    except ValueError as e:
        return _usage(str(e))
    ops = args.operation or list(OPERATIONS)
    results: list[SpeedResult] = []
    skipped: list[tuple[str, str]] = []
    failed = False
    for op in ops:
        reason = skip_reason(adapter, op)
        if reason:
            skipped.append((op, reason))
            continue
        if not args.json:
            print(f"measuring {op} speed of {adapter.name} for {claim}...", file=sys.stderr, flush=True)
        try:
            r = measure(
                adapter,
                claim,
                op,
                lengths=lengths,
                repeats=args.repeats,
                work_dir=(args.work_dir / op) if args.work_dir else None,
                target_s=args.target_seconds,
                render_size=size,
            )
        except SpeedRunError as e:
            r = failed_result(e, claim)
            failed = True
        except SpeedError as e:
            return _usage(str(e))
        if r is not None:  # None: skipped, as skip_reason said above
            results.append(r)
    sv = speed_verdict([r.to_json() for r in results])
    code = 1 if failed else (sv[1] if sv else 0)
    if args.json:
        doc = {
            "format": "fbaconf.bench/1",
            "decoder": adapter.describe(),
            "claim": claim,
            "exit_code": code,
            "speed": [r.to_json() for r in results],
            "skipped": [{"operation": op, "reason": why} for op, why in skipped],
        }
        print(json.dumps(jsonable(doc), indent=2))
        return code
    print(render_table(results))
    for op, why in skipped:
        print(f"{op}: skipped: {why}")
    for r in results:
        if r.message:
            print(f"{r.operation}: {r.message}")
    verdict = {
        0: "PASS: every measured rate meets the level minimum",
        1: "ERROR: a decoder run failed during the measurement",
        3: "FAIL: below the level's minimum rate (speed requirement only)",
        4: "INCONCLUSIVE: below the level's minimum rate on a machine busy with other work (measure again "
        "on an idle machine)",
    }[code]
    print(f"result: {verdict}")
    return code


def render_table(results: list[SpeedResult]) -> str:
    """Plain-text table: operation, per-frame ms, start-up, measured/required fps, ratio, verdict,
    the decoder's CPU time and wait and the share of the CPUs others used over the timed runs,
    provenance (provisional limits marked with ``*``)."""
    header = [
        "operation",
        "claim",
        "per-frame ms",
        "startup s",
        "measured fps",
        "required fps",
        "ratio",
        "verdict",
        "cpu s",
        "wait s",
        "others %",
        "provenance",
    ]
    rows = []
    for r in results:
        ratio = (r.rate_fps / r.required_fps) if r.required_fps and r.required_fps > 0 else math.inf
        prov = r.provenance + (" *" if r.provenance == "provisional" else "")
        rows.append(
            [
                r.operation,
                r.claim,
                _num(r.per_frame_s * 1000, 3),
                _num(r.startup_s, 3),
                _num(r.rate_fps, 1),
                _num(r.required_fps, 1),
                _num(ratio, 2),
                (r.verdict or ("pass" if r.passed else "fail")).upper(),
                _num(r.cpu_s, 2),
                _num(r.stall_s, 2),
                _num(None if r.others_share is None else 100 * r.others_share, 0),
                prov,
            ]
        )
    widths = [max(len(h), *(len(row[i]) for row in rows)) if rows else len(h) for i, h in enumerate(header)]
    right = {2, 3, 4, 5, 6, 8, 9, 10}

    def line(cells: list[str]) -> str:
        return "  ".join(c.rjust(w) if i in right else c.ljust(w) for i, (c, w) in enumerate(zip(cells, widths)))

    out = [line(header), line(["-" * w for w in widths])] + [line(r) for r in rows]
    if any(r.provenance == "provisional" for r in results):
        out.append("* provisional level limit (profiles/data/profiles.toml): not from the ISO text")
    return "\n".join(s.rstrip() for s in out)


def _num(v: float | None, digits: int) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if math.isinf(v):
        return "inf"
    return f"{v:.{digits}f}"
