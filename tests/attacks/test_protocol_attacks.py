"""Hostile decoders against the fuzzer's fast paths: the persistent protocol and the
fork server's reply channel. Each attack must become a finding of the input that made it —
no hang, no harness traceback, no ending moved onto another input — and the inputs around it
must be judged as usual.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.findings import replay
from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness import adapters
from fbaconf.harness.speed import measure as speed
from fbaconf.isolation import forkserver_build, sandbox

from lib.hangs import finishes
from lib.manifests import python_decoder
from lib.sandbox import needs_sandbox

STREAM = b"\x00\x00\x01\xba" + bytes(40)

# the persistent protocol, version 2: "<id> <size> <path>\n" + bytes in, "<id> <code>\n" out
SERVE = """import os, signal, sys, time
def read():
    line = sys.stdin.buffer.readline()
    if not line:
        sys.exit(0)
    rid, size, out = line.decode().rstrip('\\n').split(' ', 2)
    return int(rid), sys.stdin.buffer.read(int(size))
def answer(rid, code):
    sys.stdout.write('%d %d\\n' % (rid, code)); sys.stdout.flush()
"""


def _manifest(
    tmp_path: Path, body: str, *, serve: str | None = None, limits: str = "timeout_s = 3", equivalent: bool = False
) -> Path:
    return python_decoder(
        tmp_path,
        "t",
        body,
        serve_body=None if serve is None else SERVE + serve,
        limits=limits,
        serve_equivalent=equivalent,
    )


def _target(tmp_path: Path, m: Path, **kw) -> DecoderTarget:
    return DecoderTarget(adapters.resolve(m), tmp_path / "work", oracle=False, **kw)


def _queue(t: DecoderTarget, payloads: list[bytes]) -> list:
    """Queue every input (as the fuzzing loop does, up to its depth) and judge each in order."""
    runs = [t.start(Entry(STREAM + p)) for p in payloads]
    return [r.result().verdict for r in runs]


def _key(v) -> str | None:
    return None if v is None else f"{v.cls}:{v.signature}"


def test_a_ten_megabyte_answer_is_its_inputs_protocol_error_not_a_deadlock(tmp_path):
    serve = """while True:
    rid, data = read()
    if b'FLOOD' in data:
        sys.stdout.buffer.write(b'x' * (10 << 20)); sys.stdout.flush()
    answer(rid, 69)
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(69)", serve=serve))
    assert t.persistent
    try:
        got = _queue(t, [b"", b"FLOOD", b"", b""])
        assert [_key(v) for v in got] == [None, "unexpected-exit:protocol-error", None, None]
        assert "at most 4096" in got[1].message
    finally:
        t.close()


def test_early_and_extra_answers_are_a_protocol_error_of_that_input(tmp_path):
    """64 answers sent ahead (the ids of requests not yet sent) and an answer sent twice: each
    is the finding of the input that provoked it, the others are judged as usual (before, the
    early answers deadlocked the run and a double answer made every later input a false
    finding)."""
    serve = """while True:
    rid, data = read()
    if b'EARLY' in data:
        for k in range(64):
            answer(rid + k, 69)
        continue
    answer(rid, 69)
    if b'TWICE' in data:
        answer(rid, 69)
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(69)", serve=serve))
    try:
        got = _queue(t, [b"", b"", b"TWICE", b"", b"EARLY", b"", b"", b""])
        assert [_key(v) for v in got] == [
            None,
            None,
            "unexpected-exit:protocol-error",
            None,
            "unexpected-exit:protocol-error",
            None,
            None,
            None,
        ]
        assert all("broke the persistent protocol" in got[i].message for i in (2, 4))
    finally:
        t.close()


def test_a_decoder_that_answers_before_any_input_cannot_hang_the_run(tmp_path):
    serve = """for k in range(64):
    answer(k + 1, 0)
while True:
    rid, data = read()
    answer(rid, 69)
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(69)", serve=serve))
    try:
        got = _queue(t, [b""] * 8)
        assert {_key(v) for v in got} == {"unexpected-exit:protocol-error"}  # every process does it
    finally:
        t.close()


