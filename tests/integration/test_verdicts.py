"""A verdict only a real decoder can earn.

Lazy and broken decoders, written here as tiny programs, must not certify; every process
ending on the error suite gets the outcome the harness guide's table gives it."""

from __future__ import annotations

import subprocess
import sys as _sys
from pathlib import Path

import pytest

from fbaconf.bitstreams.faptext import read_fap_file
from fbaconf.bitstreams.frames import FREE, RETAINED, FapFrames
from fbaconf.certification import certify
from fbaconf.conformance.suite import load_suites
from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.targets import DecoderTarget, FuzzSetupError
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.harness.selection import select_cases
from fbaconf.harness.session import RunOptions, execute

from lib.cases import case
from lib.manifests import write_manifest

ERROR_CASE = "simple-l1-error/truncated"
VALID_CASE = "simple-l1-core/arith-q8-visemes-expressions"


def manifest(tmp_path: Path, name: str, decode: list, *, inputs=("fba",), tools=None, extra: str = "") -> Path:
    top = {"tools": list(tools)} if tools is not None else {}
    return write_manifest(tmp_path / f"{name}.toml", decode, inputs=inputs, extra=extra, **top)


def script(tmp_path: Path, name: str, body: str) -> Path:
    """A decoder program: a Python script run as {python} SCRIPT {input} {faps_out}."""
    p = tmp_path / f"{name}.py"
    p.write_text("import os, signal, sys\n" + body)
    return p


def pydec(tmp_path, name, body, **kw) -> Path:
    s = script(tmp_path, name, body)
    return manifest(tmp_path, name, ["{python}", str(s), "{input}", "{faps_out}"], **kw)


def run_one(m: Path, full_id: str, tmp_path: Path):
    a = adapters.resolve(m)
    (r,) = run_cases(a, [case(full_id)], claim="simple@1", out_dir=tmp_path / "run", jobs=1, progress=False)
    return r


# ------------------------------------------------------------------ the error-case matrix
MATRIX = [
    # name, program body, outcome on the invalid stream, words in the message
    (
        "clean-reject",
        "sys.stderr.write('dec: error: byte 9: truncated\\n'); sys.exit(1)",
        Outcome.PASS,
        "rejected cleanly",
    ),
    (
        "rust-panic",
        "sys.stderr.write(\"thread 'main' panicked at src/parse.rs:41:9:\\nindex out of bounds\\n\"); sys.exit(101)",
        Outcome.CRASH,
        "Rust panic",
    ),
    (
        "asan",
        "sys.stderr.write('==12==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x1\\n"
        "    #0 0x4 in parse_plane dec.c:10\\n'); sys.exit(1)",
        Outcome.CRASH,
        "AddressSanitizer",
    ),
    (
        "ubsan-exit0",
        "sys.stderr.write('dec.c:88:14: runtime error: signed integer overflow: 2147483647 + 1\\n'); sys.exit(0)",
        Outcome.CRASH,
        "UndefinedBehaviorSanitizer",
    ),
    (
        "go-panic",
        "sys.stderr.write('panic: runtime error: index out of range [3] with length 3\\n\\n"
        "goroutine 1 [running]:\\nmain.parse(0x1)\\n'); sys.exit(2)",
        Outcome.CRASH,
        "Go panic",
    ),
    (
        "java-exception",
        'sys.stderr.write(\'Exception in thread "main" java.lang.ArrayIndexOutOfBoundsException: 3\\n'
        "\\tat Dec.parse(Dec.java:10)\\n'); sys.exit(1)",
        Outcome.CRASH,
        "java.lang.ArrayIndexOutOfBoundsException",
    ),
    ("segfault", "os.kill(os.getpid(), signal.SIGSEGV)", Outcome.CRASH, "SIGSEGV"),
    (
        "exit0-output",
        "open(sys.argv[2], 'w').write('2.1 x 25 1\\n' + '0 ' * 68 + '\\n0\\n'); sys.exit(0)",
        Outcome.FAIL,
        "without complaint",
    ),
    # a decoder that cannot open a file ran: its ending is its own (no set-up failure read from its text)
    ("missing-input", "open(sys.argv[1] + '.nope'); sys.exit(0)", Outcome.CRASH, "FileNotFoundError"),
    ("odd-exit", "sys.exit(7)", Outcome.FAIL, "not a documented reject code"),
]


