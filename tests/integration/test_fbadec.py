"""The second, independent decoder of the face-object stream (examples/fbadec).

Written in C11 by a helper whose brief was the spec notes, the seeds and the DCT mode's
specification only (examples/fbadec/NOTES.md says what it read and what it did not). Built
here from source into a temporary folder (skipped without a C compiler), it must: pass every
case simple@2 requires, through the harness and its sandbox; agree with the reference on
generated and mutated streams (the fuzzer's oracle is the reference: wrong output on a valid
stream, acceptance of an invalid one and every crash are findings); and give no sanitizer
report (ASan + UBSan) on any suite stream or mutation of one.
"""

from __future__ import annotations

import random
import runpy
import shutil
import subprocess
import threading
from pathlib import Path

import pytest

from fbaconf.bitstreams.frames import FapFrames
from fbaconf.conformance.suite import load_suites
from fbaconf.fuzz.corpus import default_seeds
from fbaconf.fuzz.engine import FuzzConfig, Fuzzer
from fbaconf.fuzz.targets import DecoderTarget
from fbaconf.harness import adapters
from fbaconf.harness.results import Outcome
from fbaconf.harness.runner import run_cases
from fbaconf.harness.selection import required_for
from fbaconf.harness.speed import measure as speed

SRC = Path(__file__).resolve().parents[2] / "examples" / "fbadec"