def test_a_decoder_that_stops_reading_its_input_is_a_hang_not_a_deadlock(tmp_path):
    """The input is written with its deadline while the answers are read: 4 MB to a decoder
    that never reads them (a full pipe) ends at the timeout, not in a deadlock. Whose hang it
    is, is confirmed: a fresh process reads the 4 MB input and answers it; the first input,
    alone, is answered and then never finished (the process neither reads again nor exits at
    the end of its input) — the hang is the first input's."""
    serve = """rid, data = read()
answer(rid, 69)
while True:
    time.sleep(1)
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(69)", serve=serve, limits="timeout_s = 1"))
    try:
        runs = [t.start(Entry(STREAM)), t.start(Entry(STREAM + bytes(4 << 20)))]
        got = finishes(lambda: [r.result().verdict for r in runs], "judging a decoder that stopped reading")
        assert [_key(v) for v in got] == ["hang:timeout", None]
    finally:
        t.close()


def test_the_speed_phase_through_a_flooding_serve_fails_fast(tmp_path):
    """bench and certify's speed phase use the same protocol where the manifest declares serve
    equivalent to decode (it is then timed first): a 10 MB answer fails the speed measurement,
    it does not hang it."""
    serve = """while True:
    rid, data = read()
    sys.stdout.buffer.write(b'%d 0 ' % rid + b'x' * (10 << 20) + b'\\n'); sys.stdout.flush()
"""
    a = adapters.resolve(_manifest(tmp_path, "sys.exit(69)", serve=serve, equivalent=True))
    (r,) = [x for x in speed.measure_claim(a, "simple@1", lengths=[2, 4], repeats=1) if x.operation == "decode"]
    assert not r.passed and "protocol" in r.message, r.message


# ------------------------------------------------------------------ the fork server's channel


@pytest.fixture(params=["c", "python"])
def server(request, monkeypatch):
    if request.param == "c" and forkserver_build.forkserver_binary() is None:
        pytest.skip("no C compiler: the fork server in C cannot be built")
    if request.param == "python":
        monkeypatch.setattr(forkserver_build, "forkserver_binary", lambda: None)
    return request.param


FORGE = """import struct
data = open(sys.argv[1], 'rb').read()
if b'FORGE' in data or b'GARBLE' in data:
    reply = b'%s 0 0.0 0.0 1000 0.001 0 0 0' % (b'0' * 24)  # a well-formed "exit 0" with a guessed nonce
    msg = struct.pack('>I', len(reply)) + reply if b'FORGE' in data else b'\\xff' * 64
    try:
        fd = os.open('/proc/%d/fd/1' % os.getppid(), os.O_WRONLY)
        os.write(fd, msg)
        sys.stderr.write('forged into the server channel\\n')
    except OSError as e:
        sys.stderr.write('cannot reach the server channel: %s\\n' % e)
    sys.stderr.flush()
    os.kill(os.getpid(), signal.SIGSEGV)
sys.exit(69)
"""


def test_the_fork_servers_channel_is_out_of_a_sandboxed_decoders_reach(tmp_path, server):
    """In the sandbox the server is non-dumpable: /proc/<ppid>/fd/1 does not open, and the
    decoder's real ending (SIGSEGV) stays with its own input."""
    needs_sandbox()
    t = _target(tmp_path, _manifest(tmp_path, FORGE))
    assert t.fork_server and not t.persistent
    try:
        got = _queue(t, [b"", b"FORGE", b"", b"GARBLE", b""])
        assert [_key(v) for v in got] == [None, "crash:SIGSEGV", None, "crash:SIGSEGV", None]
        assert "cannot reach the server channel" in got[1].detail["stderr_tail"]
    finally:
        t.close()