@pytest.mark.parametrize("name,body,outcome,words", MATRIX, ids=[m[0] for m in MATRIX])
def test_error_stream_endings(tmp_path, name, body, outcome, words):
    r = run_one(pydec(tmp_path, name, body), ERROR_CASE, tmp_path)
    assert r.outcome == outcome, r.message
    assert words in r.message


def test_a_crash_report_is_named_in_the_result(tmp_path):
    r = run_one(pydec(tmp_path, "rust", MATRIX[1][1]), ERROR_CASE, tmp_path)
    assert r.crash_kind == "Rust panic"


def test_no_such_file_on_stderr_is_the_decoders_ending_not_a_set_up_failure(tmp_path):
    """Set-up failures are the harness's knowledge: a decoder that prints "No such
    file or directory" and exits 2 rejected the stream; on a valid stream that is a Fail."""
    body = "sys.stderr.write('dec: /nonexistent/in.fba: No such file or directory\\n'); sys.exit(2)"
    m = pydec(tmp_path, "lost", body)
    assert run_one(m, VALID_CASE, tmp_path).outcome == Outcome.FAIL
    assert run_one(m, ERROR_CASE, tmp_path).outcome == Outcome.PASS


def test_documented_reject_codes_are_the_manifests(tmp_path):
    m = pydec(tmp_path, "rej3", "sys.exit(3)", extra="reject_exit_codes = [3]\n")
    assert run_one(m, ERROR_CASE, tmp_path).outcome == Outcome.PASS
    assert run_one(m, VALID_CASE, tmp_path).outcome == Outcome.FAIL


# ------------------------------------------------------------------ claims
def certify_exit(tmp_path, m, claim="simple@1") -> int:
    # these rows are about the claim's verdict, which is the same with or without bubblewrap: on a
    # machine without it, certify would refuse (exit 2) before any case unless told it may
    return certify.certify(str(m), claim, tmp_path / "cert", jobs=2, speed=False, allow_unisolated=True)


def test_copying_player_cannot_certify(tmp_path, capsys):
    m = manifest(tmp_path, "copier", ["/bin/cp", "{input}", "{faps_out}"], inputs=("fap",))
    assert certify_exit(tmp_path, m) == 2
    assert "player" in capsys.readouterr().err


def test_copying_decoder_never_sees_the_fap_form(tmp_path):
    """A binary decoder that tries to copy the .fap text (the expected output) gets none."""
    m = manifest(tmp_path, "sneaky", ["/bin/cp", "{fap}", "{faps_out}"], inputs=("fba", "fap"))
    assert certify_exit(tmp_path, m) == 1


def test_decoder_that_supports_nothing_fails_the_claim(tmp_path):
    m = manifest(tmp_path, "nothing", ["/bin/sh", "-c", "exit 69", "{input}", "{faps_out}"])
    assert certify_exit(tmp_path, m) == 1
    statement = (tmp_path / "cert" / "statement.md").read_text()
    assert "could not take" in statement


def test_arithmetic_only_decoder_passes_with_dct_unverified(tmp_path):
    """The reference decoder declared without the DCT tool: the DCT cases are required and
    NotSupported, and every one rests on D8 (fbaconf's own tables), so the claim passes with the
    tool named unverified and the statement's "could not take" lists them (harness/verdict.py;
    tests/integration/test_verdict_policy.py for the rule itself). In-process through the session
    certify runs (the claim policy is the point, not the sandbox)."""
    m = tmp_path / "arith-only.toml"
    m.write_text(
        'name = "arith-only"\npython = "fbaconf.harness.refadapter:ReferenceAdapter"\n'
        'claims = ["simple@1"]\ntools = ["arithmetic", "high_level_faps"]\ninputs = ["fba"]\n'
        'outputs = ["faps"]\nfaps_format = "npz"\n'
    )
    a = adapters.resolve(m)
    suites = load_suites(names=["simple-l1-core", "simple-l1-error"])
    cases = select_cases(suites, "simple@1", [], [], only_required=True, adapter=a)
    record = execute(a, "simple@1", cases, suites, tmp_path / "run", RunOptions(jobs=2, speed=False))
    assert record.exit_code == 0 and record.verdict["verdict"] == "PASS (unverified: dct)"
    (line,) = record.missing
    dct = [c for c in cases if "dct" in (c.tools or [])]
    assert dct and line.startswith(f"{len(dct)} required case(s)") and "dct" in line, line


