"""Reports of a harness run, all built from one :class:`~fbaconf.harness.results.RunRecord`.

- :func:`terminal_summary` — aligned text tables (per suite, per profile, per outcome),
  the failing cases with their first difference, speed results and a final verdict line;
- :func:`write_json` / :func:`read_json` — the record as strict JSON (schema
  ``harness/data/run-report.schema.json``);
- :func:`write_junit` — JUnit XML for CI systems (ElementTree, no extra dependency);
- :func:`write_html` — one self-contained page (inline CSS and SVG, no script).

Everything a decoder produced (messages, stderr tails, first-difference values, even
case ids and artefact names) is untrusted: it is escaped for HTML and XML, stripped of
terminal control sequences for the terminal, and characters XML cannot hold are shown
as ``\\xNN`` escapes. Every file is written atomically.
"""
from __future__ import annotations

import hashlib
import html
import json
import math
import os
import re
import shlex
from collections import Counter
from pathlib import Path
from typing import Any, Iterable
from xml.etree import ElementTree as ET

from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.harness.results import OUTCOME_ORDER, CaseResult, Outcome, RunRecord, SpeedResult

__all__ = ["terminal_summary", "write_json", "read_json", "report_json", "write_junit", "junit_xml",
           "write_html", "html_report", "format_difference", "verdict", "profile_of", "svg_plot", "clean_text"]

# Column order of the outcome tables (as the Outcome enum: Pass first, then the bad ones).
COLUMNS = tuple(Outcome)

VERDICTS = {0: "PASS", 1: "FAIL", 2: "SETUP ERROR", 3: "SPEED FAIL"}

# Non-finite floats are not JSON; they are written as these strings and read back.
_NONFINITE = {"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}


# --------------------------------------------------------------------------- helpers

_ANSI = re.compile(r"\x1b(?:\[[0-?]*[ -/]*[@-~]|\][^\x07\x1b]*(?:\x07|\x1b\\)?|[@-Z\\-_])")
# Characters XML 1.0 cannot hold, plus the other C0/C1 controls (kept out of every report).
_BAD_CHARS = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff\ufffe\uffff]")


def clean_text(value: Any) -> str:
    """``value`` as text safe for a terminal, XML and HTML (before escaping): ANSI/OSC escape
    sequences removed, other control characters, lone surrogates and U+FFFE/U+FFFF shown as
    ``\\xNN``/``\\uNNNN``; newlines, tabs and carriage returns kept."""
    s = value if isinstance(value, str) else str(value)
    s = _ANSI.sub("", s)

    def esc(m: re.Match) -> str:
        c = ord(m.group(0))
        return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"
    return _BAD_CHARS.sub(esc, s)


def profile_of(claim: str | None) -> str:
    """The profile part of a claim: ``"simple"`` from ``"simple@1"``; ``"-"`` when unknown."""
    if not claim:
        return "-"
    return claim.split("@", 1)[0] or "-"


def verdict(record: RunRecord) -> str:
    """``PASS`` / ``FAIL`` / ``SPEED FAIL`` / ``SETUP ERROR`` from the record's exit code."""
    return VERDICTS.get(record.exit_code, f"EXIT {record.exit_code}")


def _fmt_value(v: Any) -> str:
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt_value(x) for x in v) + "]"
    return str(v)


_DIFF_WHERE = ("frame", "time_ms", "fap", "name", "vertex", "part", "pixel", "channel", "field")


def format_difference(d: dict | None) -> str:
    """One line for a first difference: ``frame 12, FAP 31 (raise_l_i_eyebrow): expected 120, got 121``."""
    if not d:
        return ""
    where = []
    if "frame" in d:
        where.append(f"frame {_fmt_value(d['frame'])}")
    if "time_ms" in d:
        where.append(f"t={_fmt_value(d['time_ms'])} ms")
    for key, label in (("fap", "FAP"), ("vertex", "vertex"), ("pixel", "pixel"), ("channel", "channel"),
                       ("field", "field")):
        if key in d:
            item = f"{label} {_fmt_value(d[key])}"
            extra = [str(d[k]) for k in ("name", "part") if k in d and key in ("fap", "vertex")]
            if extra:
                item += " (" + ", ".join(extra) + ")"
            where.append(item)
    if "fap" not in d and "vertex" not in d:
        where += [f"{k} {_fmt_value(d[k])}" for k in ("name", "part") if k in d]
    text = ", ".join(where)
    vals = []
    if "expected" in d:
        vals.append(f"expected {_fmt_value(d['expected'])}")
    if "got" in d:
        vals.append(f"got {_fmt_value(d['got'])}")
    rest = [f"{k} {_fmt_value(v)}" for k, v in d.items() if k not in _DIFF_WHERE + ("expected", "got")]
    parts = [p for p in (text, ", ".join(vals), ", ".join(rest)) if p]
    return clean_text(": ".join(parts[:2]) + ("; " + parts[2] if len(parts) > 2 else ""))


def _suite_names(record: RunRecord) -> list[str]:
    names = [str(s.get("name")) for s in record.suites if s.get("name") is not None]
    for r in record.results:
        if r.suite not in names:
            names.append(r.suite)
    return names


def _by(record: RunRecord, key) -> dict[str, dict[str, int]]:
    groups: dict[str, list[CaseResult]] = {}
    for r in record.results:
        groups.setdefault(key(r), []).append(r)
    return {k: record.counts(v) for k, v in groups.items()}


def _summary_counts(counts: dict[str, int]) -> str:
    n = sum(counts.values())
    parts = [f"{counts[o.value]} {o.value}" for o in COLUMNS if counts.get(o.value)]
    return f"{n} case{'s' if n != 1 else ''}" + (": " + ", ".join(parts) if parts else "")


