"""Harness reports: terminal summary, JSON (+ schema), JUnit XML, the HTML page, system info."""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import socket
import struct
import subprocess
import zlib
from html.parser import HTMLParser
from importlib import resources
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st
from junitparser import Error as JError, Failure, JUnitXml, Skipped

from fbaconf.harness import reports
from fbaconf.harness.reports import read_json, terminal_summary, write_html, write_json, write_junit
from fbaconf.harness.reports.common import failure_groups
from fbaconf.harness.results import CaseResult, Outcome, RunRecord, SpeedResult, StageResult
from fbaconf.harness.sysinfo import system_info

HOSTILE = "<script>alert(1)</script>"


def tiny_png(path: Path, rgb=(200, 30, 30), size=4) -> Path:
    """A valid size x size RGB PNG, written without any image library."""
    raw = b"".join(b"\x00" + bytes(rgb) * size for _ in range(size))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", struct.pack(">IIBBBBB", size, size, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(raw))
        + chunk(b"IEND", b"")
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(png)
    return path


def case(cid, outcome, claim="simple@1", **kw) -> CaseResult:
    suite = cid.split("/")[0]
    return CaseResult(case_id=cid, suite=suite, claim=claim, outcome=outcome, **kw)


def make_record(elsewhere: Path | None = None, inside: str | None = None) -> RunRecord:
    """A record with every outcome; image artefacts when folders are given."""
    arte = {}
    if elsewhere is not None:
        arte = {
            "expected": str(tiny_png(elsewhere / "exp.png", (20, 160, 40))),
            "got": str(tiny_png(elsewhere / "got.png", (200, 30, 30))),
            "diff": str(tiny_png(elsewhere / "diff.png", (250, 250, 0))),
        }
    if inside is not None:
        arte["inside"] = inside
    results = [
        case("basic/q0-neutral", Outcome.PASS, duration_s=0.12),
        case("basic/q8-smile", Outcome.PASS, duration_s=0.2, baseline="fixed"),
        case(
            "basic/q31-anger",
            Outcome.FAIL,
            message=f"FAP 31 differs {HOSTILE}",
            duration_s=0.3,
            baseline="known-failure",
            stages=[
                StageResult(
                    "faps",
                    Outcome.FAIL,
                    message="FAP mismatch",
                    first_difference={"frame": 12, "fap": 31, "name": "raise_l_i_eyebrow", "expected": 120, "got": 121},
                    metrics={"max_abs": 1.0, "psnr": math.inf},
                    series={"max abs error": [0, 0, 0.5, 1.0, 0.25, 0.0], "rms <error>": [0, 0.1, 0.2, 0.1, 0.0, 0.0]},
                )
            ],
        ),
        case(
            "render/teeth",
            Outcome.QUALITY_WARNING,
            claim="predictable@2",
            message="dE p95 2.1 above warn 2.0",
            stages=[
                StageResult(
                    "images",
                    Outcome.QUALITY_WARNING,
                    message="dE warn",
                    first_difference={"frame": 0, "pixel": [10, 20], "expected": [1, 2, 3], "got": [4, 5, 6]},
                    metrics={"de_p95": 2.1},
                    artefacts=arte,
                )
            ],
        ),
        case(
            "render/eyes",
            Outcome.CRASH,
            claim="predictable@2",
            message="decoder died",
            command=["dec", "--in", "x y.fba"],
            exit_code=-11,
            signal="SIGSEGV",
            stderr_tail="line1\n\x1b[31mSegmentation fault\x1b[0m \x00\n" + HOSTILE,
        ),
        case("render/slow", Outcome.TIMEOUT, claim="predictable@2", message="no output after 30 s"),
        case("basic/bad-setup", Outcome.ERROR, message='golden missing & "quoted"'),
        case("basic/dct", Outcome.NOT_SUPPORTED, message="exit 69: DCT mode", required=False),
        case("render/skipme", Outcome.SKIPPED, claim="predictable@2", message="no render command"),
    ]
    speed = [
        SpeedResult(
            "decode",
            "simple@1",
            0.001,
            0.05,
            1000.0,
            25.0,
            True,
            "seed",
            samples=[{"frames": 100, "seconds": 0.15}],
            fit_r2=0.999,
        ),
        SpeedResult(
            "render",
            "predictable@2",
            0.1,
            0.5,
            10.0,
            25.0,
            False,
            "provisional",
            samples=[{"frames": 10, "seconds": 1.5}],
            fit_r2=0.98,
            message="too slow",
        ),
    ]
    return RunRecord(
        decoder={
            "name": "exampledec",
            "manifest_sha256": "ab" * 32,
            "kind": "manifest",
            "claims": ["simple@1"],
            "inputs": ["fba"],
            "outputs": ["faps", "images"],
        },
        claim="simple@1",
        suites=[
            {"name": "basic", "version": "1.0", "sha256": "cd" * 32, "cases": 5},
            {"name": "render", "version": "0.3", "sha256": "ef" * 32, "cases": 4},
        ],
        system={"cpu_model": "Test CPU", "cpu_count": 2, "versions": {"numpy": "2.0"}},
        results=results,
        speed=speed,
        started="2024-01-01T00:00:00Z",
        finished="2024-01-01T00:01:00Z",
        duration_s=60.0,
        provisional=["level numbers are provisional", f"DCT tables {HOSTILE}"],
        exit_code=1,
    )


