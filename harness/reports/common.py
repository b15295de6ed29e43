"""What every report format shares: text cleaning of untrusted strings, verdicts, difference formatting, the cases that need attention."""  # noqa: E501

from __future__ import annotations

import math
import re
import shlex
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from fbaconf.harness.baseline import signature
from fbaconf.harness.results import OUTCOME_ORDER, CaseResult, Outcome, RunRecord, SpeedResult

# Column order of the outcome tables (as the Outcome enum: Pass first, then the bad ones).

VERDICTS = {0: "PASS", 1: "FAIL", 2: "SETUP ERROR", 3: "SPEED FAIL", 4: "SPEED INCONCLUSIVE"}

# Non-finite floats are not JSON; they are written as these strings and read back.
_NONFINITE = {"Infinity": math.inf, "-Infinity": -math.inf, "NaN": math.nan}


_ANSI = re.compile(r"\x1b(?:\[[0-?]*[ -/]*[@-~]|\][^\x07\x1b]*(?:\x07|\x1b\\)?|[@-Z\\-_])")
# Characters XML 1.0 cannot hold, plus the other C0/C1 controls (kept out of every report).
_BAD_CHARS = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f\ud800-\udfff\ufffe\uffff]")


def clean_text(value: Any) -> str:
    """``value`` as text safe for a terminal, XML and HTML (before escaping): ANSI/OSC escape
    sequences removed, other control characters, lone surrogates and U+FFFE/U+FFFF shown as
    ``\\xNN``/``\\uNNNN``; newlines, tabs and carriage returns kept."""
    s = value if isinstance(value, str) else str(value)
    s = _ANSI.sub("", s)

    def esc(m: re.Match[str]) -> str:
        c = ord(m.group(0))
        return f"\\x{c:02x}" if c < 0x100 else f"\\u{c:04x}"

    return _BAD_CHARS.sub(esc, s)


def profile_of(claim: str | None) -> str:
    """The profile part of a claim: ``"simple"`` from ``"simple@1"``; ``"-"`` when unknown."""
    if not claim:
        return "-"
    return claim.split("@", 1)[0] or "-"


def verdict(record: RunRecord) -> str:
    """The claim's verdict words (harness/verdict.py: ``PASS``, ``PASS (unverified: dct;
    provisional differences: N)``, ``FAIL``, ``SPEED FAIL`` …); from the exit code when the run
    was judged by a baseline or stopped before a verdict."""
    words = (record.verdict or {}).get("verdict")
    if isinstance(words, str) and words and record.exit_code == record.verdict.get("exit_code"):
        return words
    return VERDICTS.get(record.exit_code, f"EXIT {record.exit_code}")


def _fmt_value(v: Any) -> str:
    """A value as a reader writes it: floats to 6 digits, lists in brackets, a table as ``key value``
    pairs (never a Python repr)."""
    if isinstance(v, float):
        if not math.isfinite(v):
            return str(v)
        return f"{v:.6g}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_fmt_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "(" + ", ".join(f"{k} {_fmt_value(x)}" for k, x in v.items()) + ")"
    if v is None:
        return "none"
    return str(v)


_DIFF_WHERE = ("frame", "time_ms", "fap", "name", "vertex", "part", "pixel", "channel", "field", "what")


def format_difference(d: dict[str, Any] | None) -> str:
    """One line for a first difference: ``frame 12, FAP 31 (raise_l_i_eyebrow): expected 120, got 121``."""
    if not d:
        return ""
    where = []
    if "frame" in d:
        where.append(f"frame {_fmt_value(d['frame'])}")
    if "time_ms" in d:
        where.append(f"t={_fmt_value(d['time_ms'])} ms")
    for key, label in (
        ("fap", "FAP"),
        ("vertex", "vertex"),
        ("pixel", "pixel"),
        ("channel", "channel"),
        ("field", "field"),
    ):
        if key in d:
            item = f"{label} {_fmt_value(d[key])}"
            extra = [str(d[k]) for k in ("name", "part") if k in d and key in ("fap", "vertex")]
            if extra:
                item += " (" + ", ".join(extra) + ")"
            where.append(item)
    if "fap" not in d and "vertex" not in d:
        where += [f"{k} {_fmt_value(d[k])}" for k in ("name", "part") if k in d]
    if "what" in d:  # what of the frame differs: time_ms, status, frame count...
        where.append(_fmt_value(d["what"]).replace("time_ms", "time (ms)"))
    text = ", ".join(where)
    vals = []
    if "expected" in d:
        vals.append(f"expected {_fmt_value(d['expected'])}")
    if "got" in d:
        vals.append("got no value" if d["got"] is None else f"got {_fmt_value(d['got'])}")
    rest = [f"{k} {_fmt_value(v)}" for k, v in d.items() if k not in _DIFF_WHERE + ("expected", "got", "faps")]
    parts = [p for p in (text, ", ".join(vals), ", ".join(rest)) if p]
    return clean_text(": ".join(parts[:2]) + ("; " + parts[2] if len(parts) > 2 else ""))