def test_a_reply_forged_into_the_fork_servers_channel_is_the_decoders_finding(tmp_path, server, monkeypatch):
    """Unsandboxed (a root decoder can open its parent's descriptors), the forged "exit 0" and
    the garbled bytes reach the channel: each is a protocol error of the input that wrote
    them — never a harness traceback, never a SIGSEGV moved onto the next input."""
    monkeypatch.setattr(sandbox, "_ISOLATION", "none")
    t = _target(tmp_path, _manifest(tmp_path, FORGE))
    try:
        got = _queue(t, [b"", b"FORGE", b"", b"GARBLE", b""])
        keys = [_key(v) for v in got]
        if os.geteuid() != 0:  # without root the non-dumpable server is out of reach here too
            assert keys == [None, "crash:SIGSEGV", None, "crash:SIGSEGV", None]
            return
        assert keys == [None, "unexpected-exit:protocol-error", None, "unexpected-exit:protocol-error", None]
        assert "reply channel" in got[1].message and "another request" in got[1].message
        assert "reply channel" in got[3].message
    finally:
        t.close()


def test_no_such_file_on_stderr_does_not_stop_a_fuzz_campaign(tmp_path):
    """Set-up failures are the harness's knowledge: a decoder whose every error says "No such
    file or directory" is fuzzed to the end of its budget (before, its first input stopped
    the campaign as a set-up failure)."""
    m = _manifest(tmp_path, "sys.stderr.write('dec: config.dat: No such file or directory\\n'); sys.exit(2)")
    for mode in ({"fork_server": True}, {"fork_server": False, "persistent": False}):
        t = _target(tmp_path, m, **mode)
        fz = Fuzzer(t, [Entry(STREAM, origin="seed")], FuzzConfig(seed=1, max_execs=12, progress=False, seconds=60))
        fz.run()
        assert fz.stats.execs == 12


# ------------------------------------------------------------------ answers bound to what they answer

# "done" first, then the decoding: its crash comes while the harness has the next input in flight
ANSWER_FIRST = """while True:
    rid, data = read()
    answer(rid, 2)
    sys.stderr.write('decoding %d bytes\\n' % len(data)); sys.stderr.flush()
    if b'BOOM' in data:
        sys.stderr.write('about to crash\\n'); sys.stderr.flush()
        os.kill(os.getpid(), signal.SIGSEGV)
"""
N = 5  # the crashing input's place


def _boom_seeds() -> list[Entry]:
    """Twelve inputs the reference rejects (no oracle finding); the N-th carries BOOM in the
    middle of 300 bytes."""
    seeds = [Entry(bytes([0xFF, i]) * 150, origin=f"seed-{i}") for i in range(12)]
    seeds[N] = Entry(bytes([0xFF, N]) * 70 + b"BOOM" + bytes([0xFF, N]) * 78, origin=f"seed-{N}")
    return seeds


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_serve_that_answers_before_decoding_gets_its_crash_filed_under_its_input(tmp_path, jobs):
    """Before: its crash was filed under the next input (or lost), and minimised — each test
    judged by the crash of the test before it — to a 2-byte input that does not crash it. Now
    the ending is confirmed by running inputs alone: one finding, on the BOOM input, minimised
    to the four bytes that crash it, re-run and reproduced. With -j 2 each decoder gets one
    input at a time and an input's result is given out at its answer: the crash reaches the
    fuzzer late, and is filed under its input all the same."""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(2)", serve=ANSWER_FIRST, limits="timeout_s = 5"))
    assert t.persistent
    fz = Fuzzer(
        t,
        _boom_seeds(),
        FuzzConfig(
            seed=3,
            max_execs=12,
            seconds=120,
            jobs=jobs,
            progress=False,
            minimise_seconds=60,
            minimise_tests=400,
            out_dir=tmp_path / "out",
        ),
    )
    fz.run()
    assert fz.stats.execs == 12
    (f,) = fz.findings.values()
    assert (f.verdict.cls, f.verdict.signature) == ("crash", "SIGSEGV"), f.verdict.message
    assert (f.index, f.original.origin) == (N, f"seed-{N}")
    assert "about to crash" in f.verdict.detail["stderr_tail"]
    assert f.minimal == b"BOOM" and f.min_stats.reproduced is True and f.min_stats.flaky is False
    doc = json.loads((f.path / "finding.json").read_text())
    assert doc["flaky"] is False and doc["minimisation"]["reproduced"] is True and doc["input_index"] == N
    try:
        assert replay(t, f.minimal).key == f.verdict.key
        assert replay(t, bytes([0xFF, N + 1]) * 150) is None  # the input after it is not blamed
    finally:
        t.close()


