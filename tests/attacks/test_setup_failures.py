"""Set-up failures recognised by behaviour, not by wording (item 4): a decoder that
cannot run as set up fails every case the same way, and each read as "a reject: a valid stream
was rejected". The canary (harness/preflight.py, isolation/setup.py) runs the decoder on the
claim's simplest valid stream before the cases; after them, identical endings with no decoding are one set-up error
too. Either way: exit 2, the program's stdout and stderr, the limits in force, the likely fix —
no case counted, no certificate. The decoders here are written for it; none prints a runtime's
known words."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from fbaconf.conformance.provisional import rests_on
from fbaconf.conformance.suite import CaseKind, load_suites
from fbaconf.harness import adapters, preflight
from fbaconf.harness.results import CaseResult, Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.harness.selection import select_cases
from fbaconf.isolation import endings, sandbox, setup

from lib.sandbox import needs_sandbox


def decoder(tmp_path: Path, name: str, body: str, claim="simple@1") -> Path:
    d = tmp_path / name
    d.mkdir()
    (d / f"{name}.py").write_text("import os, sys\nIN, OUT = sys.argv[1], sys.argv[2]\n" + body)
    m = d / f"{name}.toml"
    m.write_text(
        f'name = "{name}"\nclaims = ["{claim}"]\ninputs = ["fba"]\noutputs = ["faps"]\nfaps_format = "npz"\n'
        f'[commands]\ndecode = ["{{python}}", "{{manifest_dir}}/{name}.py", "{{input}}", "{{faps_out}}"]\n'
        "[limits]\ntimeout_s = 30\n"
    )
    return m


def fbaconf(*args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "fbaconf", *map(str, args)], capture_output=True, text=True, timeout=600
    )


BROKEN = """
print("acme: licence server unreachable (this line is on stdout)")
print("acme: giving up", file=sys.stderr)
sys.exit(1)
"""


def test_a_decoder_that_cannot_start_is_one_set_up_error_not_a_fail_per_case(tmp_path):
    needs_sandbox()
    m = decoder(tmp_path, "acme", BROKEN)
    r = fbaconf("run", "--decoder", m, "--claim", "simple@1", "--suite", "simple-l1-core", "-o", tmp_path / "run")
    assert r.returncode == 2, r.stdout + r.stderr
    err = r.stderr
    assert err.count("fbaconf run: error: ") == 1 and "acme cannot run as set up" in err
    assert "acme exited with code 1, a reject" in err  # the decoder's name, not the interpreter's
    assert "| acme: licence server unreachable (this line is on stdout)" in err and "| acme: giving up" in err
    assert "limits in force: time: 30 s" in err and "likely fix:" in err and "--sandbox-ro" in err
    assert "Traceback" not in err and not (tmp_path / "run" / "results.jsonl").exists()  # no case counted
    r = fbaconf("certify", "--decoder", m, "--claim", "simple@1", "--no-speed", "-o", tmp_path / "pkg")
    assert r.returncode == 2 and "acme cannot run as set up" in r.stderr
    assert not (tmp_path / "pkg" / "certificate.json").exists()


def test_the_canary_is_the_smallest_required_valid_stream_the_decoder_can_take():
    a = adapters.resolve("reference")
    required = [c for c in select_cases(load_suites(), "simple@1", [], [], True, a) if c.kind == CaseKind.DECODE]
    # not one a provisional decision decides: a decoder following another reading may rightly reject it
    plain = [c for c in required if not rests_on(c)]
    smallest = min(plain, key=lambda c: (c.input_path("fba").stat().st_size, c.full_id))
    assert preflight.canary_case(a, "simple@1").full_id == smallest.full_id
    assert len(plain) < len(required) and not rests_on(preflight.canary_case(a, "simple@1"))
    dct_less = adapters.resolve("reference")
    dct_less.tools = ["arithmetic", "high_level_faps"]  # it cannot take a DCT case: never its canary
    assert "dct" not in (preflight.canary_case(dct_less, "simple@1").tools or [])


def test_the_canary_passes_a_decoder_that_decodes_and_one_that_declines(tmp_path):
    needs_sandbox()
    took = preflight.canary(adapters.resolve("reference"), "predictable@2")
    assert took is not None and took > 0  # the seconds it added (reported, never a budget)
    assert preflight.canary(adapters.resolve("reference-inprocess"), "predictable@2") is None  # in-process: none
    declines = decoder(tmp_path, "declines", "sys.exit(69)\n")
    assert preflight.canary(adapters.resolve(declines), "simple@1") is not None  # NotSupported: the cases decide


DECODES_ONLY_THE_CANARY = """
import shutil
name = os.path.basename(IN)
if name == os.environ["CANARY"]:
    from fbaconf.reference.pipeline import reference_outputs
    reference_outputs(IN, faps_out=OUT)
    sys.exit(0)