@pytest.fixture(scope="module")
def fbadec(tmp_path_factory):
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler")
    d = tmp_path_factory.mktemp("fbadec")
    srcs = [str(SRC / "fbadec.c"), str(SRC / "main.c")]
    flags = ["-std=c11", "-Wall", "-Wextra", "-Werror", "-I", str(SRC)]
    r = subprocess.run([cc, "-O2", *flags, "-o", str(d / "fbadec"), *srcs, "-lm"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    asan = subprocess.run(
        [
            cc,
            "-O1",
            "-g",
            "-fsanitize=address,undefined",
            "-fno-sanitize-recover=all",
            *flags,
            "-o",
            str(d / "fbadec-asan"),
            *srcs,
            "-lm",
        ],
        capture_output=True,
        text=True,
    )
    shutil.copy(SRC / "fbadec.toml", d / "fbadec.toml")
    return d, asan.returncode == 0


def test_it_passes_every_case_simple_2_requires(fbadec, tmp_path):
    d, _ = fbadec
    a = adapters.resolve(str(d / "fbadec.toml"))
    cases = [c for s in load_suites() for c in s.cases if required_for("simple@2", c, a)]
    res = run_cases(a, cases, claim="simple@2", out_dir=tmp_path / "run", jobs=2, progress=False)
    bad = [(r.case_id, r.outcome.value, r.message[:200]) for r in res if r.outcome != Outcome.PASS]
    assert len(res) >= 45 and bad == []


def _mutations(data: bytes, rng: random.Random, n: int):
    for _ in range(n):
        b = bytearray(data)
        k = rng.randrange(4)
        if k == 0 and b:
            for _ in range(rng.randint(1, 8)):
                i = rng.randrange(len(b) * 8)
                b[i // 8] ^= 0x80 >> (i % 8)
        elif k == 1:
            b = b[: rng.randrange(len(b) + 1)]
        elif k == 2 and b:
            i = rng.randrange(len(b))
            b[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 6)))
        elif b:
            i = rng.randrange(len(b))
            b[i] = rng.choice((0, 0xFF, rng.randrange(256)))
        yield bytes(b)


def _serve_each(binary: Path, inputs: list[bytes], out: Path, log: Path) -> tuple[list[int], int | None]:
    """Every input through one ``--serve`` process (the persistent protocol, docs/fuzzing.md):
    (the answer code of each input answered, the exit status). A sanitizer report ends the
    process at the input that caused it; stderr goes to ``log`` (a pipe would fill)."""
    codes: list[int] = []
    with open(log, "wb") as err:
        p = subprocess.Popen([str(binary), "--serve"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err)
        watchdog = threading.Timer(300, p.kill)
        watchdog.start()
        try:
            for i, data in enumerate(inputs):
                try:
                    p.stdin.write(f"{i} {len(data)} {out}\n".encode() + data)
                    p.stdin.flush()
                except BrokenPipeError:
                    break
                line = p.stdout.readline().split()
                if len(line) != 2 or line[0] != str(i).encode():
                    break
                codes.append(int(line[1]))
            p.stdin.close()
            rc = p.wait(timeout=60)
        finally:
            watchdog.cancel()
            if p.poll() is None:
                p.kill()
                p.wait()
                rc = None
    return codes, rc


def test_no_sanitizer_report_on_any_suite_stream_or_mutation(fbadec, tmp_path):
    """Each distinct suite stream through the command line, one process each; then those and six
    mutations of each through one ``--serve`` process (the same decoder core, 25 ms of
    sanitizer start-up saved per input)."""
    d, built = fbadec
    if not built:
        pytest.skip("the compiler cannot build with -fsanitize=address,undefined here")
    rng = random.Random(20)
    # each distinct stream once (a case's image-only views share its input file)
    streams = list(
        dict.fromkeys(
            p.read_bytes()
            for s in load_suites()
            for c in s.cases
            for p in ([c.input_path("fba")] if c.input_path("fba") else [])
        )
    )
    fin, out = tmp_path / "in.fba", tmp_path / "out.npz"
    for data in streams:
        fin.write_bytes(data)
        r = subprocess.run([str(d / "fbadec-asan"), str(fin), str(out)], capture_output=True, text=True, timeout=30)
        assert r.returncode in (0, 1) and "Sanitizer" not in r.stderr and "runtime error" not in r.stderr, (
            r.returncode,
            r.stderr[-800:],
        )
    inputs = streams + [m for s in streams for m in _mutations(s, rng, 6)]
    codes, rc = _serve_each(d / "fbadec-asan", inputs, out, tmp_path / "serve.log")
    report = (tmp_path / "serve.log").read_text(errors="replace")
    assert "Sanitizer" not in report and "runtime error" not in report, (
        f"input {len(codes)} of {len(inputs)}",
        report[-1500:],
    )
    assert rc == 0 and len(codes) == len(inputs) and set(codes) <= {0, 1}, (rc, len(codes), report[-800:])
    assert codes.count(0) >= len(streams) // 2 and codes.count(1) > 0  # both valid and invalid inputs were decoded


def test_a_sanitizer_report_in_serve_mode_is_seen_and_placed(tmp_path):
    """The serve sweep's own check: a --serve process that aborts with a report on its third input
    is seen (the report, and the input it stopped at)."""
    fake = tmp_path / "fake-serve"
    fake.write_text(
        '#!/bin/sh\nn=0\nwhile read -r id size out; do\n  head -c "$size" >/dev/null\n'
        "  if [ \"$n\" = 2 ]; then echo 'ERROR: AddressSanitizer: heap-buffer-overflow' >&2; exit 1; fi\n"
        '  echo "$id 0"; n=$((n+1))\ndone\n'
    )
    fake.chmod(0o755)
    codes, rc = _serve_each(fake, [b"abc", b"", b"xyz", b"0123"], tmp_path / "o.npz", tmp_path / "log")
    assert codes == [0, 0] and rc == 1 and "AddressSanitizer" in (tmp_path / "log").read_text()


def test_differential_fuzz_short(fbadec, tmp_path):
    """A short differential run in CI (the long one: `fbaconf fuzz --decoder
    examples/fbadec/fbadec.toml --seconds 600`): no divergence from the reference."""
    d, _ = fbadec
    target = DecoderTarget(adapters.resolve(str(d / "fbadec.toml")), tmp_path / "work", timeout_s=5.0)
    fz = Fuzzer(
        target,
        default_seeds(),
        FuzzConfig(seed=4, seconds=120, progress=False, max_execs=1500, coverage_every=4, minimise_seconds=5),
    )
    assert target.persistent  # the manifest's [commands] serve: fbadec --serve
    fz.run()
    assert fz.stats.execs == 1500
    assert {k: f.verdict.message[:200] for k, f in fz.findings.items()} == {}


def test_hand_vectors(fbadec, tmp_path):
    """The hand-annotated vectors (tests/vectors): the independent decoder gives the frames
    worked out by hand from the spec notes, and rejects the invalid ones."""

    d, _ = fbadec
    vec = runpy.run_path(str(Path(__file__).parents[1] / "lib" / "vectors.py"))

    def run(data: bytes):
        fin, out = tmp_path / "v.fba", tmp_path / "v.npz"
        out.unlink(missing_ok=True)
        fin.write_bytes(data)
        r = subprocess.run([str(d / "fbadec"), str(fin), str(out)], capture_output=True, text=True, timeout=30)
        if r.returncode == 1:
            raise ValueError(r.stderr.strip())
        assert r.returncode == 0, r.stderr
        return FapFrames.load_npz(out)

    for name in vec["NAMES"]:
        vec["check_vector"](name, run, exact_error=False)


def test_speed_is_measured_through_the_persistent_protocol_or_by_spawning(fbadec, tmp_path):
    """fbadec serves the persistent protocol: its decode speed is measured through one process
    (its outputs checked against decode's first) or, asked to, by spawning one per sample; both
    give a fitted per-frame cost from outputs judged on content. How the two compare in time is
    a benchmark's (benchmarks/bench_fbadec.py prints the ratio and the start-ups), not a test's."""
    d, _ = fbadec
    a = adapters.resolve(str(d / "fbadec.toml"))
    lengths = [1000, 20000]  # 19,000 frames apart: ~0.3 s of decoding against milliseconds of start-up noise
    pers = speed.measure(a, "simple@2", "decode", lengths=lengths, repeats=1, work_dir=tmp_path / "p")
    spawn = speed.measure(
        a, "simple@2", "decode", lengths=lengths, repeats=1, work_dir=tmp_path / "s", persistent=False
    )
    assert "persistent protocol" in pers.message and "persistent protocol" not in spawn.message
    for r in (pers, spawn):
        assert sorted({x["frames"] for x in r.samples}) == lengths and r.per_frame_s > 0, r.message
        assert "not the decoding" not in r.message and "failed" not in r.message, r.message