@pytest.fixture(scope="module")
def schema():
    text = resources.files("fbaconf.harness").joinpath("data", "run-report.schema.json").read_text("utf-8")
    s = json.loads(text)
    jsonschema.Draft202012Validator.check_schema(s)
    return s


@pytest.fixture(scope="module")
def validator(schema):
    return jsonschema.Draft202012Validator(schema)


# ----------------------------------------------------------------------------- system info


def test_system_info_fields_and_no_hostname():
    info = system_info({"jobs": 3})
    for k in (
        "cpu_model",
        "cpu_count",
        "os",
        "kernel",
        "python_version",
        "python_implementation",
        "versions",
        "timestamp_utc",
    ):
        assert k in info
    assert info["jobs"] == 3
    assert set(info["versions"]) == {"fbaconf", "numpy", "OpenImageIO", "colour-science"}
    assert info["versions"]["numpy"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", info["timestamp_utc"])
    text = json.dumps(info)
    host = socket.gethostname()
    if len(host) >= 4:
        assert host not in text
    user = os.environ.get("USER") or os.environ.get("LOGNAME")
    if user and len(user) >= 4:
        assert f"/{user}" not in text


# ----------------------------------------------------------------------------- terminal


def _row(text: str, first: str) -> list[str]:
    for line in text.splitlines():
        cells = line.split()
        if cells and cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r} in\n{text}")


def test_terminal_tables_and_verdict():
    rec = make_record()
    text = terminal_summary(rec)
    assert "\x1b" not in text and "\x00" not in text
    header = _row(text, "suite")
    # a required case the decoder could not take has a column of its own (it fails the claim)
    assert header[1:] == [
        "Pass",
        "Fail",
        "QualityWarning",
        "RequiredNotSupported",
        "NotSupported",
        "Timeout",
        "Crash",
        "Error",
        "Skipped",
        "total",
    ]
    basic = dict(zip(header[1:], map(int, _row(text, "basic")[1:])))
    assert basic == {
        "Pass": 2,
        "Fail": 1,
        "QualityWarning": 0,
        "RequiredNotSupported": 0,
        "NotSupported": 1,
        "Timeout": 0,
        "Crash": 0,
        "Error": 1,
        "Skipped": 0,
        "total": 5,
    }
    render = dict(zip(header[1:], map(int, _row(text, "render")[1:])))
    assert render["total"] == 4 and render["Crash"] == 1 and render["Timeout"] == 1
    pheader = _row(text, "profile")
    assert dict(zip(pheader[1:], map(int, _row(text, "predictable")[1:])))["QualityWarning"] == 1
    assert dict(zip(pheader[1:], map(int, _row(text, "simple")[1:])))["total"] == 5
    # failing cases: message and first difference, baseline annotations
    assert "basic/q31-anger" in text and "[baseline: known-failure]" in text
    assert "first difference: frame 12, FAP 31 (raise_l_i_eyebrow): expected 120, got 121" in text
    assert "first difference: frame 0, pixel [10, 20]: expected [1, 2, 3], got [4, 5, 6]" in text
    assert "baseline: fixed" in text and "signal SIGSEGV" in text and "Segmentation fault" in text
    order = [
        line.split()[0]
        for line in text.split("cases to look at")[1].split("speed:")[0].splitlines()
        if line.startswith("  ") and not line.startswith("   ")
    ]
    assert order == ["Pass", "Crash", "Timeout", "Fail", "Error", "QualityWarning"]  # what fails the run (fixed) first
    # speed
    speed = [line for line in text.splitlines() if line.strip().startswith("render ") and "provisional" in line]
    assert speed and "FAIL" in speed[0] and "10.00" in speed[0] and "25.00" in speed[0]
    last = text.rstrip().splitlines()[-1]
    assert last.startswith(
        "result: FAIL (9 cases: 2 Pass, 1 Fail, 1 QualityWarning, 1 NotSupported, "
        "1 Timeout, 1 Crash, 1 Error, 1 Skipped"
    )
    assert "speed: 1 of 2 pass" in last


