"""One self-contained HTML page (CSS from harness/data/report.css inlined, SVG plots, no script)."""

from __future__ import annotations

import hashlib
import html
import math
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any
from urllib.parse import quote

from fbaconf import __version__
from fbaconf._atomic import atomic_write_bytes, atomic_write_text
from fbaconf.harness.results import CaseResult, Outcome, RunRecord
from fbaconf.harness.verdict import describe

from .common import (
    DISPLAY_COLUMNS,
    NS_REQUIRED,
    _by,
    _fmt_value,
    _speed_rows,
    _speed_summary,
    _suite_names,
    _summary_counts,
    baseline_changes,
    clean_text,
    display_counts,
    failure_groups,
    profile_of,
    reproduce_line,
    verdict,
    verdict_reason,
)


def _e(value: Any) -> str:
    """Escape anything for HTML text or a quoted attribute."""
    return html.escape(clean_text("" if value is None else value), quote=True)


def _css() -> str:
    """The page's style sheet (harness/data/report.css), inlined so the page stands alone."""
    return resources.files("fbaconf.harness").joinpath("data", "report.css").read_text("utf-8")


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
    ticks: list[float] = []
    t = start
    while t <= hi + step * 1e-9 and len(ticks) < 20:
        ticks.append(round(t, 12))
        t += step
    return ticks


def svg_plot(name: str, values: list[float], *, width: int = 380, height: int = 170, x_label: str = "frame") -> str:
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
    parts = [
        f'<svg class="plot" xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" role="img" aria-label="{_e(name)} per {_e(x_label)}">',
        f"<title>{_e(name)}</title>",
        f'<text class="t" x="{ml}" y="14">{_e(name)}</text>',
    ]
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
    for t in _nice_ticks(lo, hi) if scaled else []:
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
            cx, cy = seg[0].split(",")
            parts.append(f'<circle cx="{cx}" cy="{cy}" r="2.5" fill="#cf222e"/>')
    parts.append(
        f'<text x="{ml + pw}" y="14" text-anchor="end">max {_e(f"{max(finite):.4g}")}, '
        f"{len(finite)} of {n} frames</text>"
    )
    parts.append("</svg>")
    return "".join(parts)


def _rel_href(path: Path, out_dir: Path) -> str:
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


def _diff_table(d: dict[str, Any]) -> str:
    rows = []
    keys = [k for k in d if k not in ("expected", "got")]
    for k in keys:
        rows.append(f"<tr><th>{_e(k)}</th><td class='mono' colspan='2'>{_e(_fmt_value(d[k]))}</td></tr>")
    if "expected" in d or "got" in d:
        rows.append("<tr><th></th><th>expected</th><th>got</th></tr>")
        rows.append(
            f"<tr><th>value</th><td class='mono'>{_e(_fmt_value(d.get('expected', '')))}</td>"
            f"<td class='mono'>{_e(_fmt_value(d.get('got', '')))}</td></tr>"
        )
    return "<table class='diff'><caption class='muted'>first difference</caption>" + "".join(rows) + "</table>"