def _suite_names(record: RunRecord) -> list[str]:
    names = [str(s.get("name")) for s in record.suites if s.get("name") is not None]
    for r in record.results:
        if r.suite not in names:
            names.append(r.suite)
    return names


# The count tables' columns: a required case the decoder could not take is counted apart from an
# informative one (it fails the claim unless its tool is set aside as unverified; harness/verdict.py).
NS_REQUIRED = "RequiredNotSupported"
DISPLAY_COLUMNS = (
    "Pass",
    "Fail",
    "QualityWarning",
    NS_REQUIRED,
    "NotSupported",
    "Timeout",
    "Crash",
    "Error",
    "Skipped",
)


def display_counts(results: Iterable[CaseResult]) -> dict[str, int]:
    """Counts by :data:`DISPLAY_COLUMNS` (outcomes, required NotSupported apart)."""
    c = dict.fromkeys(DISPLAY_COLUMNS, 0)
    for r in results:
        c[NS_REQUIRED if r.outcome is Outcome.NOT_SUPPORTED and r.required else r.outcome.value] += 1
    return c


def _by(record: RunRecord, key: Callable[[CaseResult], str]) -> dict[str, dict[str, int]]:
    groups: dict[str, list[CaseResult]] = {}
    for r in record.results:
        groups.setdefault(key(r), []).append(r)
    return {k: display_counts(v) for k, v in groups.items()}


def _summary_counts(counts: dict[str, int]) -> str:
    n = sum(counts.values())
    parts = [f"{counts[c]} {c}" for c in DISPLAY_COLUMNS if counts.get(c)]
    return f"{n} case{'s' if n != 1 else ''}" + (": " + ", ".join(parts) if parts else "")


def verdict_reason(record: RunRecord) -> str:
    """Why the claim's verdict is what it is, in one line beside it: the required cases that fail
    it, or what a qualified pass leaves out."""
    v = record.verdict or {}
    unverified = set(v.get("unverified") or ())
    required = [r for r in record.results if r.required]
    hard = [r for r in required if not r.outcome.ok and not unverified & set(r.tools)]
    if hard:
        return "required case(s) not passed: " + _summary_counts(display_counts(hard)).split(": ", 1)[-1]
    out = []
    for tool in sorted(unverified):
        t = (v.get("tools") or {}).get(tool, {})
        out.append(
            f"{tool} {t.get('state', 'unverified')} ({t.get('note', '')}): its {t.get('cases', '?')} required "
            f"case(s) set aside; --strict fails them"
        )
    if record.provisional_differences:
        how = sorted({str(d.get("reading")) for d in record.provisional_differences})
        out.append(f"{len(record.provisional_differences)} case(s) judged by the declared reading {', '.join(how)}")
    return clean_text("; ".join(out))


def speed_word(s: SpeedResult) -> str:
    """PASS, FAIL or INCONCLUSIVE (below the minimum on a machine busy with other work)."""
    return s.verdict.upper()


def _speed_summary(speed: list[SpeedResult]) -> str:
    if not speed:
        return ""
    words = [speed_word(s) for s in speed]
    bad, unsure = words.count("FAIL"), words.count("INCONCLUSIVE")
    return (
        f"; speed: {words.count('PASS')} of {len(speed)} pass"
        + (f", {bad} below the level minimum" if bad else "")
        + (f", {unsure} inconclusive (below it on a busy machine)" if unsure else "")
    )


# Baseline classes in the order a CI log shows them: what fails the run first.
_BASELINE_ORDER = {"new": 0, "fixed": 1}


def _problem_cases(record: RunRecord) -> list[CaseResult]:
    """Cases worth a closer look: new failures first (a required case the decoder cannot take
    included), then fixed ones, then the rest worst first: failing, quality warnings, flakes."""
    rank = {o: i for i, o in enumerate(OUTCOME_ORDER)}
    picked = [
        r
        for r in record.results
        if r.outcome.failing or r.outcome is Outcome.QUALITY_WARNING or r.baseline in ("fixed", "flake", "new")
    ]
    return sorted(
        picked, key=lambda r: (_BASELINE_ORDER.get(r.baseline or "", 2), rank[r.outcome], not r.required, r.case_id)
    )


