"""The terminal summary: aligned tables per suite, profile and outcome, the failing cases, speed, the verdict line."""

from __future__ import annotations

from collections.abc import Callable, Iterable

from fbaconf.harness.results import CaseResult, Outcome, RunRecord
from fbaconf.harness.verdict import describe
from fbaconf.isolation.endings import crash_report

from .common import (
    DISPLAY_COLUMNS,
    NS_REQUIRED,
    _by,
    _speed_rows,
    _speed_summary,
    _suite_names,
    _summary_counts,
    baseline_lines,
    clean_text,
    display_counts,
    failure_groups,
    format_difference,
    profile_of,
    provisional_line,
    reproduce_line,
    verdict,
    verdict_reason,
)

_ANSI_COLOURS: dict[str, str] = {
    Outcome.PASS: "32",
    Outcome.QUALITY_WARNING: "33",
    Outcome.NOT_SUPPORTED: "36",
    Outcome.SKIPPED: "2",
    Outcome.FAIL: "31",
    Outcome.TIMEOUT: "35",
    Outcome.CRASH: "1;31",
    Outcome.ERROR: "1;35",
}
_ANSI_COLOURS[NS_REQUIRED] = "1;33"


def _table(
    header: list[str], rows: list[list[str]], right: set[int], colour: Callable[[int, int, str], str] | None = None
) -> list[str]:
    """Aligned text table; ``colour(row, col, padded_text)`` may wrap a padded cell in ANSI codes."""
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)] if rows else [len(h) for h in header]
    out = []
    for ri, row in enumerate([header] + rows):
        cells = []
        for ci, cell in enumerate(row):
            text = str(cell).rjust(widths[ci]) if ci in right else str(cell).ljust(widths[ci])
            if colour and ri > 0:
                text = colour(ri - 1, ci, text)
            cells.append(text)
        out.append("  " + "  ".join(cells).rstrip())
    return out


def _indent(text: str, prefix: str) -> list[str]:
    return [prefix + line for line in text.splitlines()] or [prefix.rstrip()]


def _stderr_excerpt(r: CaseResult, n: int = 6) -> tuple[str, list[str]]:
    """What of a case's stderr the summary shows: the crash report's first lines when stderr holds
    one (sanitizer, panic, exception), else the last lines."""
    text = r.stderr_tail
    rep = crash_report(text) if r.crash_kind else None
    at = text.find(rep.line) if rep is not None and rep.line else -1
    if at >= 0:
        start = text.rfind("\n", 0, at) + 1
        return "the crash report", [clean_text(x) for x in text[start:].rstrip().splitlines()[:n]]
    return "last lines", clean_text(text).rstrip().splitlines()[-(n - 1) :]