def test_worked_text_example_is_a_player():
    m = Path(__file__).resolve().parents[2] / "examples" / "fapplay" / "fapplay.toml"
    a = adapters.resolve(m)
    assert a.is_player


# ------------------------------------------------------------------ timing in .fap output
NTSC_CASE = "simple-l1-core/arith-ntsc-rate"


def rewriting_decoder(tmp_path, name, edit: str) -> Path:
    """The reference decoder writing .fap text, then ``edit`` applied to the text lines."""
    body = f"""from fbaconf.reference.pipeline import reference_outputs
reference_outputs(sys.argv[1], faps_out=sys.argv[2])
lines = open(sys.argv[2]).read().splitlines()
{edit}
open(sys.argv[2], "w").write("\\n".join(lines) + "\\n")
"""
    return pydec(tmp_path, name, body)


def test_truncated_header_rate_fails_naming_the_rate(tmp_path):
    m = rewriting_decoder(tmp_path, "rate30", """h = lines[0].split(); h[2] = "30"; lines[0] = " ".join(h)""")
    r = run_one(m, NTSC_CASE, tmp_path)
    assert r.outcome == Outcome.FAIL and "frame rate" in r.message and "29.97" in r.message, r.message


def test_header_rate_with_two_decimals_passes(tmp_path):
    m = rewriting_decoder(tmp_path, "rate2", """h = lines[0].split(); h[2] = "29.97"; lines[0] = " ".join(h)""")
    assert run_one(m, NTSC_CASE, tmp_path).outcome == Outcome.PASS


def test_frames_numbered_from_one_pass(tmp_path):
    edit = """for i in range(2, len(lines), 2):
    t = lines[i].split(); t[0] = str(int(t[0]) + 1); lines[i] = " ".join(t)"""
    r = run_one(rewriting_decoder(tmp_path, "from1", edit), NTSC_CASE, tmp_path)
    assert r.outcome == Outcome.PASS, r.message
    assert r.stages[0].metrics["frame_number_offset"] == 1.0


def test_frames_numbered_from_two_fail(tmp_path):
    edit = """for i in range(2, len(lines), 2):
    t = lines[i].split(); t[0] = str(int(t[0]) + 2); lines[i] = " ".join(t)"""
    assert run_one(rewriting_decoder(tmp_path, "from2", edit), NTSC_CASE, tmp_path).outcome == Outcome.FAIL


# ------------------------------------------------------------------ run and fuzz agree
SERVE = """import os, signal, sys
BODY = {body!r}
while True:
    line = sys.stdin.buffer.readline()
    if not line:
        break
    rid, size, out = line.decode().rstrip("\\n").split(" ", 2)
    data = sys.stdin.buffer.read(int(size))
    path = os.path.join(os.environ["TMPDIR"], "in.fba")
    open(path, "wb").write(data)
    sys.argv = [sys.argv[0], path, out]
    try:
        exec(BODY, {{"os": os, "signal": signal, "sys": sys}})
        code = 0
    except SystemExit as e:  # the persistent form of an exit code is the answer
        code = e.code or 0
    sys.stderr.flush()
    print(rid, code, flush=True)
"""


def _fuzz_class(m: Path, tmp_path: Path, **kw) -> str:
    """How the fuzzer classifies the same decoder on the same invalid stream."""
    target = DecoderTarget(adapters.resolve(m), tmp_path / "fz", **kw)
    data = case(ERROR_CASE).input_path("fba").read_bytes()
    try:
        v = target.execute(Entry(data, origin="error-case")).verdict
    except FuzzSetupError:
        return "Error"
    finally:
        target.close()
    if v is None:
        return "Pass"
    return {"crash": "Crash", "memory": "Crash", "hang": "Timeout"}.get(v.cls, "Fail")


@pytest.mark.parametrize("name,body,outcome,words", MATRIX, ids=[m[0] for m in MATRIX])
def test_run_and_fuzz_agree(tmp_path, name, body, outcome, words):
    """One classifier: the conformance run, the fuzzer spawning a fresh sandbox per input,
    the fuzzer's fork server and (where an input path means anything) the persistent
    protocol give the same ending."""
    m = pydec(tmp_path, name, body)
    expected = run_one(m, ERROR_CASE, tmp_path).outcome.value
    assert expected == outcome.value
    assert _fuzz_class(m, tmp_path / "spawn", fork_server=False) == expected
    assert _fuzz_class(m, tmp_path / "fork", fork_server=True) == expected
    if name != "missing-input":  # a persistent decoder gets the bytes, not a path
        s = tmp_path / f"{name}-serve.py"
        s.write_text(SERVE.format(body=body))
        p = manifest(
            tmp_path, f"{name}-serve", ["{python}", str(script(tmp_path, name, body)), "{input}", "{faps_out}"]
        )
        p.write_text(p.read_text().replace("[limits]", f'serve = ["{{python}}", "{s}"]\n[limits]'))
        assert _fuzz_class(p, tmp_path / "serve") == expected