def _speed_summary(speed: list[SpeedResult]) -> str:
    if not speed:
        return ""
    bad = sum(1 for s in speed if not s.passed)
    return f"; speed: {len(speed) - bad} of {len(speed)} pass" + (f", {bad} below the level minimum" if bad else "")


def _problem_cases(record: RunRecord) -> list[CaseResult]:
    """Cases worth a closer look, worst first: failing, quality warnings, baseline changes."""
    rank = {o: i for i, o in enumerate(OUTCOME_ORDER)}
    picked = [r for r in record.results
              if r.outcome.failing or r.outcome is Outcome.QUALITY_WARNING or r.baseline in ("fixed", "flake")]
    return sorted(picked, key=lambda r: (rank[r.outcome], not r.required, r.case_id))


def _speed_rows(speed: list[SpeedResult]) -> list[list[str]]:
    return [[s.operation, s.claim, f"{s.rate_fps:.2f}", f"{s.required_fps:.2f}", "PASS" if s.passed else "FAIL",
             s.provenance] for s in speed]


# --------------------------------------------------------------------------- terminal

_ANSI_COLOURS = {
    Outcome.PASS: "32", Outcome.QUALITY_WARNING: "33", Outcome.NOT_SUPPORTED: "36", Outcome.SKIPPED: "2",
    Outcome.FAIL: "31", Outcome.TIMEOUT: "35", Outcome.CRASH: "1;31", Outcome.ERROR: "1;35",
}


def _table(header: list[str], rows: list[list[str]], right: set[int], colour=None) -> list[str]:
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


def terminal_summary(record: RunRecord, *, color: bool = False, max_failures: int = 20) -> str:
    """A plain-text summary of ``record`` (ANSI colours when ``color``), ending with the verdict line
    ``result: PASS|FAIL|SPEED FAIL|SETUP ERROR (N cases: a Pass, b Fail, ...)``."""
    def paint(code: str, text: str) -> str:
        return f"\x1b[{code}m{text}\x1b[0m" if color else text

    lines: list[str] = []
    dec = record.decoder or {}
    lines.append(f"fbaconf run: decoder {clean_text(dec.get('name', '?'))}"
                 + (f", claim {clean_text(record.claim)}" if record.claim else "")
                 + (f", {record.duration_s:.1f} s" if record.duration_s else ""))
    suites = []
    for s in record.suites:
        n = s.get("cases")
        n = len(n) if isinstance(n, (list, tuple)) else n
        suites.append(f"{clean_text(s.get('name', '?'))} {clean_text(s.get('version', ''))}".rstrip()
                      + (f" ({n} cases)" if n is not None else ""))
    if suites:
        lines.append("  suites: " + ", ".join(suites))
    for p in record.provisional:
        lines.append(f"  provisional: {clean_text(p)}")

    header_cols = [o.value for o in COLUMNS] + ["total"]

    def colour_counts(_r, ci, text):
        if ci == 0 or ci > len(COLUMNS) or not text.strip() or text.strip() == "0":
            return text
        return paint(_ANSI_COLOURS[COLUMNS[ci - 1]], text)

    def count_table(title: str, groups: dict[str, dict[str, int]], order: Iterable[str]):
        rows = []
        for name in order:
            c = groups.get(name, {o.value: 0 for o in COLUMNS})
            rows.append([clean_text(name)] + [str(c[o.value]) for o in COLUMNS] + [str(sum(c.values()))])
        tot = record.counts()
        rows.append(["total"] + [str(tot[o.value]) for o in COLUMNS] + [str(sum(tot.values()))])
        lines.append("")
        lines.extend(_table([title] + header_cols, rows, set(range(1, len(header_cols) + 1)), colour_counts))

    by_suite = _by(record, lambda r: r.suite)
    count_table("suite", by_suite, _suite_names(record))
    by_profile = _by(record, lambda r: profile_of(r.claim))
    count_table("profile", by_profile, sorted(by_profile))

    problems = _problem_cases(record)
    if problems:
        shown = problems[:max(0, max_failures)]
        lines.append("")
        lines.append(f"cases to look at ({len(shown)} of {len(problems)} shown):")
        for r in shown:
            tags = []
            if not r.required:
                tags.append("optional")
            if r.baseline:
                tags.append(f"baseline: {clean_text(r.baseline)}")
            head = f"  {paint(_ANSI_COLOURS[r.outcome], r.outcome.value.ljust(14))} {clean_text(r.case_id)}"
            lines.append(head + (f"  [{', '.join(tags)}]" if tags else ""))
            if r.message:
                lines.extend(_indent(clean_text(r.message), " " * 6))
            for st in r.stages:
                if st.outcome is not Outcome.PASS and st.message and st.message != r.message:
                    lines.extend(_indent(f"{st.stage}: {clean_text(st.message)}", " " * 6))
            diff = r.first_difference
            if diff:
                lines.append(f"      first difference: {format_difference(diff)}")
            if r.signal or (r.exit_code not in (None, 0) and r.outcome in (Outcome.CRASH, Outcome.ERROR)):
                lines.append(f"      exit code {r.exit_code}" + (f", signal {clean_text(r.signal)}" if r.signal else ""))
            if r.stderr_tail and r.outcome in (Outcome.CRASH, Outcome.TIMEOUT, Outcome.ERROR):
                tail = clean_text(r.stderr_tail).rstrip().splitlines()[-5:]
                lines.append("      stderr (last lines):")
                lines.extend("        " + t for t in tail)
        if len(problems) > len(shown):
            lines.append(f"  ... and {len(problems) - len(shown)} more (see the JSON/HTML report)")

    if record.speed:
        lines.append("")
        lines.append("speed:")

        def colour_speed(ri, ci, text):
            if ci != 4:
                return text
            return paint("32" if record.speed[ri].passed else "31", text)
        rows = [[clean_text(c) for c in row] for row in _speed_rows(record.speed)]
        lines.extend(_table(["operation", "claim", "measured fps", "required fps", "verdict", "provenance"],
                            rows, {2, 3}, colour_speed))
        for s in record.speed:
            if s.message:
                lines.append(f"  {clean_text(s.operation)}: {clean_text(s.message)}")

    v = verdict(record)
    lines.append("")
    code = "32" if record.exit_code == 0 else ("33" if record.exit_code == 3 else "31")
    lines.append(f"result: {paint('1;' + code, v)} ({_summary_counts(record.counts())}{_speed_summary(record.speed)})")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- JSON

