"""``fbaconf check``: the stream checker on the command line.

    fbaconf check IN.fba [--scene S.bt] [--claim PROFILE@LEVEL] [--json] [--max-issues N]
                  [--only CODE ...] [--ignore CODE ...] [--smallest-claim] [--locations N]
    fbaconf check IN.fap [--json] [--max-issues N] [--only CODE ...] [--ignore CODE ...]

An ASCII ``.fap`` file (by its name, or text that starts like one) is checked against the text
rules of the .fap reader (``FAP-TEXT-*`` codes, each at line:column; profiles/textcheck.py).

Exit status: 0 no errors (warnings/info allowed), 1 errors, 2 unreadable input (file
missing, or not a face object stream at all) or a bad command line.
"""

from __future__ import annotations

import json
import os
import stat
import sys
from pathlib import Path

from fbaconf import rules as R

from . import diagnostics as D
from .checker import Report, analyse
from .model import Claim, load_profiles
from .textcheck import analyse_text, is_text_input

REPORT_FORMAT = "fbaconf.check-report/1"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "check",
        help="check a face object stream (syntax, semantics, profile and level)",
        description="Check a face object bitstream: syntax, semantics, decision dependence, and (with --claim) "
        "the tools and limits of a profile@level. Exit 0 clean, 1 errors, 2 unreadable input.",
    )
    p.add_argument("input", metavar="IN.fba", help="face object bitstream, or an ASCII .fap file (its text rules)")
    p.add_argument(
        "--scene",
        metavar="S.bt",
        help="scene file (FDP/FIT/FaceDefTables) for profile/level checks: BT text, or binary BIFS (.bifs)",
    )
    p.add_argument("--claim", metavar="PROFILE@LEVEL", help="check against a claim, e.g. simple@1")
    p.add_argument("--json", action="store_true", help="JSON report (schema: profiles/data/check-report.schema.json)")
    p.add_argument(
        "--max-issues",
        type=int,
        default=0,
        metavar="N",
        help="report at most N diagnostics (0 = no limit); the exit status still counts all",
    )
    p.add_argument("--only", nargs="+", default=[], metavar="CODE", help="report only these codes (PREFIX* allowed)")
    p.add_argument(
        "--ignore", nargs="+", default=[], metavar="CODE", help="do not report these codes (PREFIX* allowed)"
    )
    p.add_argument("--smallest-claim", action="store_true", help="print the lowest profile@level the stream fits")
    p.add_argument(
        "--locations", type=int, default=5, metavar="N", help="locations listed per folded issue (default 5)"
    )
    p.set_defaults(func=run)


def build_report(
    rep: Report,
    *,
    file: str | None,
    max_issues: int = 0,
    only=(),
    ignore=(),
    locations: int = 5,
    smallest_claim: bool = False,
) -> tuple[dict, int]:
    """The JSON-able report and the exit status."""
    kept = D.select(rep.diagnostics, list(only), list(ignore))
    total = D.counts(kept)
    shown = kept[:max_issues] if max_issues and max_issues > 0 else kept
    issues = D.fold(shown, max(locations, 0))
    status = 2 if rep.unreadable else (1 if total["error"] else 0)
    doc = {
        "format": REPORT_FORMAT,
        "file": file,
        "claim": str(rep.claim) if rep.claim is not None else None,
        "status": (
            "unreadable"
            if status == 2
            else "violations"
            if status == 1
            else "warnings"
            if total["warning"]
            else "clean"
        ),
        "exit_code": status,
        "counts": total,
        "truncated": len(shown) < len(kept),
        "issues": [i.to_dict() for i in issues],
        "summary": rep.summary,
        "config": {"max_issues": max_issues, "only": list(only), "ignore": list(ignore), "locations": locations},
    }
    if smallest_claim:
        doc["smallest_claim"] = rep.summary.get("smallest_claim")
    return doc, status


