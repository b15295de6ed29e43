"""JUnit XML for CI systems (ElementTree, no extra dependency), agreeing with the run's exit code."""

from __future__ import annotations

import json
import math
import os
import shlex
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from xml.etree import ElementTree as ET

from fbaconf._atomic import atomic_write_bytes
from fbaconf.harness.results import CaseResult, Outcome, RunRecord

from .common import _fmt_value, _suite_names, clean_text, format_difference, verdict
from .jsonreport import jsonable


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
    return s if len(s) <= limit else s[: limit - 1] + "\u2026"


def _properties(parent: ET.Element, props: list[tuple[str, Any]]) -> None:
    el = ET.SubElement(parent, "properties")
    for name, value in props:
        if isinstance(value, (dict, list)):
            value = json.dumps(jsonable(value), sort_keys=True, ensure_ascii=False)
        ET.SubElement(el, "property", name=clean_text(name), value=clean_text("" if value is None else value))


@dataclass
class _Tally:
    """A <testsuite>'s (or the whole run's) counts and time."""

    tests: int = 0
    failures: int = 0
    errors: int = 0
    skipped: int = 0
    time: float = 0.0

    def add(self, other: _Tally) -> None:
        self.tests += other.tests
        self.failures += other.failures
        self.errors += other.errors
        self.skipped += other.skipped
        self.time += other.time


def _close_suite(ts: ET.Element, c: _Tally, record: RunRecord) -> None:
    """A <testsuite>'s counts, time and timestamp from its counter ``c``."""
    ts.set("tests", str(c.tests))
    for k in ("failures", "errors", "skipped"):
        ts.set(k, str(getattr(c, k)))
    ts.set("time", _sec(c.time))
    if record.started:
        ts.set("timestamp", clean_text(record.started))