@pytest.mark.parametrize("code,word", [(0, "PASS"), (1, "FAIL"), (2, "SETUP ERROR"), (3, "SPEED FAIL")])
def test_terminal_verdict_follows_exit_code(code, word):
    rec = make_record()
    rec.exit_code = code
    assert terminal_summary(rec).rstrip().splitlines()[-1].startswith(f"result: {word} (9 cases")


def test_terminal_limits_and_colour():
    rec = make_record()
    text = terminal_summary(rec, max_failures=2)
    assert "6 in 6 group(s)" in text and "(2 groups shown)" in text and "... and 4 more group(s)" in text
    coloured = terminal_summary(rec, color=True)
    assert "\x1b[" in coloured
    # colour codes do not break the alignment of the plain text
    plain = re.sub(r"\x1b\[[0-9;]*m", "", coloured)
    assert plain == terminal_summary(rec)
    empty = RunRecord(decoder={"name": "d"}, claim=None, suites=[], system={})
    assert terminal_summary(empty).rstrip().endswith("result: PASS (0 cases)")


# ----------------------------------------------------------------------------- JSON


def test_json_schema_strict_and_round_trip(tmp_path, schema):
    rec = make_record(tmp_path / "elsewhere")
    p = write_json(rec, tmp_path / "out" / "run.json")
    text = p.read_text("utf-8")
    doc = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))
    jsonschema.validate(doc, schema)
    assert doc["counts"]["Fail"] == 1 and doc["exit_code"] == 1
    assert doc["results"][2]["stages"][0]["metrics"]["psnr"] == "Infinity"
    assert "\n  " in text  # indented
    back = read_json(p)
    assert back == rec
    assert [x.name for x in p.parent.iterdir()] == ["run.json"]  # atomic: no temp files left


def test_json_handles_numpy_values(tmp_path, schema):
    rec = make_record()
    rec.results[2].stages[0].first_difference = {
        "frame": np.int64(3),
        "vertex": np.int32(7),
        "expected": np.array([1.0, 2.0]),
        "got": np.float32(0.5),
    }
    doc = json.loads(write_json(rec, tmp_path / "r.json").read_text())
    jsonschema.validate(doc, schema)
    assert doc["results"][2]["stages"][0]["first_difference"] == {
        "frame": 3,
        "vertex": 7,
        "expected": [1.0, 2.0],
        "got": 0.5,
    }


# ----------------------------------------------------------------------------- JUnit


def _suites(xml: JUnitXml) -> dict:
    return {s.name: s for s in xml}