def _case_html(r: CaseResult, out_dir: Path, base_dir: Path, env: dict[str, Any] | None = None) -> str:
    o = r.outcome.value
    h = [
        f"<section class='case k-{o}' id='case-{_e(_anchor(r.case_id))}'>",
        f"<h3><span class='badge o-{o}'>{_e(o)}</span> <span class='mono'>{_e(r.case_id)}</span>",
    ]
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
        h.append(
            f"<div class='stage'><b>stage {_e(st.stage)}</b> <span class='badge o-{st.outcome.value}'>"
            f"{_e(st.outcome.value)}</span>"
        )
        if st.message and st.message != r.message:
            h.append(f" <span>{_e(st.message)}</span>")
        h.append("</div>")
        if st.metrics:
            h.append(
                "<table class='metrics'><tr>"
                + "".join(f"<th>{_e(k)}</th>" for k in st.metrics)
                + "</tr><tr>"
                + "".join(f"<td class='num mono'>{_e(_fmt_value(v))}</td>" for v in st.metrics.values())
                + "</tr></table>"
            )
        if st.first_difference and st.first_difference is not diff:
            h.append(_diff_table(st.first_difference))
        for group, keys in _artefact_groups(st.artefacts):
            figs = [f"<div class='glabel muted'>{_e(group)}</div>"] if group else []
            for k in keys:
                href, shown = _place_artefact(str(st.artefacts[k]), out_dir, base_dir, f"{r.case_id}-{st.stage}-{k}")
                if href is None:
                    figs.append(
                        f"<figure><figcaption>{_e(k)}: missing<br><span class='mono'>{_e(shown)}</span>"
                        f"</figcaption></figure>"
                    )
                elif Path(shown).suffix.lower() in _IMG_EXT:
                    figs.append(
                        f"<figure><a href='{_e(href)}'><img src='{_e(href)}' alt='{_e(k)}' loading='lazy'>"
                        f"</a><figcaption>{_e(k)}</figcaption></figure>"
                    )
                else:
                    figs.append(
                        f"<figure><figcaption><a href='{_e(href)}'>{_e(k)}: {_e(Path(shown).name)}</a>"
                        f"</figcaption></figure>"
                    )
            h.append("<div class='images'>" + "".join(figs) + "</div>")
        if st.series:
            h.append(
                "<div class='plots'>"
                + "".join(svg_plot(f"{st.stage}: {k}", v) for k, v in st.series.items())
                + "</div>"
            )
    extra = []
    if r.command:
        extra.append(f"<tr><th>reproduce</th><td class='mono'>{_e(reproduce_line(r, env=env))}</td></tr>")
    if r.exit_code is not None or r.signal:
        extra.append(
            f"<tr><th>exit</th><td class='mono'>{_e(r.exit_code)}"
            + (f", signal {_e(r.signal)}" if r.signal else "")
            + "</td></tr>"
        )
    if extra:
        h.append("<table class='meta'>" + "".join(extra) + "</table>")
    if r.stderr_tail:
        h.append(f"<details><summary>stderr (tail)</summary><pre>{_e(r.stderr_tail)}</pre></details>")
    h.append("</section>")
    return "".join(h)


def _anchor(case_id: str) -> str:
    return (
        re.sub(r"[^A-Za-z0-9_-]+", "-", case_id).strip("-")
        + "-"
        + hashlib.sha1(case_id.encode("utf-8", "surrogatepass"), usedforsecurity=False).hexdigest()[:6]
    )


def _counts_table_html(title: str, groups: dict[str, dict[str, int]], order: list[str], total: dict[str, int]) -> str:
    h = [f"<table class='counts'><tr><th>{_e(title)}</th>"]
    h += [f"<th class='num'>{_e(c)}</th>" for c in DISPLAY_COLUMNS] + ["<th class='num'>total</th></tr>"]

    def row(name: str, c: dict[str, int], cls: str = "") -> str:
        cells = [f"<tr{cls}><td>{_e(name)}</td>"]
        for col in DISPLAY_COLUMNS:
            n = c.get(col, 0)
            css = "c-NotSupportedRequired" if col == NS_REQUIRED else f"c-{col}"
            cells.append(f"<td class='num {css if n else 'zero'}'>{n}</td>")
        cells.append(f"<td class='num'>{sum(c.values())}</td></tr>")
        return "".join(cells)

    for name in order:
        h.append(row(name, groups.get(name, {})))
    h.append(row("total", total, " class='total'"))
    h.append("</table>")
    return "".join(h)


def _kv_table(d: dict[str, Any]) -> str:
    rows = []
    for k, v in d.items():
        if isinstance(v, dict):
            v = ", ".join(f"{kk} {vv}" for kk, vv in v.items())
        rows.append(f"<tr><td>{_e(k)}</td><td class='mono'>{_e(v)}</td></tr>")
    return "<table class='meta'>" + "".join(rows) + "</table>"