def _jsonable(obj: Any) -> Any:
    """Plain JSON values: numpy scalars/arrays, paths and enums converted; non-finite floats as
    the strings ``Infinity``/``-Infinity``/``NaN`` (strict JSON has no such numbers)."""
    if obj is None or isinstance(obj, (bool, str, int)):
        return obj
    if isinstance(obj, float):
        if math.isfinite(obj):
            return obj
        return "NaN" if math.isnan(obj) else ("Infinity" if obj > 0 else "-Infinity")
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "value") and isinstance(getattr(obj, "value"), str):  # Enum
        return obj.value
    if hasattr(obj, "tolist"):  # numpy array or scalar
        return _jsonable(obj.tolist())
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    return str(obj)


def _restore_float(v: Any) -> Any:
    return _NONFINITE.get(v, v) if isinstance(v, str) else v


def _restore(doc: dict) -> dict:
    """Undo the non-finite spelling in the numeric fields (metrics, series, durations, speed)."""
    doc = json.loads(json.dumps(doc))  # private copy
    doc["duration_s"] = _restore_float(doc.get("duration_s", 0.0))
    for r in doc.get("results", []):
        r["duration_s"] = _restore_float(r.get("duration_s", 0.0))
        for st in r.get("stages", []):
            st["metrics"] = {k: _restore_float(v) for k, v in st.get("metrics", {}).items()}
            st["series"] = {k: [_restore_float(x) for x in v] for k, v in st.get("series", {}).items()}
    for s in doc.get("speed", []):
        for k in ("per_frame_s", "startup_s", "rate_fps", "required_fps", "fit_r2"):
            if k in s:
                s[k] = _restore_float(s[k])
    return doc


def report_json(record: RunRecord) -> dict:
    """The JSON document written by :func:`write_json` (``record.to_json()`` made strict JSON)."""
    return _jsonable(record.to_json())


def write_json(record: RunRecord, path) -> Path:
    """Write ``record.to_json()`` as indented, strict, ASCII-only JSON (atomically); returns the path."""
    path = Path(path)
    text = json.dumps(report_json(record), indent=2, ensure_ascii=True, allow_nan=False)
    atomic_write_text(path, text + "\n")
    return path


def read_json(path) -> RunRecord:
    """Read a report written by :func:`write_json` back (non-finite metrics restored)."""
    with open(path, encoding="utf-8") as f:
        return RunRecord.from_json(_restore(json.load(f)))


# --------------------------------------------------------------------------- JUnit XML

def _sec(x: float) -> str:
    return f"{x:.3f}" if isinstance(x, (int, float)) and math.isfinite(x) and x >= 0 else "0.000"


def _case_details(r: CaseResult) -> str:
    out = []
    if r.message:
        out.append(r.message)
    if r.baseline:
        out.append(f"baseline: {r.baseline}")
    if not r.required:
        out.append("optional (not required by the claim)")
    out.append(f"claim: {r.claim}")
    diff = r.first_difference
    if diff:
        out.append(f"first difference: {format_difference(diff)}")
    for st in r.stages:
        line = f"stage {st.stage}: {st.outcome.value}"
        if st.message:
            line += f" - {st.message}"
        if st.metrics:
            line += " (" + ", ".join(f"{k}={_fmt_value(v)}" for k, v in st.metrics.items()) + ")"
        out.append(line)
    if r.command:
        out.append("command: " + shlex.join(str(a) for a in r.command))
    if r.exit_code is not None or r.signal:
        out.append(f"exit code: {r.exit_code}" + (f", signal {r.signal}" if r.signal else ""))
    if r.stderr_tail:
        out.append("stderr (tail):\n" + r.stderr_tail)
    return clean_text("\n".join(out))


def _one_line(text: str, limit: int = 500) -> str:
    s = " ".join(clean_text(text).split())
    return s if len(s) <= limit else s[:limit - 1] + "\u2026"


def _properties(parent: ET.Element, props: list[tuple[str, Any]]) -> None:
    el = ET.SubElement(parent, "properties")
    for name, value in props:
        if isinstance(value, (dict, list)):
            value = json.dumps(_jsonable(value), sort_keys=True, ensure_ascii=False)
        ET.SubElement(el, "property", name=clean_text(name), value=clean_text("" if value is None else value))