def test_junit_counts_names_messages(tmp_path):
    rec = make_record()
    p = write_junit(rec, tmp_path / "junit.xml")
    xml = JUnitXml.fromfile(str(p))
    suites = _suites(xml)
    assert list(suites) == ["basic", "render", "speed"]
    basic, render, speed = suites["basic"], suites["render"], suites["speed"]
    # the known failure (q31-anger) is skipped, as the exit code excuses it; the required
    # NotSupported case fails (a claim means all of it)
    assert (basic.tests, basic.failures, basic.errors, basic.skipped) == (5, 1, 1, 2)
    assert (render.tests, render.failures, render.errors, render.skipped) == (4, 2, 0, 1)
    assert (speed.tests, speed.failures) == (2, 1)
    props = {pr.name: pr.value for pr in basic.properties()}
    assert props["decoder"] == "exampledec" and props["claim"] == "simple@1"
    assert props["decoder.manifest_sha256"] == "ab" * 32 and props["suite.version"] == "1.0"
    assert props["system.cpu_model"] == "Test CPU"
    cases = {c.name: c for s in xml for c in s}
    assert set(cases) >= {r.case_id for r in rec.results} | {"decode simple@1", "render predictable@2"}
    anger = cases["basic/q31-anger"]
    assert anger.classname == "fbaconf.basic"
    (f,) = anger.result
    assert isinstance(f, Skipped) and f.message == f"known-failure (Fail): FAP 31 differs {HOSTILE}"
    assert "frame 12, FAP 31 (raise_l_i_eyebrow): expected 120, got 121" in f.text
    assert "baseline: known-failure" in f.text
    (crash,) = cases["render/eyes"].result
    assert isinstance(crash, Failure) and crash.type == "Crash" and "SIGSEGV" in crash.text
    assert "\\x00" in crash.text and "\x1b" not in crash.text
    (err,) = cases["basic/bad-setup"].result
    assert isinstance(err, JError) and err.message == 'golden missing & "quoted"'
    (sk,) = cases["basic/dct"].result
    assert isinstance(sk, Skipped) and "DCT mode" in sk.message
    qw = cases["render/teeth"]
    assert not qw.result and "QualityWarning" in qw.system_out
    (sp,) = cases["render predictable@2"].result
    assert isinstance(sp, Failure) and "below the required 25.00 fps" in sp.message
    assert not cases["decode simple@1"].result
    assert float(cases["basic/q8-smile"].time) == pytest.approx(0.2)


def test_junit_an_inconclusive_speed_is_skipped_not_failed(tmp_path):
    """A rate missed on a busy machine is the lab's, not the decoder's: a CI gate reading JUnit
    must not fail the decoder for it (certify exits 4, "inconclusive", for the same result)."""
    rec = make_record()
    busy = SpeedResult(
        "decode", "simple@1", 0.1, 0.05, 10.0, 25.0, False, "seed", verdict="inconclusive", reason="load 7.9 on 2 CPUs"
    )
    rec.speed = [busy]
    xml = JUnitXml.fromfile(str(write_junit(rec, tmp_path / "junit.xml")))
    speed = _suites(xml)["speed"]
    assert (speed.tests, speed.failures, speed.errors, speed.skipped) == (1, 0, 0, 1)
    (sk,) = next(iter(speed)).result
    assert isinstance(sk, Skipped) and "inconclusive" in sk.message and "busy" in sk.message
    assert "load 7.9 on 2 CPUs" in sk.text


# ----------------------------------------------------------------------------- HTML


class _Collector(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.stack: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))


def test_html_report(tmp_path):
    out = tmp_path / "report"
    tiny_png(out / "run" / "frame0.png")
    rec = make_record(tmp_path / "elsewhere", inside="run/frame0.png")
    rec.results[3].stages[0].artefacts["missing"] = str(tmp_path / "nope.png")
    for kind in ("diff", "got", "expected"):  # the comparison ladder's naming, out of order
        rec.results[3].stages[0].artefacts[f"frame3_{kind}"] = str(tiny_png(tmp_path / "w" / f"f3{kind}.png"))
    rec.results[3].stages[0].artefacts["secret"] = str(tmp_path / "w" / "id_rsa")
    (tmp_path / "w" / "id_rsa").write_text("not an image")
    page = write_html(rec, out)
    assert page == out / "index.html"
    text = page.read_text("utf-8")
    assert text.startswith("<!DOCTYPE html>")
    for r in rec.results:
        if r.outcome is not Outcome.PASS:
            assert r.case_id in text
    assert "<script" not in text.lower()
    assert "&lt;script&gt;alert(1)&lt;/script&gt;" in text
    assert "\x1b" not in text and "\x00" not in text
    assert "level numbers are provisional" in text
    p = _Collector()
    p.feed(text)
    tags = p.tags
    # no external resources at all
    for _tag, attrs in tags:
        for a in ("src", "href"):
            v = attrs.get(a)
            if v:
                assert not re.match(r"^[a-z]+:", v) or v.startswith("data:"), v
    # one SVG plot per series, with a polyline each
    svgs = [a for t, a in tags if t == "svg"]
    assert len(svgs) == 2 and len([t for t, _ in tags if t == "polyline"]) == 2
    assert "rms &lt;error&gt;" in text
    # images: copied ones under artefacts/, the one inside out_dir linked in place
    imgs = [a["src"] for t, a in tags if t == "img"]
    assert "run/frame0.png" in imgs
    copied = [s for s in imgs if s.startswith("artefacts/")]
    assert len(copied) == 6
    alts = [a["alt"] for t, a in tags if t == "img"]
    assert alts.index("frame3_expected") < alts.index("frame3_got") < alts.index("frame3_diff")
    assert not any("id_rsa" in p.name for p in (out / "artefacts").iterdir())  # only artefact types are copied
    for s in copied:
        assert (out / s).read_bytes()[:4] == b"\x89PNG"
    assert "missing" in text
    # summary table has colour-coded cells and the passing list is collapsible
    assert "c-Crash" in text and "<details><summary>Passing cases (1)" in text
    assert "q0-neutral" in text
    # rewriting is idempotent and leaves no temp files
    write_html(rec, out)
    assert sorted(x.name for x in out.iterdir()) == ["artefacts", "index.html", "run"]


