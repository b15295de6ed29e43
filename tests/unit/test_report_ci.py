"""Reports as a CI log and a vendor read them: the crash line is the report's first
line, one bug is one group whatever the addresses, pids and temporary paths, what fails the run
against its baseline comes first and by name, and the ``N new, N known, N fixed, N flaky`` line
is in every format. The crash texts are written the way the runtimes print them (an ASan report,
a Go panic, a Python traceback), each with its own random addresses."""

from __future__ import annotations

import random
import re
from xml.etree import ElementTree as ET

from fbaconf.harness.reports import html_report, junit_xml, terminal_summary
from fbaconf.harness.reports.common import failure_groups, format_difference
from fbaconf.harness.results import CaseResult, Outcome, RunRecord, StageResult
from fbaconf.isolation import endings
from fbaconf.isolation.process import ProcResult
from fbaconf.isolation.sandbox import Limits


def asan_text(rng: random.Random, func: str = "parse_plane") -> str:
    pc = rng.randrange(0x550000000000, 0x56FFFFFFFFFF)
    sp = rng.randrange(0x7FF000000000, 0x7FFFFFFFFFFF)
    pid = rng.randrange(2, 99999)
    frames = "\n".join(
        f"    #{i} {hex(pc - 64 * i)} in {f} /build/dec.c:{10 * i + 3}"
        for i, f in enumerate([func, "decode_object", "main"])
    )
    legend = "\n".join(f"  Shadow byte legend line {i}: {hex(rng.randrange(2**40))}" for i in range(30))
    return (
        f"decoding /tmp/fbaconf-run-{rng.randrange(10**6)}/work/case-{rng.randrange(10**6)}/in/x.fba\n"
        f"=================================================================\n"
        f"=={pid}==ERROR: AddressSanitizer: heap-buffer-overflow on address {hex(rng.randrange(2**44))} "
        f"at pc {hex(pc)} bp {hex(sp + 16)} sp {hex(sp)}\n"
        f"READ of size 4 at {hex(rng.randrange(2**44))} thread T0\n{frames}\n{legend}\n=={pid}==ABORTING\n"
    )


def go_text(rng: random.Random) -> str:
    n = rng.randrange(5, 500)
    return (
        f"panic: runtime error: index out of range [{n}] with length {n - 1}\n\ngoroutine 1 [running]:\n"
        f"main.parse({{{hex(rng.randrange(0xC000000000, 0xC00FFFFFFF))}, {hex(n)}, {hex(n + 7)}}})\n"
        f"\t/home/ci/acme/parse.go:41 +{hex(rng.randrange(16, 4096))}\n"
        f"main.main()\n\t/home/ci/acme/main.go:20 +{hex(rng.randrange(16, 4096))}\n"
    )


def crashed(cid: str, stderr: str, rc: int = 1, signal: str | None = None) -> CaseResult:
    res = ProcResult(argv=["/opt/acme/dec", f"/tmp/x/{cid}.fba"], returncode=rc, signal=signal, stderr_tail=stderr)
    e = endings.classify(res, Limits(), {1, 2})
    assert e.kind == "crash", e
    return CaseResult(
        case_id=cid,
        suite=cid.split("/")[0],
        claim="simple@1",
        outcome=Outcome.CRASH,
        message=e.message,
        crash_kind=e.report.kind,
        exit_code=rc,
        signal=signal,
        stderr_tail=stderr,
    )


def test_the_crash_line_is_the_reports_first_line_not_the_last_stderr_line():
    rng = random.Random(1)
    text = asan_text(rng)
    e = endings.classify(ProcResult(argv=["dec"], returncode=1, stderr_tail=text), Limits(), {1, 2})
    first = next(ln for ln in text.splitlines() if "ERROR: AddressSanitizer" in ln)
    assert (
        e.message == f"dec crashed: AddressSanitizer heap-buffer-overflow in parse_plane (exit code 1); stderr: {first}"
    )
    assert "ABORTING" not in e.message
    e = endings.classify(ProcResult(argv=["godec"], returncode=2, stderr_tail=go_text(rng)), Limits(), {1, 2})
    assert e.message.startswith(
        "godec crashed: Go panic in main.parse (exit code 2); stderr: panic: runtime error: index out of range ["
    )
    tb = (
        'Traceback (most recent call last):\n  File "/w/dec.py", line 9, in <module>\n    main()\n'
        '  File "/w/dec.py", line 5, in parse\n    raise ValueError("bad plane")\nValueError: bad plane\n'
        "dec: cleaning up\n"
    )
    e = endings.classify(ProcResult(argv=["dec.py"], returncode=1, stderr_tail=tb), Limits(), {1, 2})
    assert e.message == (
        "dec.py crashed: uncaught Python exception ValueError in parse (exit code 1); stderr: ValueError: bad plane"
    )
    rust = (
        "thread 'main' panicked at src/plane.rs:41:9:\nindex out of bounds: the len is 3 but the index is 7\nnote: x\n"
    )
    e = endings.classify(ProcResult(argv=["rdec"], returncode=101, stderr_tail=rust), Limits(), {1, 2})
    assert e.message.endswith(
        "stderr: thread 'main' panicked at src/plane.rs:41:9: index out of bounds: the len is 3 but the index is 7"
    )
    # no report: the last line is all there is
    e = endings.classify(ProcResult(argv=["dec"], returncode=None, signal="SIGSEGV", stderr_tail="a\nb\n"), Limits())
    assert e.message == "dec crashed: killed by SIGSEGV; stderr: b"