def junit_xml(record: RunRecord) -> bytes:
    """The JUnit XML document written by :func:`write_junit`."""
    dec = record.decoder or {}
    common = [("decoder", dec.get("name")), ("decoder.manifest_sha256", dec.get("manifest_sha256")),
              ("claim", record.claim), ("exit_code", record.exit_code), ("verdict", verdict(record))]
    common += [(f"provisional.{i}", p) for i, p in enumerate(record.provisional)]
    common += [(f"system.{k}", v) for k, v in (record.system or {}).items()]
    suite_meta = {str(s.get("name")): s for s in record.suites}
    root = ET.Element("testsuites", name=clean_text(f"fbaconf {dec.get('name', '')}".strip()))
    totals = Counter()
    for name in _suite_names(record):
        cases = [r for r in record.results if r.suite == name]
        c = Counter()
        ts = ET.SubElement(root, "testsuite", name=clean_text(name))
        meta = suite_meta.get(name, {})
        _properties(ts, common + [(f"suite.{k}", v) for k, v in meta.items() if k != "name"])
        for r in cases:
            tc = ET.SubElement(ts, "testcase", classname=clean_text(f"fbaconf.{r.suite}"), name=clean_text(r.case_id),
                               time=_sec(r.duration_s))
            o = r.outcome
            msg = _one_line(r.message or o.value)
            if o in (Outcome.FAIL, Outcome.TIMEOUT, Outcome.CRASH):
                el = ET.SubElement(tc, "failure", message=msg, type=o.value)
                el.text = _case_details(r)
                c["failures"] += 1
            elif o is Outcome.ERROR:
                el = ET.SubElement(tc, "error", message=msg, type=o.value)
                el.text = _case_details(r)
                c["errors"] += 1
            elif o in (Outcome.NOT_SUPPORTED, Outcome.SKIPPED):
                el = ET.SubElement(tc, "skipped", message=_one_line(f"{o.value}: {r.message}" if r.message else o.value))
                c["skipped"] += 1
            elif o is Outcome.QUALITY_WARNING:
                ET.SubElement(tc, "system-out").text = "QualityWarning (passes): " + _case_details(r)
            elif r.baseline:
                ET.SubElement(tc, "system-out").text = clean_text(f"baseline: {r.baseline}")
            c["tests"] += 1
            c["time"] += r.duration_s if math.isfinite(r.duration_s) and r.duration_s > 0 else 0.0
        ts.set("tests", str(c["tests"]))
        for k in ("failures", "errors", "skipped"):
            ts.set(k, str(c[k]))
        ts.set("time", _sec(c["time"]))
        if record.started:
            ts.set("timestamp", clean_text(record.started))
        totals.update(c)
    if record.speed:
        ts = ET.SubElement(root, "testsuite", name="speed")
        c = Counter()
        _properties(ts, common)
        for s in record.speed:
            t = sum(float(x.get("seconds", 0.0)) for x in s.samples if isinstance(x, dict))
            tc = ET.SubElement(ts, "testcase", classname="fbaconf.speed",
                               name=clean_text(f"{s.operation} {s.claim}"), time=_sec(t))
            text = (f"{s.operation}: {s.rate_fps:.2f} fps measured, {s.required_fps:.2f} fps required "
                    f"(provenance: {s.provenance}); per frame {s.per_frame_s:.6g} s, startup {s.startup_s:.6g} s, "
                    f"fit r2 {s.fit_r2:.4f}" + (f"\n{s.message}" if s.message else ""))
            if not s.passed:
                el = ET.SubElement(tc, "failure", type="SpeedBelowMinimum",
                                   message=_one_line(f"{s.operation} {s.rate_fps:.2f} fps below the required "
                                                     f"{s.required_fps:.2f} fps ({s.provenance})"))
                el.text = clean_text(text)
                c["failures"] += 1
            else:
                ET.SubElement(tc, "system-out").text = clean_text(text)
            c["tests"] += 1
            c["time"] += t
        ts.set("tests", str(c["tests"]))
        for k in ("failures", "errors", "skipped"):
            ts.set(k, str(c[k]))
        ts.set("time", _sec(c["time"]))
        if record.started:
            ts.set("timestamp", clean_text(record.started))
        totals.update(c)
    root.set("tests", str(totals["tests"]))
    for k in ("failures", "errors", "skipped"):
        root.set(k, str(totals[k]))
    root.set("time", _sec(record.duration_s if record.duration_s else totals["time"]))
    ET.indent(root)
    return ET.tostring(root, encoding="utf-8", xml_declaration=True) + b"\n"


def write_junit(record: RunRecord, path) -> Path:
    """Write the run as JUnit XML (one ``<testsuite>`` per suite plus ``speed``), atomically."""
    path = Path(path)
    atomic_write_bytes(path, junit_xml(record))
    return path


# --------------------------------------------------------------------------- HTML

def _e(value: Any) -> str:
    """Escape anything for HTML text or a quoted attribute."""
    return html.escape(clean_text("" if value is None else value), quote=True)