def test_svg_plot_edge_cases():
    assert "no finite values" in reports.svg_plot("x", [])
    assert "<circle" in reports.svg_plot("x", [3.0])
    s = reports.svg_plot("x", [1, math.nan, 2, 3, math.inf, 4])
    assert s.count("<polyline") == 1 and s.count("<circle") == 2
    for vals in ([1e308, -1e308, 0], [5e-324, 0.0], [1.7e308] * 2, [-1.79e308] * 3, [2, 2]):
        svg = reports.svg_plot("x", vals)
        assert "nan" not in svg.lower() and "inf" not in svg.replace("infinite", "").lower(), vals
    flat = reports.svg_plot("flat", [0.0] * 5000)
    assert flat.count("<polyline") == 1 and len(flat) < 20000


# ----------------------------------------------------------------------------- property tests

_text = st.text(max_size=30)
_finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
_json_leaf = st.one_of(st.none(), st.booleans(), st.integers(-(10**6), 10**6), _finite, _text)
_anyjson = st.one_of(_json_leaf, st.lists(_json_leaf, max_size=3))
_diff = st.one_of(
    st.none(),
    st.fixed_dictionaries(
        {"frame": st.one_of(st.none(), st.integers(0, 10**6))},
        optional={k: _anyjson for k in ("fap", "vertex", "pixel", "expected", "got", "name", "distance", "extra")},
    ),
)
_stage = st.builds(
    StageResult,
    stage=st.sampled_from(["faps", "vertices", "images", "process"]),
    outcome=st.sampled_from(list(Outcome)),
    message=_text,
    first_difference=_diff,
    metrics=st.dictionaries(_text, _finite, max_size=3),
    series=st.dictionaries(_text, st.lists(_finite, max_size=6), max_size=2),
    artefacts=st.dictionaries(_text, _text, max_size=2),
)
_case = st.builds(
    CaseResult,
    case_id=_text,
    suite=st.sampled_from(["basic", "render", "ünï<&>"]),
    claim=st.sampled_from(["simple@1", "predictable@2", "calibration@1"]),
    outcome=st.sampled_from(list(Outcome)),
    message=_text,
    required=st.booleans(),
    stages=st.lists(_stage, max_size=2),
    duration_s=st.floats(0, 1e4),
    command=st.one_of(st.none(), st.lists(_text, max_size=3)),
    exit_code=st.one_of(st.none(), st.integers(-64, 255)),
    signal=st.one_of(st.none(), _text),
    stderr_tail=_text,
    baseline=st.sampled_from([None, "known-failure", "flake", "fixed"]),
)
_speed = st.builds(
    SpeedResult,
    operation=st.sampled_from(["decode", "render"]),
    claim=st.just("simple@1"),
    per_frame_s=_finite,
    startup_s=_finite,
    rate_fps=_finite,
    required_fps=_finite,
    passed=st.booleans(),
    provenance=st.sampled_from(["seed", "provisional"]),
    samples=st.lists(st.fixed_dictionaries({"frames": st.integers(0, 100), "seconds": st.floats(0, 10)}), max_size=2),
    fit_r2=_finite,
    message=_text,
)
_record = st.builds(
    RunRecord,
    decoder=st.fixed_dictionaries({"name": _text}),
    claim=st.one_of(st.none(), st.just("simple@1")),
    suites=st.just([{"name": "basic", "version": "1"}]),
    system=st.just({"os": "Linux"}),
    results=st.lists(_case, max_size=6),
    speed=st.lists(_speed, max_size=2),
    started=_text,
    finished=_text,
    duration_s=st.floats(0, 1e5),
    provisional=st.lists(_text, max_size=2),
    exit_code=st.sampled_from([0, 1, 2, 3]),
)


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
)
@given(rec=_record)
def test_property_json_round_trip_and_junit_parses(tmp_path, validator, rec):
    p = write_json(rec, tmp_path / "r.json")
    with open(p, encoding="utf-8") as f:
        doc = json.load(f)
    validator.validate(doc)
    assert RunRecord.from_json(doc) == rec
    j = write_junit(rec, tmp_path / "j.xml")
    xml = JUnitXml.fromfile(str(j))
    by = {s.name: s for s in xml}
    for suite in {r.suite for r in rec.results}:
        mine = [r for r in rec.results if r.suite == suite]
        s = by[reports.clean_text(suite)]
        assert s.tests == len(mine)
        # JUnit agrees with the exit code: known failures and flakes are skipped, fixed cases and
        # required NotSupported cases fail
        excused = [r.baseline in ("known-failure", "flake") and not r.outcome.ok for r in mine]
        fixed = [r.baseline == "fixed" and not ex for r, ex in zip(mine, excused)]
        assert s.failures == sum(
            not ex
            and (
                fx
                or r.outcome in (Outcome.FAIL, Outcome.TIMEOUT, Outcome.CRASH)
                or (r.outcome is Outcome.NOT_SUPPORTED and r.required)
            )
            for r, ex, fx in zip(mine, excused, fixed)
        )
        assert s.errors == sum(
            not ex and not fx and r.outcome is Outcome.ERROR for r, ex, fx in zip(mine, excused, fixed)
        )
        assert s.skipped == sum(
            ex or (not fx and (r.outcome is Outcome.SKIPPED or (r.outcome is Outcome.NOT_SUPPORTED and not r.required)))
            for r, ex, fx in zip(mine, excused, fixed)
        )
    if rec.speed:
        assert by["speed"].failures == sum(not s.passed for s in rec.speed)
    text = terminal_summary(rec)
    assert "\x1b" not in text and text.rstrip().splitlines()[-1].startswith("result: ")
    page = reports.html_report(rec, tmp_path / "h")
    assert "<script" not in page.lower()