def test_one_bug_failing_sixty_cases_with_differing_addresses_is_one_group(tmp_path):
    rng = random.Random(7)
    rs = [crashed(f"simple-l1-core/case-{i:02d}", asan_text(rng)) for i in range(60)]
    assert len({re.search(r"at pc (0x[0-9a-f]+)", r.message).group(1) for r in rs}) == 60  # all differ
    rs += [crashed(f"simple-l1-stress/go-{i}", go_text(rng), rc=2) for i in range(5)]
    rs.append(crashed("simple-l1-core/other-bug", asan_text(rng, func="read_header")))  # another bug
    record = RunRecord(decoder={"name": "acme"}, claim="simple@1", suites=[], system={}, results=rs, exit_code=1)
    assert [len(g) for _o, g in failure_groups(record)] == [60, 5, 1]
    text = terminal_summary(record)
    assert "66 in 3 group(s) of identical failures" in text and "Crash x60" in text
    page = html_report(record, tmp_path)
    assert "<h2>Failures and warnings (66 case(s) in 3 group(s) of identical failures)</h2>" in page
    assert "stderr (the crash report):" in text and "ABORTING" not in text


def ci_record(tmp_path) -> RunRecord:
    kept = tmp_path / "run" / "work" / "case-abc123"
    (kept / "in").mkdir(parents=True)
    rs = [
        CaseResult("s/known", "s", "simple@1", Outcome.FAIL, "faps differ", baseline="known-failure"),
        CaseResult(
            "s/zz-new",
            "s",
            "simple@1",
            Outcome.FAIL,
            "faps: FAP 31 differs",
            baseline="new",
            stages=[
                StageResult(
                    "faps",
                    Outcome.FAIL,
                    "x",
                    first_difference={
                        "frame": 0,
                        "fap": 31,
                        "expected": 1,
                        "got": 2,
                        "detail": {"frame": 0, "state": "SET"},
                    },
                )
            ],
            command=["/opt/dec", f"{kept}/in/a.fba", f"{kept}/out/faps.npz"],
        ),
        CaseResult("s/no-multi", "s", "simple@1", Outcome.NOT_SUPPORTED, "no decode_multi command", baseline="new"),
        CaseResult("s/fixed", "s", "simple@1", Outcome.PASS, "faps match", baseline="fixed"),
        CaseResult(
            "s/prov",
            "s",
            "simple@1",
            Outcome.PASS,
            "judged by the declared reading D7:rewind-14: faps match",
            rests_on=["D7"],
            reading="D7:rewind-14",
        ),
        CaseResult("s/ok", "s", "simple@1", Outcome.PASS, "faps match"),
    ]
    return RunRecord(
        decoder={"name": "acme"},
        claim="simple@1",
        suites=[],
        system={},
        results=rs,
        exit_code=1,
        baseline_summary="2 new, 1 known, 1 fixed, 0 flaky",
        provisional_differences=[{"case_id": "s/prov", "rests_on": ["D7"], "reading": "D7:rewind-14"}],
    )


def test_a_ci_log_names_what_fails_the_run_first(tmp_path):
    text = terminal_summary(ci_record(tmp_path))
    lines = text.splitlines()
    assert lines[1] == "  baseline: 2 new, 1 known, 1 fixed, 0 flaky"
    assert lines[2].split() == ["NEW", "s/zz-new", "Fail:", "faps:", "FAP", "31", "differs"]
    assert lines[3].split()[:3] == ["NEW", "s/no-multi", "NotSupported:"]
    assert lines[4].split()[:2] == ["FIXED", "s/fixed"]
    looked = text.split("cases to look at")[1]
    assert looked.index("s/zz-new") < looked.index("s/no-multi") < looked.index("s/fixed") < looked.index("s/known")
    # the kept case folder is named as it is; no Python repr anywhere
    assert f"reproduce: /opt/dec {tmp_path}/run/work/case-abc123/in/a.fba" in text
    assert "{'" not in text and "':" not in text


def test_html_puts_the_summary_first_with_the_baseline_line_and_provisional_differences(tmp_path):
    page = html_report(ci_record(tmp_path), tmp_path / "html")
    h2 = re.findall(r"<h2>([^<]*)</h2>", page)
    assert h2[0] == "Summary" and h2[1].startswith("Failures and warnings")
    assert page.index("Baseline</b>: 2 new, 1 known, 1 fixed, 0 flaky") < page.index("<h2>Failures")
    assert page.index("Provisional differences (1)") < page.index("<h2>Failures")
    assert "<span class='mono'>s/prov</span> rests on D7; judged by D7:rewind-14" in page
    assert "{&#x27;" not in page and "{'" not in page


def test_junit_carries_the_baseline_line_and_tags_new_failures(tmp_path):
    root = ET.fromstring(junit_xml(ci_record(tmp_path)))  # noqa: S314 - fbaconf's own JUnit output
    props = {p.get("name"): p.get("value") for p in root.iter("property")}
    assert props["baseline"] == "2 new, 1 known, 1 fixed, 0 flaky"
    fails = {
        tc.get("name"): tc.find("failure").get("message")
        for tc in root.iter("testcase")
        if tc.find("failure") is not None
    }
    assert fails["s/zz-new"].startswith("new: ") and fails["s/no-multi"].startswith("new: required by the claim")


def test_a_difference_is_written_as_words_not_a_python_repr():
    d = {"frame": 2, "fap": 31, "expected": 1, "got": None, "detail": {"frame": 0, "state": "SET"}}
    assert format_difference(d) == "frame 2, FAP 31: expected 1, got no value; detail (frame 0, state SET)"
    # what differs in the frame is named where it differs, not left as a trailing "what time_ms"
    d = {"frame": 15, "frame_number": 15, "what": "time_ms", "expected": 500.5, "got": 500.0}
    assert format_difference(d) == "frame 15, time (ms): expected 500.5, got 500; frame_number 15"