def test_one_input_at_a_time_the_late_crash_reaches_its_input_not_the_next(tmp_path):
    """``execute`` gives an input's result out at its answer; the crash that follows shows on the
    next input, which gets its own ending (none) while the crash goes to ``take_late`` under
    the input that made it."""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(2)", serve=ANSWER_FIRST, limits="timeout_s = 5"))
    try:
        boom, after = Entry(STREAM + b"BOOM", origin="boom"), Entry(STREAM + b"after", origin="after")
        got = [t.execute(e).verdict for e in (Entry(STREAM, origin="first"), boom, after)]
        assert got == [None, None, None]
        ((e, v),) = t.take_late()
        assert e is boom and _key(v) == "crash:SIGSEGV" and "alone" in v.detail["harness"]
        assert t.take_late() == []
    finally:
        t.close()


def test_a_crash_that_needs_the_processs_history_is_reported_flaky_not_minimised(tmp_path):
    """A serve that crashes on the third input any process of it receives: no input crashes it
    alone, so the finding says flaky (its own key), and minimisation — which runs each input
    on a process of its own — reports it flaky with the original input, not a two-byte input
    that does nothing."""
    serve = """n = 0
while True:
    rid, data = read()
    n += 1
    if n == 3:
        os.kill(os.getpid(), signal.SIGSEGV)
    answer(rid, 2)
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(2)", serve=serve, limits="timeout_s = 5"))
    fz = Fuzzer(
        t,
        _boom_seeds(),
        FuzzConfig(
            seed=3,
            max_execs=7,
            seconds=120,
            progress=False,
            minimise_seconds=60,
            minimise_tests=400,
            out_dir=tmp_path / "out",
        ),
    )
    fz.run()
    (f,) = fz.findings.values()
    assert (f.verdict.cls, f.verdict.signature) == ("crash", "flaky:SIGSEGV"), f.verdict.message
    assert f.verdict.detail["flaky"] is True and "neither this input" in f.verdict.message
    assert f.min_stats.flaky is True and f.min_stats.reproduced is False
    assert f.minimal == f.original.data and f.min_stats.tests == 1  # not minimised
    assert json.loads((f.path / "finding.json").read_text())["flaky"] is True


def test_a_crash_report_printed_after_the_answer_is_its_inputs(tmp_path):
    """A sanitizer report printed after the answer, the process living on: wherever it lands
    (before the harness read the answer, in the next input's stderr, or between the two
    requests), it is confirmed and filed under the input that printed it — not the next one,
    and not lost."""
    serve = """while True:
    rid, data = read()
    answer(rid, 2)
    if b'REPORT' in data:
        time.sleep(0.05)
        sys.stderr.write('==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x602 at pc 0x4005\\n'
                         '    #0 0x4005 in parse_plane dec.c:10\\n    #1 0x4006 in main dec.c:20\\n')
        sys.stderr.flush()
"""
    t = _target(tmp_path, _manifest(tmp_path, "sys.exit(2)", serve=serve, limits="timeout_s = 5"))
    try:
        got = _queue(t, [b"", b"REPORT", b"", b""])
        assert [v is None for v in got] == [True, False, True, True], got
        assert got[1].cls == "crash" and "AddressSanitizer" in got[1].message
        # one input at a time, the report written between two requests: it reaches its input late
        report = Entry(STREAM + b"REPORT", origin="report")
        assert t.execute(report).verdict is None  # given out at its answer
        time.sleep(0.5)  # the report is written before the next request
        assert t.execute(Entry(STREAM, origin="next")).verdict is None
        ((e, v),) = t.take_late()
        assert e is report and v.cls == "crash" and "AddressSanitizer" in v.message
    finally:
        t.close()