def junit_xml(record: RunRecord) -> bytes:
    """The JUnit XML document written by :func:`write_junit`."""
    dec = record.decoder or {}
    common = [
        ("decoder", dec.get("name")),
        ("decoder.manifest_sha256", dec.get("manifest_sha256")),
        ("claim", record.claim),
        ("exit_code", record.exit_code),
        ("verdict", verdict(record)),
    ]
    if record.baseline_summary:  # "N new, N known, N fixed, N flaky"
        common.append(("baseline", record.baseline_summary))
    common += [(f"provisional.{i}", p) for i, p in enumerate(record.provisional)]
    common += [(f"system.{k}", v) for k, v in (record.system or {}).items()]
    suite_meta = {str(s.get("name")): s for s in record.suites}
    root = ET.Element("testsuites", name=clean_text(f"fbaconf {dec.get('name', '')}".strip()))
    totals = _Tally()
    for name in _suite_names(record):
        cases = [r for r in record.results if r.suite == name]
        c = _Tally()
        ts = ET.SubElement(root, "testsuite", name=clean_text(name))
        meta = suite_meta.get(name, {})
        _properties(ts, common + [(f"suite.{k}", v) for k, v in meta.items() if k != "name"])
        for r in cases:
            tc = ET.SubElement(
                ts,
                "testcase",
                classname=clean_text(f"fbaconf.{r.suite}"),
                name=clean_text(r.case_id),
                time=_sec(r.duration_s),
            )
            o = r.outcome
            msg = _one_line(("new: " if r.baseline == "new" else "") + (r.message or o.value))
            excused = r.baseline in ("known-failure", "flake") and not o.ok
            if excused:
                # agrees with the exit code: a known failure or a flake does not fail the run
                el = ET.SubElement(tc, "skipped", message=_one_line(f"{r.baseline} ({o.value}): {r.message}"))
                el.text = _case_details(r)
                c.skipped += 1
            elif r.baseline == "fixed":
                el = ET.SubElement(
                    tc,
                    "failure",
                    message=_one_line(
                        "fixed: the baseline lists this case as failing but it passes now: remove the line"
                    ),
                    type="BaselineFixed",
                )
                c.failures += 1
            elif o is Outcome.NOT_SUPPORTED and r.required:
                el = ET.SubElement(
                    tc,
                    "failure",
                    message=_one_line(
                        ("new: " if r.baseline == "new" else "") + f"required by the claim but not supported: "
                        f"{r.message}"
                    ),
                    type=o.value,
                )
                c.failures += 1
            elif o in (Outcome.FAIL, Outcome.TIMEOUT, Outcome.CRASH):
                el = ET.SubElement(tc, "failure", message=msg, type=o.value)
                el.text = _case_details(r)
                c.failures += 1
            elif o is Outcome.ERROR:
                el = ET.SubElement(tc, "error", message=msg, type=o.value)
                el.text = _case_details(r)
                c.errors += 1
            elif o in (Outcome.NOT_SUPPORTED, Outcome.SKIPPED):
                el = ET.SubElement(
                    tc, "skipped", message=_one_line(f"{o.value}: {r.message}" if r.message else o.value)
                )
                c.skipped += 1
            elif o is Outcome.QUALITY_WARNING:
                ET.SubElement(tc, "system-out").text = "QualityWarning (passes): " + _case_details(r)
            elif r.baseline:
                ET.SubElement(tc, "system-out").text = clean_text(f"baseline: {r.baseline}")
            c.tests += 1
            c.time += r.duration_s if math.isfinite(r.duration_s) and r.duration_s > 0 else 0.0
        _close_suite(ts, c, record)
        totals.add(c)
    if record.speed:
        ts = ET.SubElement(root, "testsuite", name="speed")
        c = _Tally()
        _properties(ts, common)
        for s in record.speed:
            t = sum(float(x.get("seconds", 0.0)) for x in s.samples if isinstance(x, dict))
            tc = ET.SubElement(
                ts, "testcase", classname="fbaconf.speed", name=clean_text(f"{s.operation} {s.claim}"), time=_sec(t)
            )
            text = (
                f"{s.operation}: {s.rate_fps:.2f} fps measured, {s.required_fps:.2f} fps required "
                f"(provenance: {s.provenance}); per frame {s.per_frame_s:.6g} s, startup {s.startup_s:.6g} s, "
                f"fit r2 {s.fit_r2:.4f}" + (f"\n{s.message}" if s.message else "")
            )
            if s.verdict == "inconclusive":  # the lab's load, not the decoder's speed: no failure
                el = ET.SubElement(
                    tc,
                    "skipped",
                    message=_one_line(
                        f"{s.operation} speed inconclusive: {s.rate_fps:.2f} fps measured on a busy machine "
                        f"({s.required_fps:.2f} fps required); measure again on a quiet one"
                    ),
                )
                el.text = clean_text(text + (f"\n{s.reason}" if s.reason else ""))
                c.skipped += 1
            elif not s.passed:
                below = s.rate_fps < s.required_fps
                el = ET.SubElement(
                    tc,
                    "failure",
                    type="SpeedBelowMinimum" if below else "SpeedMeasurementFailed",
                    message=_one_line(
                        f"{s.operation} {s.rate_fps:.2f} fps below the required "
                        f"{s.required_fps:.2f} fps ({s.provenance})"
                        if below
                        else f"{s.operation}: {s.message or 'the speed measurement failed'}"
                    ),
                )
                el.text = clean_text(text)
                c.failures += 1
            else:
                ET.SubElement(tc, "system-out").text = clean_text(text)
            c.tests += 1
            c.time += t
        _close_suite(ts, c, record)
        totals.add(c)
    root.set("tests", str(totals.tests))
    for k in ("failures", "errors", "skipped"):
        root.set(k, str(getattr(totals, k)))
    root.set("time", _sec(record.duration_s if record.duration_s else totals.time))
    ET.indent(root)
    xml: bytes = ET.tostring(root, encoding="utf-8", xml_declaration=True)
    return xml + b"\n"


def write_junit(record: RunRecord, path: str | os.PathLike[str]) -> Path:
    """Write the run as JUnit XML (one ``<testsuite>`` per suite plus ``speed``), atomically."""
    out = Path(path)
    atomic_write_bytes(out, junit_xml(record))
    return out