# ----------------------------------------------------------------------------- optional browser check

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(not CHROMIUM, reason="chromium not installed")
@pytest.mark.spawns("the report as a real browser shows it")
def test_html_in_headless_chromium(tmp_path):
    out = tmp_path / "report"
    page = write_html(make_record(tmp_path / "elsewhere", inside=None), out)
    try:
        proc = subprocess.run(
            [
                CHROMIUM,
                "--headless=new",
                "--no-sandbox",
                "--disable-gpu",
                "--enable-logging=stderr",
                "--v=0",
                f"--user-data-dir={tmp_path / 'profile'}",
                "--dump-dom",
                page.as_uri(),
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    except subprocess.TimeoutExpired:
        pytest.skip("chromium did not finish in time")
    assert "Failures and warnings" in proc.stdout
    bad = [
        line
        for line in proc.stderr.splitlines()
        if "CONSOLE" in line or "Uncaught" in line or "Content Security Policy" in line
    ]
    assert not bad, bad


def test_html_artefacts_relative_to_base_dir(tmp_path):
    run = tmp_path / "run"
    tiny_png(run / "cases" / "a_expected.png")
    rec = make_record()
    rec.results[2].stages[0].artefacts = {"a_expected": "cases/a_expected.png"}
    out = tmp_path / "html"
    text = write_html(rec, out, base_dir=run).read_text("utf-8")
    (src,) = re.findall(r"<img src='([^']+)'", text)
    assert src.startswith("artefacts/") and (out / src).is_file()
    assert "missing" in write_html(rec, tmp_path / "other").read_text("utf-8")  # not under out_dir itself


# ------------------------------------------------------------------ what the user reads is what happened


def _qualified_record() -> RunRecord:
    """A decoder that declines dct: every other required case passes (harness/verdict.py sets the
    tool aside: PASS (unverified: dct))."""
    rs = [case("s/a", Outcome.PASS, tools=["arithmetic"]), case("s/b", Outcome.PASS, tools=["arithmetic"])]
    rs += [
        case(
            f"s/d{i}",
            Outcome.NOT_SUPPORTED,
            message="case uses tool(s) dct the decoder does not declare",
            tools=["dct"],
            rests_on=["D8"],
        )
        for i in range(3)
    ]
    verdict = {
        "verdict": "PASS (unverified: dct)",
        "exit_code": 0,
        "unverified": ["dct"],
        "tools": {
            "arithmetic": {
                "tool": "arithmetic",
                "state": "verified",
                "cases": 2,
                "passed": 2,
                "provisional": False,
                "note": "",
            },
            "dct": {
                "tool": "dct",
                "state": "declined",
                "cases": 3,
                "passed": 0,
                "provisional": True,
                "note": "not taken (3 valid stream(s) NotSupported)",
            },
        },
        "decisions": {"D8": {"decision": "D8", "state": "declined", "cases": 3, "passed": 0, "readings": []}},
    }
    return RunRecord(
        decoder={"name": "honest", "env": {"JAVA_OPTS": "-Xss4m"}},
        claim="simple@1",
        suites=[],
        system={},
        results=rs,
        exit_code=0,
        verdict=verdict,
        missing=["3 required case(s): case uses tool(s) dct the decoder does not declare"],
    )


def test_a_qualified_pass_reads_declined_with_its_reason_beside_an_amber_badge(tmp_path):
    page = write_html(_qualified_record(), tmp_path, heading="fbaconf certification").read_text()
    assert "<title>fbaconf certification: honest (simple@1)</title>" in page
    badge = re.search(r"<span class='badge verdict ([^']+)'>([^<]*)</span> <span class='reason'>([^<]*)</span>", page)
    assert badge and badge.group(1) == "v-PASSQ" and badge.group(2) == "PASS (unverified: dct)"
    assert "dct declined" in badge.group(3) and "set aside" in badge.group(3)
    body = page.split("</style>", 1)[1]  # the inlined style sheet names every class
    assert "v-FAIL" not in body and "c-Fail" not in body
    assert "tool dct: declined" in page
    # the required NotSupported cases have their own column and colour, not the informative one's
    assert page.count("<td class='num c-NotSupportedRequired'>3</td>") == 2  # the suite row and the total
    text = terminal_summary(_qualified_record())
    assert (
        text.rstrip()
        .splitlines()[-1]
        .startswith("result: PASS (unverified: dct) (5 cases: 2 Pass, 3 RequiredNotSupported)")
    )
    assert "  tool dct: declined" in text


def test_identical_failures_that_name_their_own_input_are_one_group():
    rs = [
        case(
            f"s/dct-{n}",
            Outcome.FAIL,
            tools=["dct"],
            exit_code=1,
            message=(
                f"acme-java exited with code 1, a reject; stderr: Exception in thread main: in/dct-{n}.fba: "
                f"DCT segment mode not implemented: a valid stream was rejected"
            ),
        )
        for n in ("q4", "skips", "mode-switch", "short")
    ]
    rec = RunRecord(decoder={"name": "acme-java"}, claim="simple@1", suites=[], system={}, results=rs, exit_code=1)
    groups = failure_groups(rec)
    assert len(groups) == 1 and len(groups[0][1]) == 4


def test_reproduce_lines_carry_the_manifests_env(tmp_path):
    r = case("s/a", Outcome.FAIL, message="x", command=["/opt/acme/dec", "/run/work/case-ab12/in/a.fba"])
    rec = RunRecord(
        decoder={"name": "acme", "env": {"ACME_LICENSE": "ci", "B": "two words"}},
        claim="simple@1",
        suites=[],
        system={},
        results=[r],
        exit_code=1,
    )
    line = next(x for x in terminal_summary(rec).splitlines() if "reproduce:" in x)
    assert line.split("reproduce: ")[1].startswith("env ACME_LICENSE=ci 'B=two words' /opt/acme/dec ")
    assert "env ACME_LICENSE=ci &#x27;B=two words&#x27; /opt/acme/dec" in write_html(rec, tmp_path).read_text()
