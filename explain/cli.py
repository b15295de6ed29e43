"""``fbaconf explain RUN``: a run's failures as ranked root causes (see explain/causes.py)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from fbaconf.errors import FbaconfInputError

from .confirm import Budget


class ExplainError(FbaconfInputError):
    pass


def register(sub: Any) -> None:
    p = sub.add_parser(
        "explain",
        help="group a run's failing cases into root causes, each confirmed by an input without its trigger",
        description="Read a run (an `fbaconf run` or `certify` output folder, or its report.json), "
        "rank the features the failing cases share that the passing ones do not, and confirm each "
        "cause by running the decoder, in the sandbox, on a variant of a failing case without it.",
    )
    p.add_argument("run", type=Path, help="a run or certification folder, or a JSON report")
    p.add_argument("--json", action="store_true", help="print the explanation as JSON (fbaconf.explain/1)")
    p.add_argument(
        "--decoder",
        help="the decoder's manifest for the confirming runs (default: the one the run recorded, or the "
        "certification folder's decoder.toml)",
    )
    p.add_argument("--no-confirm", action="store_true", help="rank only: run no decoder")
    b = Budget()
    p.add_argument(
        "--per-cause",
        type=int,
        default=b.per_cause,
        help=f"decoder runs per cause to confirm it (default {b.per_cause})",
    )
    p.add_argument(
        "--reruns",
        type=int,
        default=b.reruns,
        help=f"times each of up to {b.rerun_cases} failing cases that did not end with outputs is run again, to "
        f"find undefined behaviour (default {b.reruns})",
    )
    p.add_argument("--keep", type=Path, help="write the confirming inputs into this folder")
    p.add_argument(
        "--write-doc",
        type=Path,
        metavar="DOC",
        help="replace this decoder's block of causes in a markdown document (docs/third-party.md)",
    )
    p.add_argument("--html", type=Path, help="also write the run's HTML report with a causes section here")
    p.add_argument("--sandbox-ro", action="append", default=[], metavar="PATH", help="as for fbaconf run (e.g. a JVM)")
    p.set_defaults(func=cmd_explain)


def _report(run: Path) -> Path:
    if run.is_dir():
        p = run / "report.json"
        if not p.is_file():
            raise ExplainError(f"{run}: no report.json: not an fbaconf run or certification folder", rule="usage")
        return p
    if not run.is_file():
        raise ExplainError(f"{run}: no such file or folder", rule="usage")
    return run


def cmd_explain(args: argparse.Namespace) -> int:
    from fbaconf.conformance.suite import load_suites
    from fbaconf.harness import reports
    from fbaconf.harness.adapters import CommandAdapter, resolve
    from fbaconf.harness.usage import lab_folders
    from fbaconf.isolation import sandbox

    from .causes import explain
    from .render import markdown, replace_block, terminal

    report = _report(args.run)
    try:
        record = reports.read_json(report)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ExplainError(f"{report}: not an fbaconf run report: {e}", rule="usage") from None
    cases = {c.full_id: c for s in load_suites() for c in s.cases}
    manifest = args.decoder or record.decoder.get("manifest")
    if not args.decoder and args.run.is_dir() and (args.run / "decoder.toml").is_file():
        manifest = str(args.run / "decoder.toml")
    adapter, why = None, ""
    if args.no_confirm:
        why = "--no-confirm"
    elif not manifest or not Path(manifest).is_file():
        why = f"the decoder's manifest {manifest or '(none recorded)'} is not here: give --decoder"
    else:
        adapter = resolve(manifest)
        if isinstance(adapter, CommandAdapter):
            if sandbox.isolation() != "bwrap":
                adapter, why = None, "bubblewrap cannot make a sandbox here, and explain runs no decoder outside one"
            elif args.sandbox_ro:
                adapter.lab_read_only = lab_folders(args.sandbox_ro)
    if args.per_cause < 0 or args.reruns < 0:
        raise ExplainError("--per-cause and --reruns must be >= 0", rule="usage")
    budget = Budget(per_cause=args.per_cause, reruns=args.reruns)
    ex = explain(record, cases, adapter=adapter, why_not=why, budget=budget, keep=args.keep)
    if adapter is not None:
        where = "in the sandbox (bubblewrap)" if isinstance(adapter, CommandAdapter) else "in-process (bundled)"
        ex.confirming = (
            f"{budget.per_cause} per cause x {budget.max_causes} causes + {budget.reruns} reruns x "
            f"{budget.rerun_cases} cases, every run {where}"
        )
    doc = ex.to_json()
    if args.html:
        reports.write_html(record, args.html, base_dir=report.parent, causes=doc)
    if args.write_doc:
        counts: dict[str, int] = {}
        for r in record.results:
            counts[r.outcome.value] = counts.get(r.outcome.value, 0) + 1
        doc_text = args.write_doc.read_text(encoding="utf-8") if args.write_doc.is_file() else ""
        args.write_doc.write_text(replace_block(doc_text, ex.decoder, markdown(ex, counts)), encoding="utf-8")
    if args.json:
        json.dump(doc, sys.stdout, indent=1)
        print()
    else:
        print(terminal(ex))
    return 0