_CSS = """
:root{--pass:#1a7f37;--qw:#b7791f;--ns:#3b7a9e;--skip:#6e7781;--fail:#cf222e;--timeout:#bc4c00;
--crash:#82071e;--error:#8250df;--bg:#fff;--fg:#1f2328;--muted:#57606a;--line:#d0d7de;--soft:#f6f8fa}
*{box-sizing:border-box}
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,Helvetica,Arial,sans-serif;color:var(--fg);
background:var(--bg);margin:0 auto;max-width:1200px;padding:1.2em 1.5em 3em}
h1{font-size:1.6em;margin:.2em 0 .4em}h2{font-size:1.25em;margin:1.6em 0 .5em;border-bottom:1px solid var(--line);
padding-bottom:.2em}h3{font-size:1.05em;margin:.2em 0 .4em}
code,pre,.mono{font-family:ui-monospace,SFMono-Regular,Menlo,Consolas,monospace;font-size:12.5px}
pre{background:var(--soft);border:1px solid var(--line);border-radius:4px;padding:.5em .7em;white-space:pre-wrap;
word-break:break-word;margin:.3em 0;max-height:24em;overflow:auto}
table{border-collapse:collapse;margin:.4em 0}th,td{border:1px solid var(--line);padding:.2em .55em;text-align:left;
vertical-align:top}th{background:var(--soft);font-weight:600}td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
.muted{color:var(--muted)}.meta td:first-child{color:var(--muted);white-space:nowrap}
.badge{display:inline-block;border-radius:3px;padding:0 .45em;color:#fff;font-weight:600;font-size:.85em;
letter-spacing:.02em;vertical-align:1px}
.verdict{font-size:1.1em;padding:.15em .7em}
.o-Pass{background:var(--pass)}.o-QualityWarning{background:var(--qw)}.o-NotSupported{background:var(--ns)}
.o-Skipped{background:var(--skip)}.o-Fail{background:var(--fail)}.o-Timeout{background:var(--timeout)}
.o-Crash{background:var(--crash)}.o-Error{background:var(--error)}
td.c-Pass{background:#dafbe1}td.c-QualityWarning{background:#fff8c5}td.c-NotSupported{background:#ddf4ff}
td.c-Skipped{background:#eaeef2}td.c-Fail,td.c-Timeout,td.c-Crash{background:#ffebe9;color:#82071e;font-weight:600}
td.c-Error{background:#fbefff;color:#6e40c9;font-weight:600}td.zero{color:#afb8c1}
tr.total td{font-weight:600;border-top:2px solid var(--fg)}
.v-PASS{background:var(--pass)}.v-FAIL,.v-SETUP{background:var(--fail)}.v-SPEED{background:var(--qw)}
.case{border:1px solid var(--line);border-left:6px solid var(--skip);border-radius:4px;padding:.6em .9em;margin:.9em 0}
.case.k-Fail,.case.k-Timeout,.case.k-Crash{border-left-color:var(--fail)}.case.k-Error{border-left-color:var(--error)}
.case.k-QualityWarning{border-left-color:var(--qw)}.case.k-Pass{border-left-color:var(--pass)}
.tag{display:inline-block;border:1px solid var(--line);border-radius:10px;padding:0 .5em;font-size:.8em;
color:var(--muted);margin-left:.3em}
.stage{margin:.6em 0 .2em}.images{display:flex;flex-wrap:wrap;gap:.8em;margin:.4em 0}
figure{margin:0;border:1px solid var(--line);border-radius:4px;padding:.3em;background:var(--soft)}
figure img{display:block;min-width:96px;max-width:300px;max-height:300px;image-rendering:pixelated;background:#fff}
figcaption{font-size:.85em;color:var(--muted);text-align:center}
.glabel{align-self:center;min-width:4.5em}
.plots{display:flex;flex-wrap:wrap;gap:.8em;margin:.4em 0}
svg.plot{border:1px solid var(--line);border-radius:4px;background:#fff}
svg.plot text{font:11px system-ui,sans-serif;fill:#57606a}svg.plot text.t{font-weight:600;fill:#1f2328}
details{margin:.6em 0}summary{cursor:pointer;font-weight:600}
ul.prov li{margin:.15em 0}
footer{margin-top:2.5em;color:var(--muted);font-size:.85em}
"""

_IMG_EXT = {".png", ".jpg", ".jpeg", ".gif", ".webp", ".bmp"}
_COPY_EXT = _IMG_EXT | {".exr", ".tif", ".tiff", ".npz", ".fap", ".fba", ".json", ".txt", ".csv"}
_ARTEFACT_ORDER = ("expected", "got", "diff")


def _nice_ticks(lo: float, hi: float, n: int = 4) -> list[float]:
    raw = (hi - lo) / n
    if not math.isfinite(raw) or raw <= 0:
        return [lo, hi] if math.isfinite(lo) and math.isfinite(hi) else []
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 2.5, 5, 10) if m * mag >= raw)
    try:
        start = math.ceil(lo / step) * step
    except (OverflowError, ValueError):
        return [lo, hi]
    ticks = []
    t = start
    while t <= hi + step * 1e-9 and len(ticks) < 20:
        ticks.append(round(t, 12))
        t += step
    return ticks