def format_text(doc: dict) -> str:
    lines = []
    name = doc["file"] or "<stream>"
    s = doc["summary"]
    head = f"{name}: {doc['status']}"
    if doc["claim"]:
        head += f" (claim {doc['claim']})"
    lines.append(head)
    if s.get("form") == "fap-text":
        rate = f"{s['frame_rate']:g} Hz" if s.get("frame_rate") else "no readable header"
        lines.append(f"  .fap text: {s.get('frames', 0)} frames read, {rate}")
    if "planes" in s:
        rate = f"{s['frame_rate']:g} Hz" if s.get("frame_rate") else "no frame rate"
        lines.append(
            f"  {s['planes']} planes ({s['intra_planes']} intra), {rate}, peak "
            f"{s.get('peak_bitrate_bps', 0) / 1000:.3f} kbit/s, peak {s.get('peak_frame_rate_hz', 0)} "
            f"planes/s, tools: {', '.join(s.get('tools', [])) or '-'}"
        )
    for it in doc["issues"]:
        more = f" (x{it['count']})" if it["count"] > 1 else ""
        lines.append(f"{it['severity']}: {it['code']}{more}: {it['message']}")
        lines.append(f"    clause: {it['clause']}")
        for loc in it["locations"]:
            lines.append(f"    at {_loc_text(loc)}")
        if it["omitted_locations"]:
            lines.append(f"    ... and {it['omitted_locations']} more")
    c = doc["counts"]
    tail = f"{c['error']} error(s), {c['warning']} warning(s), {c['info']} info"
    if doc["truncated"]:
        tail += " (report truncated by --max-issues)"
    lines.append(tail)
    if "smallest_claim" in doc:
        lines.append(f"smallest claim: {doc['smallest_claim'] or 'none'}")
    return "\n".join(lines)


def _loc_text(loc: dict) -> str:
    parts = []
    if "line" in loc:
        parts.append(f"line {loc['line']}:{loc['column']}")
    if "byte_offset" in loc:
        parts.append(f"byte {loc['byte_offset']} bit {loc['bit']}")
    for k in ("plane", "frame", "fap"):
        if k in loc:
            parts.append(f"{k} {loc[k]}")
    if "node_path" in loc:
        parts.append(loc["node_path"])
    return ", ".join(parts) or "stream"


def not_regular(path) -> str | None:
    """Why ``path`` is not a regular file to read (a FIFO, a device, a folder...), or None; asked
    with ``stat``, which never blocks, before anything opens it."""
    try:
        st = os.stat(path)
    except OSError as e:
        return e.strerror or str(e)
    if stat.S_ISREG(st.st_mode):
        return None
    return (
        "is a FIFO"
        if stat.S_ISFIFO(st.st_mode)
        else "is a folder"
        if stat.S_ISDIR(st.st_mode)
        else "is a device or a socket"
    ) + ", not a regular file"


def run(args) -> int:
    ps = load_profiles()
    claim = None
    if args.claim:
        try:
            claim = Claim.parse(args.claim, ps)
        except ValueError as e:
            print(f"fbaconf check: error: {e}", file=sys.stderr)
            return 2
    path = Path(args.input)
    why = args.scene and not_regular(args.scene)
    if why:
        print(f"fbaconf check: error: scene {args.scene}: {why}", file=sys.stderr)
        return 2
    try:
        why = not_regular(path)
        if why:  # refused before it is opened: a FIFO would block, a device stream forever
            raise OSError(why)
        data = path.read_bytes()
    except OSError as e:
        rep = Report(
            [D.diag(R.INPUT_UNREADABLE, f"cannot read {args.input}: {e.strerror or e}")],
            {"bytes": 0},
            unreadable=True,
            claim=claim,
        )
    else:
        if is_text_input(str(path), data) and not data.startswith(b"\x00\x00\x01\xba"):
            if args.scene or claim is not None or args.smallest_claim:
                print(
                    "fbaconf check: error: --scene, --claim and --smallest-claim are for the binary stream; "
                    f"{args.input} is .fap text",
                    file=sys.stderr,
                )
                return 2
            rep = analyse_text(data, file=str(path))
        else:
            rep = analyse(
                data, scene=args.scene, claim=claim, file=str(path), profiles=ps, smallest_claim=args.smallest_claim
            )
    doc, status = build_report(
        rep,
        file=str(path),
        max_issues=args.max_issues,
        only=args.only,
        ignore=args.ignore,
        locations=args.locations,
        smallest_claim=args.smallest_claim,
    )
    if args.json:
        print(json.dumps(doc, indent=2, sort_keys=False))
    else:
        print(format_text(doc))
    return status


__all__ = ["register", "run", "build_report", "format_text", "REPORT_FORMAT"]