def baseline_changes(record: RunRecord) -> tuple[list[CaseResult], list[CaseResult]]:
    """The required cases that fail the run against its baseline: (new failures, fixed cases)."""
    new = [r for r in record.results if r.required and r.baseline == "new"]
    fixed = [r for r in record.results if r.required and r.baseline == "fixed"]
    return new, fixed


def baseline_lines(record: RunRecord, limit: int = 30) -> list[str]:
    """What a CI log shows first: ``baseline: N new, N known, N fixed, N flaky``, then every new
    failure and every fixed case by name (plain text, cleaned)."""
    if not record.baseline_summary:
        return []
    new, fixed = baseline_changes(record)
    out = [f"baseline: {record.baseline_summary}"]
    for r in new[:limit]:
        what = r.message.splitlines()[0] if r.message else ""
        out.append(f"  NEW    {r.case_id}  {r.outcome.value}" + (f": {what[:200]}" if what else ""))
    for r in fixed[:limit]:
        out.append(
            f"  FIXED  {r.case_id}  passes now, listed as failing: remove its line from the baseline (or --allow-fixed)"
        )
    more = max(0, len(new) - limit) + max(0, len(fixed) - limit)
    if more:
        out.append(f"  ... and {more} more (see the cases to look at below)")
    return [clean_text(x) for x in out]


_CASE_FOLDER = re.compile(r"/\S*/work/case-[A-Za-z0-9_]+(?=/)")


def reproduce_line(r: CaseResult, keep_option: str = "--keep-workdirs", env: dict[str, Any] | None = None) -> str:
    """The command of a case, with the manifest's ``[env]`` before it (``env K=V …``): as run when its
    work folder was kept (``keep_option``), else with the deleted folder named for what it was."""
    pre = ["env"] + [f"{k}={v}" for k, v in sorted((env or {}).items())] if env else []
    cmd = " ".join(shlex.quote(str(c)) for c in pre + list(r.command or []))
    folders = set(_CASE_FOLDER.findall(cmd))
    if folders and all(Path(f).is_dir() for f in folders):
        return clean_text(cmd)
    return clean_text(_CASE_FOLDER.sub("<case folder>", cmd)) + f"   (rerun with {keep_option})"


def _speed_rows(speed: list[SpeedResult]) -> list[list[str]]:
    return [
        [s.operation, s.claim, f"{s.rate_fps:.2f}", f"{s.required_fps:.2f}", speed_word(s), s.provenance] for s in speed
    ]


def _normalised(message: str, case_id: str = "") -> str:
    """A message with what differs between identical failures masked: the case's own name (a
    decoder's error names its input file), paths, addresses (``0x7ffd…``, ``+0x1c``), process ids,
    numbers."""
    own = case_id.rsplit("/", 1)[-1]
    m = (message or "").replace(own, "<case>") if own else (message or "")
    m = re.sub(r"/\S+", "<path>", m)
    m = re.sub(r"0x[0-9a-fA-F]+", "0x?", m)
    return re.sub(r"[-+]?\d+(\.\d+)?", "N", m)[:160]


def failure_groups(record: RunRecord) -> list[tuple[str, list[CaseResult]]]:
    """The cases worth a look, identical failures grouped (same outcome, same failure
    signature, same message up to paths, addresses and numbers): new failures first, then fixed
    cases, then the worst and largest groups."""
    groups: dict[tuple[str, ...], list[CaseResult]] = {}
    for r in _problem_cases(record):
        key = (r.outcome.value, signature(r), r.crash_kind or "", _normalised(r.message, r.case_id), r.baseline or "")
        groups.setdefault(key, []).append(r)
    rank = {o.value: i for i, o in enumerate(OUTCOME_ORDER)}
    out = sorted(
        groups.items(), key=lambda kv: (_BASELINE_ORDER.get(kv[0][4], 2), rank[kv[0][0]], -len(kv[1]), kv[1][0].case_id)
    )
    return [(k[0], rs) for k, rs in out]


def provisional_line(record: RunRecord) -> str:
    n = len(record.provisional)
    return (
        (
            f"{n} provisional rule(s) and level limit(s) this verdict rests on (listed in report.json and "
            f"in a certificate's statement)"
        )
        if n
        else ""
    )