# ------------------------------------------------------------------ baselines (deqp-runner style)
BUGGY = """from fbaconf.reference.pipeline import reference_outputs
reference_outputs(sys.argv[1], faps_out=sys.argv[2])
lines = open(sys.argv[2]).read().splitlines()
bug = os.environ.get("BUG", "")
if bug and "ntsc" in sys.argv[1]:
    t = lines[2].split()
    k = 1 if bug == "0" else len(t) - 1
    t[k] = str(int(t[k]) + 1)
    lines[2] = " ".join(t)
open(sys.argv[2], "w").write(chr(10).join(lines) + chr(10))
"""


def _junit_failures(path: Path) -> int:
    import junitparser  # noqa: PLC0415 (test-only dependency)

    xml = junitparser.JUnitXml.fromfile(str(path))
    return sum(s.failures + s.errors for s in xml)


def test_baseline_scenario(tmp_path):
    """One known bug -> exit 0, JUnit without failures, '0 new, 1 known'; the bug fixed ->
    '1 fixed', exit 1; a second bug in a known-failing case -> exit 1."""

    def run(bug: str, *extra):
        m = pydec(tmp_path, f"dec{bug or 'ok'}", BUGGY, extra=f'[env]\nBUG = "{bug}"\n')
        out = tmp_path / f"run-{bug or 'ok'}-{len(extra)}"
        r = subprocess.run(
            [
                _sys.executable,
                "-m",
                "fbaconf",
                "run",
                "--decoder",
                str(m),
                "--suite",
                "simple-l1-core",
                "--case",
                "arith-ntsc-rate",
                "--case",
                "arith-q8-visemes-expressions",
                "-o",
                str(out),
                "--no-progress",
                "--strict",
                *extra,
            ],
            capture_output=True,
            text=True,
            timeout=600,
        )
        return r, out  # --strict: the bug is in a case resting on decision D5, a provisional difference otherwise

    bfile = tmp_path / "baseline.txt"
    r, _ = run("0", "--write-baseline", str(bfile))
    assert r.returncode == 1 and "arith-ntsc-rate,Fail,faps:" in bfile.read_text(), r.stdout + r.stderr
    r, out = run("0", "--baseline", str(bfile))
    assert r.returncode == 0, r.stdout + r.stderr
    assert "baseline: 0 new, 1 known, 0 fixed, 0 flaky" in r.stdout
    assert _junit_failures(out / "junit.xml") == 0
    r, out = run("", "--baseline", str(bfile))
    assert r.returncode == 1 and "0 new, 0 known, 1 fixed" in r.stdout, r.stdout
    assert _junit_failures(out / "junit.xml") == 1
    r, _ = run("1", "--baseline", str(bfile))
    assert r.returncode == 1 and "1 new, 0 known" in r.stdout, r.stdout


def test_a_copying_player_fails_every_case_with_a_held_value(tmp_path):
    """Players get sparse .fap text and must write their state: copying the input is no play."""
    m = manifest(tmp_path, "copier", ["/bin/cp", "{input}", "{faps_out}"], inputs=("fap",))
    (s,) = load_suites(names=["simple-l1-core"])
    rs = run_cases(adapters.resolve(m), s.cases, claim="simple@1", out_dir=tmp_path / "run", jobs=2, progress=False)

    def holds(c) -> bool:  # the text holds a FAP whose value the standard fixes (not FREE)
        text = read_fap_file(c.input_path("fap"))[0]
        gold = FapFrames.load_npz(c.golden_dir() / c.goldens["faps"])
        return bool(((text.status == RETAINED) & (gold.status != FREE)).any())

    held = {c.full_id for c in s.cases if holds(c)}
    assert len(held) >= 15
    assert all(r.outcome == Outcome.FAIL for r in rs if r.case_id in held), [
        (r.case_id, r.outcome) for r in rs if r.case_id in held and r.outcome != Outcome.FAIL
    ]