def _baseline_html(record: RunRecord) -> str:
    """``Baseline: N new, N known, N fixed, N flaky`` and the cases that fail the run against it, by name."""
    if not record.baseline_summary:
        return ""
    new, fixed = baseline_changes(record)
    items = [
        f"<li><b>new</b> <a class='mono' href='#case-{_e(_anchor(r.case_id))}'>{_e(r.case_id)}</a> "
        f"{_e(r.outcome.value)}</li>"
        for r in new
    ]
    items += [
        f"<li><b>fixed</b> <span class='mono'>{_e(r.case_id)}</span>: passes now, listed as failing: remove "
        f"its line from the baseline (or --allow-fixed)</li>"
        for r in fixed
    ]
    return (
        f"<div class='card'><b>Baseline</b>: {_e(record.baseline_summary)}"
        + (f"<ul>{''.join(items)}</ul>" if items else "")
        + "</div>"
    )


def _provisional_differences_html(record: RunRecord) -> str:
    """The failing cases whose expected output rests on a provisional decision (conformance/provisional.py)."""
    diffs = record.provisional_differences
    if not diffs:
        return ""
    how = "they fail the claim (--strict)" if record.strict else "the claim passes with them; --strict fails them"
    return (
        f"<div class='card'><b>Provisional differences ({len(diffs)})</b>: cases judged by an other reading "
        f"the decoder declares (bitstreams/data/readings.toml); {_e(how)}<ul>"
        + "".join(
            f"<li><span class='mono'>{_e(d.get('case_id', ''))}</span> rests on "
            f"{_e(', '.join(map(str, d.get('rests_on', []))))}; judged by {_e(d.get('reading'))}</li>"
            for d in diffs
        )
        + "</ul></div>"
    )


def _causes_html(causes: dict[str, Any]) -> str:
    """The root causes ``fbaconf explain`` found (its JSON: headline, causes), ranked."""
    h = [f"<h2>Root causes</h2><p>{_e(causes.get('headline', ''))}</p><ol class='causes'>"]
    for c in causes.get("causes", []):
        conf = c.get("confirmed")
        proof = (
            f"confirmed: {conf['case_id']} {conf['edit']} — {conf['outcome']}" if conf else "not confirmed by a variant"
        )
        if conf and conf.get("also"):
            proof += f" (the variant also lacks {', '.join(conf['also'])}: the edit does not tell them apart)"
        h.append(
            f"<li><b>{_e(c.get('what', ''))}</b> <span class='mono'>{_e(c.get('feature', ''))}</span>"
            f" — {_e(len(c.get('cases', [])))} case(s); {_e(c.get('concerns', ''))}<br>"
            f"<span class='muted'>{_e(proof)}; first divergence: {_e('; '.join(c.get('divergences', [])))}</span>"
            f"<details><summary>cases</summary><p class='mono'>{_e(', '.join(c.get('cases', [])))}</p></details></li>"
        )
    h.append("</ol>")
    return "".join(h)


def _badge_class(v: str) -> str:
    """PASS green, a pass with what it leaves out (unverified tools, provisional differences) and
    the speed verdicts amber, FAIL and SETUP ERROR red."""
    if v.startswith("PASS ("):
        return "v-PASSQ"
    return f"v-{v.split()[0]}"