def svg_plot(name: str, values: list[float], *, width: int = 380, height: int = 170,
             x_label: str = "frame") -> str:
    """An inline SVG line plot of one per-frame series (non-finite values break the line)."""
    ml, mr, mt, mb = 52, 12, 22, 32
    pw, ph = width - ml - mr, height - mt - mb
    vals = []
    for v in values:
        try:
            vals.append(float(v))
        except (TypeError, ValueError):
            vals.append(math.nan)
    finite = [v for v in vals if math.isfinite(v)]
    parts = [f'<svg class="plot" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
             f'viewBox="0 0 {width} {height}" role="img" aria-label="{_e(name)} per {_e(x_label)}">',
             f'<title>{_e(name)}</title>',
             f'<text class="t" x="{ml}" y="14">{_e(name)}</text>']
    if not finite:
        parts.append(f'<text x="{ml + pw / 2:.1f}" y="{mt + ph / 2:.1f}" text-anchor="middle">no finite values</text>')
        parts.append("</svg>")
        return "".join(parts)
    lo, hi = min(finite), max(finite)
    if hi == lo:
        pad = abs(hi) * 0.1 or 1.0
        lo, hi = lo - pad, hi + pad
    else:
        lo = min(lo, 0.0) if lo >= 0 and lo < (hi - lo) * 0.5 else lo
    n = len(vals)
    xmax = max(n - 1, 1)

    def X(i: float) -> float:
        return ml + pw * (i / xmax)

    span = hi / 2 - lo / 2  # halves: no overflow even when hi - lo exceeds the float range
    scaled = math.isfinite(span) and span > 0

    def Y(v: float) -> float:
        return mt + ph * (1 - (v / 2 - lo / 2) / span) if scaled else mt + ph / 2
    # axes and grid
    parts.append(f'<line x1="{ml}" y1="{mt}" x2="{ml}" y2="{mt + ph}" stroke="#57606a"/>')
    parts.append(f'<line x1="{ml}" y1="{mt + ph}" x2="{ml + pw}" y2="{mt + ph}" stroke="#57606a"/>')
    for t in (_nice_ticks(lo, hi) if scaled else []):
        if lo <= t <= hi:
            y = Y(t)
            parts.append(f'<line x1="{ml}" y1="{y:.1f}" x2="{ml + pw}" y2="{y:.1f}" stroke="#eaeef2"/>')
            parts.append(f'<text x="{ml - 4}" y="{y + 3.5:.1f}" text-anchor="end">{_e(f"{t:.4g}")}</text>')
    for t in _nice_ticks(0, xmax):
        if float(t).is_integer() and 0 <= t <= xmax:
            x = X(t)
            parts.append(f'<line x1="{x:.1f}" y1="{mt + ph}" x2="{x:.1f}" y2="{mt + ph + 4}" stroke="#57606a"/>')
            parts.append(f'<text x="{x:.1f}" y="{mt + ph + 15}" text-anchor="middle">{int(t)}</text>')
    parts.append(f'<text x="{ml + pw / 2:.1f}" y="{height - 3}" text-anchor="middle">{_e(x_label)}</text>')
    # the curve (decimated to at most ~2 points per pixel column)
    stride = max(1, n // (2 * pw))
    segs: list[list[str]] = [[]]
    for i in range(0, n, stride):
        v = vals[i]
        if math.isfinite(v):
            segs[-1].append(f"{X(i):.1f},{Y(v):.1f}")
        elif segs[-1]:
            segs.append([])
    for seg in segs:
        if len(seg) > 1:
            parts.append(f'<polyline fill="none" stroke="#cf222e" stroke-width="1.5" points="{" ".join(seg)}"/>')
        elif len(seg) == 1:
            x, y = seg[0].split(",")
            parts.append(f'<circle cx="{x}" cy="{y}" r="2.5" fill="#cf222e"/>')
    parts.append(f'<text x="{ml + pw}" y="14" text-anchor="end">max {_e(f"{max(finite):.4g}")}, '
                 f'{len(finite)} of {n} frames</text>')
    parts.append("</svg>")
    return "".join(parts)


def _rel_href(path: Path, out_dir: Path) -> str:
    from urllib.parse import quote
    rel = os.path.relpath(path, out_dir)
    return quote(Path(rel).as_posix())


def _place_artefact(src: str, out_dir: Path, base_dir: Path, tag: str) -> tuple[str | None, str]:
    """Return (href relative to out_dir or None when missing, display name) for one artefact,
    copying it into ``out_dir/artefacts/`` when it does not already lie inside ``out_dir``."""
    try:
        p = Path(src)
        full = (p if p.is_absolute() else base_dir / p).resolve()
        if not full.is_file():
            return None, src
    except (OSError, ValueError):  # unreadable, or not a possible path (NUL byte...)
        return None, src
    out_res = out_dir.resolve()
    if full.is_relative_to(out_res):
        return _rel_href(full, out_res), src
    if full.suffix.lower() not in _COPY_EXT:  # never copy arbitrary files into a shareable report
        return None, src
    digest = hashlib.sha256(str(full).encode("utf-8", "surrogatepass")).hexdigest()[:10]
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", f"{tag}-{full.stem}")[:80]
    ext = full.suffix.lower() if re.fullmatch(r"\.[A-Za-z0-9]{1,8}", full.suffix) else ""
    dst = out_res / "artefacts" / f"{safe}-{digest}{ext}"
    if not dst.is_file() or dst.stat().st_size != full.stat().st_size:
        atomic_write_bytes(dst, full.read_bytes())
    return _rel_href(dst, out_res), src


def _artefact_groups(artefacts: dict[str, str]) -> list[tuple[str, list[str]]]:
    """Artefact keys grouped into triplets: ``frame3_expected``/``frame3_got``/``frame3_diff`` form
    the group ``frame3`` (shown expected, got, diff); other keys form the unnamed group."""
    groups: dict[str, list[str]] = {}
    for k in artefacts:
        prefix, sep, kind = k.rpartition("_")
        groups.setdefault(prefix if sep and kind in _ARTEFACT_ORDER else "", []).append(k)
    out = []
    for g, keys in groups.items():
        def rank(k: str) -> int:
            kind = k.rpartition("_")[2] if g else k
            return _ARTEFACT_ORDER.index(kind) if kind in _ARTEFACT_ORDER else len(_ARTEFACT_ORDER)
        out.append((g, sorted(keys, key=rank)))
    out.sort(key=lambda t: t[0] == "")  # named triplets first, then the rest (stable)
    return out


def _diff_table(d: dict) -> str:
    rows = []
    keys = [k for k in d if k not in ("expected", "got")]
    for k in keys:
        rows.append(f"<tr><th>{_e(k)}</th><td class='mono' colspan='2'>{_e(_fmt_value(d[k]))}</td></tr>")
    if "expected" in d or "got" in d:
        rows.append("<tr><th></th><th>expected</th><th>got</th></tr>")
        rows.append(f"<tr><th>value</th><td class='mono'>{_e(_fmt_value(d.get('expected', '')))}</td>"
                    f"<td class='mono'>{_e(_fmt_value(d.get('got', '')))}</td></tr>")
    return "<table class='diff'><caption class='muted'>first difference</caption>" + "".join(rows) + "</table>"


def _case_html(r: CaseResult, out_dir: Path, base_dir: Path) -> str:
    o = r.outcome.value
    h = [f"<section class='case k-{o}' id='case-{_e(_anchor(r.case_id))}'>",
         f"<h3><span class='badge o-{o}'>{_e(o)}</span> <span class='mono'>{_e(r.case_id)}</span>"]
    if not r.required:
        h.append("<span class='tag'>optional</span>")
    if r.baseline:
        h.append(f"<span class='tag'>baseline: {_e(r.baseline)}</span>")
    h.append(f"<span class='tag'>{_e(r.claim)}</span><span class='tag'>{_e(f'{r.duration_s:.2f}')} s</span></h3>")
    if r.message:
        h.append(f"<pre class='msg'>{_e(r.message)}</pre>")
    diff = r.first_difference
    if diff:
        h.append(_diff_table(diff))
    for st in r.stages:
        h.append(f"<div class='stage'><b>stage {_e(st.stage)}</b> <span class='badge o-{st.outcome.value}'>"
                 f"{_e(st.outcome.value)}</span>")
        if st.message and st.message != r.message:
            h.append(f" <span>{_e(st.message)}</span>")
        h.append("</div>")
        if st.metrics:
            h.append("<table class='metrics'><tr>" + "".join(f"<th>{_e(k)}</th>" for k in st.metrics) + "</tr><tr>"
                     + "".join(f"<td class='num mono'>{_e(_fmt_value(v))}</td>" for v in st.metrics.values())
                     + "</tr></table>")
        if st.first_difference and st.first_difference is not diff:
            h.append(_diff_table(st.first_difference))
        for group, keys in _artefact_groups(st.artefacts):
            figs = [f"<div class='glabel muted'>{_e(group)}</div>"] if group else []
            for k in keys:
                href, shown = _place_artefact(str(st.artefacts[k]), out_dir, base_dir, f"{r.case_id}-{st.stage}-{k}")
                if href is None:
                    figs.append(f"<figure><figcaption>{_e(k)}: missing<br><span class='mono'>{_e(shown)}</span>"
                                f"</figcaption></figure>")
                elif Path(shown).suffix.lower() in _IMG_EXT:
                    figs.append(f"<figure><a href='{_e(href)}'><img src='{_e(href)}' alt='{_e(k)}' loading='lazy'>"
                                f"</a><figcaption>{_e(k)}</figcaption></figure>")
                else:
                    figs.append(f"<figure><figcaption><a href='{_e(href)}'>{_e(k)}: {_e(Path(shown).name)}</a>"
                                f"</figcaption></figure>")
            h.append("<div class='images'>" + "".join(figs) + "</div>")
        if st.series:
            h.append("<div class='plots'>" + "".join(svg_plot(f"{st.stage}: {k}", v) for k, v in st.series.items())
                     + "</div>")
    extra = []
    if r.command:
        extra.append(f"<tr><th>command</th><td class='mono'>{_e(shlex.join(str(a) for a in r.command))}</td></tr>")
    if r.exit_code is not None or r.signal:
        extra.append(f"<tr><th>exit</th><td class='mono'>{_e(r.exit_code)}"
                     + (f", signal {_e(r.signal)}" if r.signal else "") + "</td></tr>")
    if extra:
        h.append("<table class='meta'>" + "".join(extra) + "</table>")
    if r.stderr_tail:
        h.append(f"<details><summary>stderr (tail)</summary><pre>{_e(r.stderr_tail)}</pre></details>")
    h.append("</section>")
    return "".join(h)


def _anchor(case_id: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "-", case_id).strip("-") + "-" + hashlib.sha1(
        case_id.encode("utf-8", "surrogatepass")).hexdigest()[:6]


def _counts_table_html(title: str, groups: dict[str, dict[str, int]], order: list[str], total: dict[str, int]) -> str:
    h = [f"<table class='counts'><tr><th>{_e(title)}</th>"]
    h += [f"<th class='num'>{_e(o.value)}</th>" for o in COLUMNS] + ["<th class='num'>total</th></tr>"]

    def row(name, c, cls=""):
        cells = [f"<tr{cls}><td>{_e(name)}</td>"]
        for o in COLUMNS:
            n = c.get(o.value, 0)
            cells.append(f"<td class='num {'c-' + o.value if n else 'zero'}'>{n}</td>")
        cells.append(f"<td class='num'>{sum(c.values())}</td></tr>")
        return "".join(cells)
    for name in order:
        h.append(row(name, groups.get(name, {})))
    h.append(row("total", total, " class='total'"))
    h.append("</table>")
    return "".join(h)


def _kv_table(d: dict) -> str:
    rows = []
    for k, v in d.items():
        if isinstance(v, dict):
            v = ", ".join(f"{kk} {vv}" for kk, vv in v.items())
        rows.append(f"<tr><td>{_e(k)}</td><td class='mono'>{_e(v)}</td></tr>")
    return "<table class='meta'>" + "".join(rows) + "</table>"


def html_report(record: RunRecord, out_dir, *, base_dir=None) -> str:
    """The page written by :func:`write_html` (artefacts outside ``out_dir`` are copied as a side effect)."""
    out_dir = Path(out_dir)
    base_dir = Path(base_dir) if base_dir is not None else out_dir
    dec = record.decoder or {}
    v = verdict(record)
    title = f"fbaconf run: {clean_text(dec.get('name', '?'))}" + (f" ({clean_text(record.claim)})" if record.claim else "")
    h = ["<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>",
         "<meta name='viewport' content='width=device-width, initial-scale=1'>",
         "<meta http-equiv='Content-Security-Policy' content=\"default-src 'none'; style-src 'unsafe-inline'; "
         "img-src 'self' file: data:\">",
         "<link rel='icon' href='data:,'>",
         f"<title>{_e(title)}</title><style>{_CSS}</style></head><body>"]
    h.append(f"<h1>{_e(title)} <span class='badge verdict v-{v.split()[0]}'>{_e(v)}</span></h1>")
    h.append(f"<p class='muted'>{_e(_summary_counts(record.counts()) + _speed_summary(record.speed))}; "
             f"exit code {_e(record.exit_code)}</p>")
    # header: decoder, run, suites, system, provisional
    run_meta = {"decoder": dec.get("name"), "kind": dec.get("kind"),
                "manifest sha256": dec.get("manifest_sha256"),
                "decoder claims": ", ".join(map(str, dec.get("claims") or [])) or None,
                "inputs / outputs": (", ".join(map(str, dec.get("inputs") or [])) + " \u2192 "
                                     + ", ".join(map(str, dec.get("outputs") or []))) if dec.get("inputs") or dec.get("outputs") else None,
                "claim under test": record.claim, "started": record.started, "finished": record.finished,
                "duration": f"{record.duration_s:.1f} s" if record.duration_s else None}
    h.append("<h2>Run</h2>" + _kv_table({k: val for k, val in run_meta.items() if val not in (None, "")}))
    if record.suites:
        h.append("<table><tr><th>suite</th><th>version</th><th>sha256</th><th class='num'>cases</th></tr>")
        for s in record.suites:
            n = s.get("cases")
            n = len(n) if isinstance(n, (list, tuple)) else n
            h.append(f"<tr><td>{_e(s.get('name'))}</td><td>{_e(s.get('version', ''))}</td>"
                     f"<td class='mono'>{_e(s.get('sha256', ''))}</td><td class='num'>{_e('' if n is None else n)}</td></tr>")
        h.append("</table>")
    if record.system:
        h.append("<details><summary>System</summary>" + _kv_table(record.system) + "</details>")
    if record.provisional:
        h.append("<h2>Provisional rules and limits</h2><p class='muted'>This run depends on readings of the "
                 "standard that are provisional (not confirmed against the ISO text):</p><ul class='prov'>"
                 + "".join(f"<li>{_e(p)}</li>" for p in record.provisional) + "</ul>")
    # summary
    total = record.counts()
    h.append("<h2>Summary</h2>")
    h.append(_counts_table_html("suite", _by(record, lambda r: r.suite), _suite_names(record), total))
    by_profile = _by(record, lambda r: profile_of(r.claim))
    if len(by_profile) > 1:
        h.append(_counts_table_html("profile", by_profile, sorted(by_profile), total))
    # problem cases
    problems = _problem_cases(record)
    if problems:
        h.append(f"<h2>Failures and warnings ({len(problems)})</h2>")
        h.extend(_case_html(r, out_dir, base_dir) for r in problems)
    # speed
    if record.speed:
        h.append("<h2>Speed</h2><table><tr><th>operation</th><th>claim</th><th class='num'>measured fps</th>"
                 "<th class='num'>required fps</th><th>verdict</th><th>provenance</th><th class='num'>per frame s</th>"
                 "<th class='num'>startup s</th><th class='num'>fit r\u00b2</th><th>message</th></tr>")
        for s, row in zip(record.speed, _speed_rows(record.speed)):
            cls = "c-Pass" if s.passed else "c-Fail"
            h.append(f"<tr><td>{_e(row[0])}</td><td>{_e(row[1])}</td><td class='num'>{_e(row[2])}</td>"
                     f"<td class='num'>{_e(row[3])}</td><td class='{cls}'>{_e(row[4])}</td><td>{_e(row[5])}</td>"
                     f"<td class='num'>{_e(_fmt_value(s.per_frame_s))}</td><td class='num'>{_e(_fmt_value(s.startup_s))}</td>"
                     f"<td class='num'>{_e(f'{s.fit_r2:.4f}')}</td><td>{_e(s.message)}</td></tr>")
        h.append("</table>")
    # the rest, compact
    listed = {id(r) for r in problems}
    rest = [r for r in record.results if id(r) not in listed]
    for label, outs in (("Passing cases", (Outcome.PASS,)),
                        ("Not supported and skipped cases", (Outcome.NOT_SUPPORTED, Outcome.SKIPPED))):
        rows = [r for r in rest if r.outcome in outs]
        if not rows:
            continue
        h.append(f"<details><summary>{_e(label)} ({len(rows)})</summary><table><tr><th>case</th><th>outcome</th>"
                 "<th>claim</th><th class='num'>time s</th><th>note</th></tr>")
        for r in rows:
            note = "; ".join(x for x in (r.message, f"baseline: {r.baseline}" if r.baseline else "",
                                         "" if r.required else "optional") if x)
            h.append(f"<tr><td class='mono'>{_e(r.case_id)}</td><td class='c-{r.outcome.value}'>{_e(r.outcome.value)}"
                     f"</td><td>{_e(r.claim)}</td><td class='num'>{_e(f'{r.duration_s:.2f}')}</td>"
                     f"<td>{_e(note)}</td></tr>")
        h.append("</table></details>")
    from fbaconf import __version__
    h.append(f"<footer>fbaconf {_e(__version__)} \u00b7 report format fbaconf.run/1 \u00b7 "
             f"{_e((record.system or {}).get('timestamp_utc', record.finished))}</footer>")
    h.append("</body></html>\n")
    return "\n".join(h)


def write_html(record: RunRecord, out_dir, *, base_dir=None) -> Path:
    """Write ``out_dir/index.html``, one self-contained page (inline CSS and SVG, no script).

    Artefact paths are relative to ``base_dir`` (default ``out_dir``, the run's output
    folder) or absolute; images not already inside ``out_dir`` are copied into
    ``out_dir/artefacts/`` so that every link is relative. Returns the page's path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    page = out_dir / "index.html"
    atomic_write_text(page, html_report(record, out_dir, base_dir=base_dir))
    return page