print(f"acme: cannot map the model for {IN}", file=sys.stderr)
sys.exit(1)
"""


def test_every_case_ending_the_same_way_without_a_decoding_is_one_set_up_error(tmp_path):
    """The canary passes (the decoder decodes that one stream), then every case selected ends the
    same way — its stderr naming each case's own file — and none decodes."""
    needs_sandbox()
    a0 = adapters.resolve("reference")
    stem = preflight.canary_case(a0, "simple@1").id
    m = decoder(tmp_path, "acme", DECODES_ONLY_THE_CANARY)
    m.write_text(m.read_text() + f'[env]\nCANARY = "{stem}.fba"\n')
    r = fbaconf(
        "run",
        "--decoder",
        m,
        "--claim",
        "simple@1",
        "--case",
        "simple-l1-core/arith-q*",
        "--case",
        "simple-l1-error/*marker*",
        "-o",
        tmp_path / "run",
        "-j",
        "2",
    )
    assert r.returncode == 2, r.stdout + r.stderr
    assert "every one of the" in r.stderr and "ended the same way, none decoded" in r.stderr
    assert "| acme: cannot map the model for" in r.stderr and "likely fix:" in r.stderr
    assert not (tmp_path / "run" / "report.json").exists()


def _result(case_id, outcome, exit_code=1, stderr="", **kw):
    return CaseResult(
        case_id=case_id,
        suite=case_id.split("/")[0],
        claim="simple@1",
        outcome=outcome,
        exit_code=exit_code,
        stderr_tail=stderr,
        **kw,
    )


def test_identical_endings_are_judged_on_endings_not_on_outcomes():
    """An invalid stream's reject passes and a valid one's fails: the same ending, two outcomes.
    Different endings, a decoding, or no valid stream at all: no set-up error."""
    (core,) = load_suites(names=["simple-l1-core"])
    (err,) = load_suites(names=["simple-l1-error"])
    valid, invalid = core.cases[:2], err.cases[:2]
    a = adapters.resolve("reference")
    same = [
        _result(c.full_id, Outcome.FAIL, stderr=f"cannot open /x/run/work/case-{i}ab/in/{c.id}.fba")
        for i, c in enumerate(valid)
    ]
    same += [
        _result(c.full_id, Outcome.PASS, stderr=f"cannot open /x/run/work/case-9{i}/in/{c.id}.fba")
        for i, c in enumerate(invalid)
    ]
    ids = {c.full_id for c in valid}

    def judged(results, valid_ids=ids):
        return setup.identical(a.name, a.limits, results, valid_ids)

    assert "every one of the 4 cases it ran ended the same way, none decoded" in judged(same)
    differs = same[:-1] + [_result(invalid[-1].full_id, Outcome.PASS, stderr="bad marker at byte 4")]
    assert judged(differs) is None
    decoded = same[:-1] + [_result(valid[0].full_id, Outcome.FAIL, exit_code=0)]
    assert judged(decoded) is None
    only_invalid = [r for r in same if r.outcome == Outcome.PASS]
    assert judged(only_invalid, set()) is None  # an honest rejecter of an error suite


def test_the_ending_names_the_decoder_not_the_program():
    res = sandbox.ProcResult(["/usr/bin/java", "-jar", "x.jar"], 1, stderr_tail="no")
    assert (
        endings.classify(res, sandbox.Limits(), name="acme-java").message == "acme-java exited with code 1, a "
        "reject; stderr: no"
    )
    assert endings.classify(res, sandbox.Limits()).message.startswith("java exited")  # no name: the program


LOUD = """
sys.stdout.write("o" * 9000 + "END-OUT\\n")
sys.stderr.write("e" * 9000 + "END-ERR\\n")
os.symlink(os.environ["TARGET"], "stderr.txt")  # the harness must not write through it
sys.exit(3)
"""


def test_keep_workdirs_keeps_each_cases_whole_stdout_and_stderr(tmp_path):
    needs_sandbox()
    target = tmp_path / "outside.txt"
    target.write_text("untouched")
    m = decoder(tmp_path, "loud", LOUD)
    m.write_text(m.read_text() + f'[env]\nTARGET = "{target}"\n')
    (s,) = load_suites(names=["simple-l1-core"])
    (r,) = run_cases(
        adapters.resolve(m),
        [c for c in s.cases if c.id == "dct-q4"],
        claim="simple@1",
        out_dir=tmp_path / "run",
        jobs=1,
        progress=False,
        keep_workdirs=True,
    )
    assert r.outcome == Outcome.FAIL and "loud exited with code 3" in r.message
    (kept,) = list((tmp_path / "run" / "work").glob("case-*"))
    out, err = (kept / "stdout.txt"), (kept / "stderr.txt")
    assert not err.is_symlink() and target.read_text() == "untouched"
    assert out.read_text() == "o" * 9000 + "END-OUT\n" and err.read_text() == "e" * 9000 + "END-ERR\n"
    assert json.loads(json.dumps(r.to_json()))["stderr_tail"].endswith("END-ERR\n")
