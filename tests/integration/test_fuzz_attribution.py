"""A finding belongs to the input that caused it, in every mode: a decoder that
crashes on one input among many queued to it — through ``[commands] serve`` (the persistent
protocol, framed per input), the fork server and a fresh sandbox per input — gives the same
finding, naming that input; the finding replays, and is minimised."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fbaconf.cli import main
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.inputs import Entry
from fbaconf.fuzz.targets import PIPELINE_DEPTH, DecoderTarget
from fbaconf.harness import adapters

from lib.manifests import python_decoder

# the decoder crashes on any input holding BOOM; it rejects everything else (exit/answer 2)
DECODE = """import os, signal, sys
data = open(sys.argv[1], 'rb').read()
sys.stderr.write('decoding %d bytes\\n' % len(data))
if b'BOOM' in data:
    sys.stderr.write('about to crash\\n'); sys.stderr.flush()
    os.kill(os.getpid(), signal.SIGSEGV)
sys.exit(2)
"""
SERVE = """import os, signal, sys
while True:
    line = sys.stdin.buffer.readline()
    if not line:
        break
    rid, size, out = line.decode().rstrip('\\n').split(' ', 2)
    data = sys.stdin.buffer.read(int(size))
    sys.stderr.write('decoding %d bytes\\n' % len(data))
    if b'BOOM' in data:
        sys.stderr.write('about to crash\\n'); sys.stderr.flush()
        os.kill(os.getpid(), signal.SIGSEGV)
    print(rid, 2, flush=True)
"""
N = 5  # the crashing input's place in the queue


def _manifest(tmp_path: Path) -> Path:
    return python_decoder(tmp_path, "boom", DECODE, serve_body=SERVE, prelude="", limits="timeout_s = 5")


def _seeds() -> list[Entry]:
    """Twelve inputs the reference rejects (no oracle finding); the N-th carries the crash in
    the middle of 300 bytes of filler."""
    seeds = [Entry(bytes([0xFF, i]) * 150, origin=f"seed-{i}") for i in range(12)]
    seeds[N] = Entry(bytes([0xFF, N]) * 70 + b"BOOM" + bytes([0xFF, N]) * 78, origin=f"seed-{N}")
    return seeds


@pytest.mark.parametrize("mode", ["persistent", "fork-server", "spawn"])
def test_a_crash_among_queued_inputs_is_found_on_its_input_replays_and_is_minimised(tmp_path, mode):
    target = DecoderTarget(
        adapters.resolve(_manifest(tmp_path)),
        tmp_path / "work",
        fork_server=mode != "spawn",
        persistent=mode == "persistent",
    )
    assert (target.persistent, target.fork_server) == {
        "persistent": (True, True),
        "fork-server": (False, True),
        "spawn": (False, False),
    }[mode]
    assert target.depth == (PIPELINE_DEPTH if mode != "spawn" else 1) and N < PIPELINE_DEPTH - 1
    fz = Fuzzer(
        target,
        _seeds(),
        FuzzConfig(seed=3, max_execs=12, seconds=120, progress=False, minimise_seconds=60, minimise_tests=400),
    )
    fz.run()
    assert fz.stats.execs == 12
    (f,) = fz.findings.values()  # one finding: no crash blamed on a neighbour, no "exit-2" for the real one
    assert (f.verdict.cls, f.verdict.signature) == ("crash", "SIGSEGV"), f.verdict.message
    assert (f.index, f.original.origin) == (N, f"seed-{N}")
    assert "about to crash" in f.verdict.detail["stderr_tail"]  # its own stderr, no neighbour's
    assert f.verdict.detail["stderr_tail"].count("decoding") == 1
    assert f.minimal == b"BOOM" and f.min_stats.bytes_before == 300
    # it replays, the original and the minimal input alike, in this mode
    try:
        for data in (f.original.data, f.minimal):
            assert target.execute(Entry(data, origin="replay")).verdict.key == f.verdict.key
        assert target.execute(Entry(bytes(40), origin="replay")).verdict is None
    finally:
        target.close()


@pytest.mark.parametrize("spawn", [False, True])
def test_a_crash_file_of_any_fuzzer_is_re_minimised_to_the_fuzzers_signature(tmp_path, capsys, spawn, monkeypatch):
    """``fbaconf fuzz minimise FILE``: a crash file as AFL++ or libFuzzer write it (any name, no
    finding folder) gets the class and signature the fuzzer gives that input, and the minimal input
    the fuzzer's minimisation reaches (the 4 bytes the decoder crashes on)."""
    m = _manifest(tmp_path)
    crash = tmp_path / "id:000000,sig:11,src:000003,op:havoc"
    crash.write_bytes(_seeds()[N].data)
    work = tmp_path / "work"
    work.mkdir()
    target = DecoderTarget(adapters.resolve(str(m)), work, timeout_s=5, fork_server=not spawn, persistent=not spawn)
    try:
        expected = target.alone(Entry(crash.read_bytes(), origin="replay")).verdict
    finally:
        target.close()
    assert expected is not None and expected.cls == "crash"
    out = tmp_path / "min.fba"
    capsys.readouterr()
    argv = ["fuzz", "minimise", str(crash), "--decoder", str(m), "-o", str(out), "--json", "--timeout", "5"]
    assert main(argv + (["--spawn"] if spawn else [])) == 1
    doc = json.loads(capsys.readouterr().out)
    assert (doc["class"], doc["signature"]) == (expected.cls, expected.signature)
    assert out.read_bytes() == b"BOOM" and doc["reproduced"] and not doc["flaky"]
    monkeypatch.chdir(tmp_path)  # from a folder of its own: minimising one file leaves no run folder
    assert main(argv + (["--spawn"] if spawn else [])) == 1
    assert not (tmp_path / "fbaconf-fuzz").exists()