def terminal_summary(record: RunRecord, *, color: bool = False, max_failures: int = 20) -> str:  # noqa: C901
    """A plain-text summary of ``record`` (ANSI colours when ``color``), ending with the verdict line
    ``result: PASS|FAIL|SPEED FAIL|SPEED INCONCLUSIVE|SETUP ERROR (N cases: a Pass, b Fail, ...)``."""

    def paint(code: str, text: str) -> str:
        return f"\x1b[{code}m{text}\x1b[0m" if color else text

    lines: list[str] = []
    dec = record.decoder or {}
    lines.append(
        f"fbaconf run: decoder {clean_text(dec.get('name', '?'))}"
        + (f", claim {clean_text(record.claim)}" if record.claim else "")
        + (f", {record.duration_s:.1f} s" if record.duration_s else "")
    )
    lines += ["  " + x for x in baseline_lines(record)]  # what fails the run against its baseline, first
    suites = []
    for s in record.suites:
        n = s.get("cases")
        n = len(n) if isinstance(n, (list, tuple)) else n
        suites.append(
            f"{clean_text(s.get('name', '?'))} {clean_text(s.get('version', ''))}".rstrip()
            + (f" ({n} cases)" if n is not None else "")
        )
    if suites:
        lines.append("  suites: " + ", ".join(suites))
    if record.provisional:
        lines.append(f"  provisional: {provisional_line(record)}")

    header_cols = list(DISPLAY_COLUMNS) + ["total"]

    def colour_counts(_r: int, ci: int, text: str) -> str:
        if ci == 0 or ci > len(DISPLAY_COLUMNS) or not text.strip() or text.strip() == "0":
            return text
        return paint(_ANSI_COLOURS[DISPLAY_COLUMNS[ci - 1]], text)

    def count_table(title: str, groups: dict[str, dict[str, int]], order: Iterable[str]) -> None:
        rows = []
        for name in order:
            c = groups.get(name, dict.fromkeys(DISPLAY_COLUMNS, 0))
            rows.append([clean_text(name)] + [str(c[k]) for k in DISPLAY_COLUMNS] + [str(sum(c.values()))])
        tot = display_counts(record.results)
        rows.append(["total"] + [str(tot[k]) for k in DISPLAY_COLUMNS] + [str(sum(tot.values()))])
        lines.append("")
        lines.extend(_table([title] + header_cols, rows, set(range(1, len(header_cols) + 1)), colour_counts))

    by_suite = _by(record, lambda r: r.suite)
    count_table("suite", by_suite, _suite_names(record))
    by_profile = _by(record, lambda r: profile_of(r.claim))
    count_table("profile", by_profile, sorted(by_profile))

    groups = failure_groups(record)
    if groups:
        n_cases = sum(len(rs) for _o, rs in groups)
        shown = groups[: max(0, max_failures)]
        lines.append("")
        lines.append(
            f"cases to look at: {n_cases} in {len(groups)} group(s) of identical failures"
            + (f" ({len(shown)} groups shown)" if len(shown) < len(groups) else "")
        )
        for outcome, rs in shown:
            r = rs[0]
            tags = []
            if not r.required:
                tags.append("optional")
            if r.baseline:
                tags.append(f"baseline: {clean_text(r.baseline)}")
            count = f" x{len(rs)}" if len(rs) > 1 else ""
            head = f"  {paint(_ANSI_COLOURS[r.outcome], (outcome + count).ljust(14))} {clean_text(r.case_id)}"
            if len(rs) > 1:
                others = ", ".join(clean_text(x.case_id.split("/", 1)[-1]) for x in rs[1:9])
                head += f" (and {others}" + (f", +{len(rs) - 9} more" if len(rs) > 9 else "") + ")"
            lines.append(head + (f"  [{', '.join(tags)}]" if tags else ""))
            if r.message:
                lines.extend(_indent(clean_text(r.message), " " * 6))
            diff = r.first_difference
            if diff and format_difference(diff) not in (r.message or ""):
                lines.append(f"      first difference: {format_difference(diff)}")
            if r.outcome in (Outcome.CRASH, Outcome.ERROR, Outcome.TIMEOUT):
                how = []
                if r.exit_code is not None:
                    how.append(f"exit code {r.exit_code}")
                if r.signal:
                    how.append(f"signal {clean_text(r.signal)}")
                if r.crash_kind:
                    how.append(f"report: {clean_text(r.crash_kind)}")
                if how:
                    lines.append("      " + ", ".join(how))
                if r.stderr_tail:
                    label, tail = _stderr_excerpt(r)
                    lines.append(f"      stderr ({label}):")
                    lines.extend("        " + t for t in tail)
            if r.command:
                lines.append("      reproduce: " + reproduce_line(r, env=dec.get("env")))
        if len(shown) < len(groups):
            lines.append(f"  ... and {len(groups) - len(shown)} more group(s) (see the JSON/HTML report)")

    if record.speed:
        lines.append("")
        lines.append("speed:")

        def colour_speed(ri: int, ci: int, text: str) -> str:
            if ci != 4:
                return text
            return paint({"PASS": "32", "INCONCLUSIVE": "33"}.get(text.strip(), "31"), text)

        rows = [[clean_text(c) for c in row] for row in _speed_rows(record.speed)]
        lines.extend(
            _table(
                ["operation", "claim", "measured fps", "required fps", "verdict", "provenance"],
                rows,
                {2, 3},
                colour_speed,
            )
        )
        for sp in record.speed:
            if sp.message:
                lines.append(f"  {clean_text(sp.operation)}: {clean_text(sp.message)}")

    detail = describe(record.verdict or {})
    if detail and record.claim:
        lines += ["", f"tools and provisional decisions of {clean_text(record.claim)} (harness/verdict.py):"]
        lines += [f"  {clean_text(x)}" for x in detail]
    if record.provisional_differences:
        strictly = (
            "they fail the claim (--strict)" if record.strict else "the claim passes with them; --strict fails them"
        )
        lines += ["", f"provisional differences ({strictly}): cases judged by an other reading the decoder declares"]
        lines += [
            f"  {clean_text(d['case_id'])}  rests on {', '.join(d['rests_on'])}; judged by {d.get('reading')}"
            for d in record.provisional_differences
        ]

    v = verdict(record)
    lines.append("")
    code = (
        "33"
        if record.exit_code in (3, 4) or (record.exit_code == 0 and v != "PASS")
        else "32"
        if record.exit_code == 0
        else "31"
    )
    reason = verdict_reason(record)
    if reason:
        lines.append(f"why: {reason}")
    lines.append(
        f"result: {paint('1;' + code, v)} "
        f"({_summary_counts(display_counts(record.results))}{_speed_summary(record.speed)})"
    )
    return "\n".join(lines) + "\n"