def html_report(
    record: RunRecord,
    out_dir: Path,
    *,
    base_dir: Path | None = None,
    heading: str = "fbaconf run",
    causes: dict[str, Any] | None = None,
) -> str:
    """The page written by :func:`write_html` (artefacts outside ``out_dir`` are copied as a side effect)."""
    out_dir = Path(out_dir)
    base_dir = Path(base_dir) if base_dir is not None else out_dir
    dec = record.decoder or {}
    v = verdict(record)
    title = f"{heading}: {clean_text(dec.get('name', '?'))}" + (
        f" ({clean_text(record.claim)})" if record.claim else ""
    )
    h = [
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>",
        "<meta name='viewport' content='width=device-width, initial-scale=1'>",
        "<meta http-equiv='Content-Security-Policy' content=\"default-src 'none'; style-src 'unsafe-inline'; "
        "img-src 'self' file: data:\">",
        "<link rel='icon' href='data:,'>",
        f"<title>{_e(title)}</title><style>{_css()}</style></head><body>",
    ]
    reason = verdict_reason(record)
    h.append(
        f"<h1>{_e(title)}</h1><p class='verdict-line'><span class='badge verdict {_badge_class(v)}'>{_e(v)}"
        f"</span>" + (f" <span class='reason'>{_e(reason)}</span>" if reason else "") + "</p>"
    )
    h.append(
        f"<p class='muted'>{_e(_summary_counts(display_counts(record.results)) + _speed_summary(record.speed))}"
        f"; exit code {_e(record.exit_code)}</p>"
    )
    if causes is not None:
        h.append(_causes_html(causes))
    # the summary table first, then what fails the run against its baseline, then the failures
    total = display_counts(record.results)
    h.append("<h2>Summary</h2>")
    h.append(_counts_table_html("suite", _by(record, lambda r: r.suite), _suite_names(record), total))
    by_profile = _by(record, lambda r: profile_of(r.claim))
    if len(by_profile) > 1:
        h.append(_counts_table_html("profile", by_profile, sorted(by_profile), total))
    h.append(_baseline_html(record))
    if record.missing:
        h.append(
            "<div class='card'><b>Required cases the decoder could not take</b> (each fails the claim, unless "
            "its tool is set aside as unverified below):<ul>"
            + "".join(f"<li>{_e(m)}</li>" for m in record.missing)
            + "</ul></div>"
        )
    detail = describe(record.verdict or {})
    if detail and record.claim:
        h.append(
            "<div class='card'><b>Tools and provisional decisions</b> (harness/verdict.py: verified, differs, "
            "declined, unverified or fails)<ul class='tools'>"
            + "".join(f"<li>{_e(x)}</li>" for x in detail)
            + "</ul></div>"
        )
    h.append(_provisional_differences_html(record))
    # identical failures grouped (one card, the other cases listed), new failures first
    groups = failure_groups(record)
    problems = [r for _o, rs in groups for r in rs]
    if groups:
        h.append(
            f"<h2>Failures and warnings ({len(problems)} case(s) in {len(groups)} group(s) of identical failures)</h2>"
        )
        for _o, rs in groups:
            h.append(_case_html(rs[0], out_dir, base_dir, dec.get("env")))
            if len(rs) > 1:
                h.append(
                    f"<p class='muted'>The same failure in {len(rs) - 1} more case(s): "
                    + ", ".join(
                        f"<span class='mono' id='case-{_e(_anchor(r.case_id))}'>{_e(r.case_id)}</span>" for r in rs[1:]
                    )
                    + "</p>"
                )
    # speed
    if record.speed:
        h.append(
            "<h2>Speed</h2><table><tr><th>operation</th><th>claim</th><th class='num'>measured fps</th>"
            "<th class='num'>required fps</th><th>verdict</th><th>provenance</th><th class='num'>per frame s</th>"
            "<th class='num'>startup s</th><th class='num'>fit r\u00b2</th><th>message</th></tr>"
        )
        for s, row in zip(record.speed, _speed_rows(record.speed)):
            cls = {"PASS": "c-Pass", "INCONCLUSIVE": "c-QualityWarning"}.get(row[4], "c-Fail")
            h.append(
                f"<tr><td>{_e(row[0])}</td><td>{_e(row[1])}</td><td class='num'>{_e(row[2])}</td>"
                f"<td class='num'>{_e(row[3])}</td><td class='{cls}'>{_e(row[4])}</td><td>{_e(row[5])}</td>"
                f"<td class='num'>{_e(_fmt_value(s.per_frame_s))}</td><td class='num'>{_e(_fmt_value(s.startup_s))}</td>"  # noqa: E501
                f"<td class='num'>{_e(f'{s.fit_r2:.4f}')}</td><td>{_e(s.message)}</td></tr>"
            )
        h.append("</table>")
    # header: decoder, run, suites, system, provisional
    run_meta = {
        "decoder": dec.get("name"),
        "kind": dec.get("kind"),
        "manifest sha256": dec.get("manifest_sha256"),
        "decoder claims": ", ".join(map(str, dec.get("claims") or [])) or None,
        "inputs / outputs": (
            ", ".join(map(str, dec.get("inputs") or [])) + " \u2192 " + ", ".join(map(str, dec.get("outputs") or []))
        )
        if dec.get("inputs") or dec.get("outputs")
        else None,
        "claim under test": record.claim,
        "started": record.started,
        "finished": record.finished,
        "duration": f"{record.duration_s:.1f} s" if record.duration_s else None,
    }
    h.append("<h2>Run</h2>" + _kv_table({k: val for k, val in run_meta.items() if val not in (None, "")}))
    if record.suites:
        h.append("<table><tr><th>suite</th><th>version</th><th>sha256</th><th class='num'>cases</th></tr>")
        for suite in record.suites:
            n = suite.get("cases")
            n = len(n) if isinstance(n, (list, tuple)) else n
            h.append(
                f"<tr><td>{_e(suite.get('name'))}</td><td>{_e(suite.get('version', ''))}</td>"
                f"<td class='mono'>{_e(suite.get('sha256', ''))}</td>"
                f"<td class='num'>{_e('' if n is None else n)}</td></tr>"
            )
        h.append("</table>")
    if record.system:
        h.append("<details><summary>System</summary>" + _kv_table(record.system) + "</details>")
    if record.provisional:
        h.append(
            f"<details><summary>Provisional rules and limits ({len(record.provisional)})</summary>"
            "<p class='muted'>This run depends on readings of the standard that are provisional (not "
            "confirmed against the ISO text):</p><ul class='prov'>"
            + "".join(f"<li>{_e(p)}</li>" for p in record.provisional)
            + "</ul></details>"
        )
    # the rest, compact
    listed = {id(r) for r in problems}
    rest = [r for r in record.results if id(r) not in listed]
    for label, outs in (
        ("Passing cases", (Outcome.PASS,)),
        ("Not supported and skipped cases", (Outcome.NOT_SUPPORTED, Outcome.SKIPPED)),
    ):
        rows = [r for r in rest if r.outcome in outs]
        if not rows:
            continue
        h.append(
            f"<details><summary>{_e(label)} ({len(rows)})</summary><table><tr><th>case</th><th>outcome</th>"
            "<th>claim</th><th class='num'>time s</th><th>note</th></tr>"
        )
        for r in rows:
            note = "; ".join(
                x
                for x in (r.message, f"baseline: {r.baseline}" if r.baseline else "", "" if r.required else "optional")
                if x
            )
            h.append(
                f"<tr><td class='mono'>{_e(r.case_id)}</td><td class='c-{r.outcome.value}'>{_e(r.outcome.value)}"
                f"</td><td>{_e(r.claim)}</td><td class='num'>{_e(f'{r.duration_s:.2f}')}</td>"
                f"<td>{_e(note)}</td></tr>"
            )
        h.append("</table></details>")
    h.append(
        f"<footer>fbaconf {_e(__version__)} \u00b7 report format fbaconf.run/1 \u00b7 "
        f"{_e((record.system or {}).get('timestamp_utc', record.finished))}</footer>"
    )
    h.append("</body></html>\n")
    return "\n".join(h)


def write_html(
    record: RunRecord,
    out_dir: str | os.PathLike[str],
    *,
    base_dir: Path | None = None,
    heading: str = "fbaconf run",
    causes: dict[str, Any] | None = None,
) -> Path:
    """Write ``out_dir/index.html``, one self-contained page (inline CSS and SVG, no script).

    Artefact paths are relative to ``base_dir`` (default ``out_dir``, the run's output
    folder) or absolute; images not already inside ``out_dir`` are copied into
    ``out_dir/artefacts/`` so that every link is relative. Returns the page's path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    page = out / "index.html"
    atomic_write_text(page, html_report(record, out, base_dir=base_dir, heading=heading, causes=causes))
    return page
