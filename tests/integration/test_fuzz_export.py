"""``fbaconf fuzz export``: seeds, dictionary and OSS-Fuzz snippet for the fuzzers vendors
run, checked by a real libFuzzer build where clang has one."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.errors import FbaconfInputError
from fbaconf.fuzz.export import MAX_SEEDS, _features, export
from fbaconf.fuzz.inputs import STRESS_BYTES
from fbaconf.profiles.checker import check_stream


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    out = tmp_path_factory.mktemp("export")
    doc = export(out, n_valid=8, seed=3)
    return out, doc


def _dict_tokens(text: str) -> list[bytes]:
    toks = []
    for line in text.splitlines():
        if line.startswith("#") or not line.strip():
            continue
        m = re.fullmatch(r'[A-Za-z0-9_]+="((?:\\x[0-9A-F]{2})+)"', line)
        assert m, f"not an AFL/libFuzzer dictionary line: {line!r}"
        toks.append(bytes(int(h, 16) for h in re.findall(r"\\x([0-9A-F]{2})", m.group(1))))
    return toks


def test_dictionary_holds_the_start_codes(exported):
    out, doc = exported
    toks = _dict_tokens((out / "fba.dict").read_text())
    # the face object, plane and end start codes of the spec notes (§1.1)
    for code in (b"\x00\x00\x01\xba", b"\x00\x00\x01\xbb", b"\x00\x00\x01\xb1"):
        assert code in toks
    assert b"\x7f\x00\x00\x01\xbb" in toks  # next_start_code() on a byte boundary (D1)
    assert len(toks) == len(set(toks)) == doc["tokens"]


def test_seeds_to_start_from_reach_every_feature_the_others_do(exported):
    """corpus/ is a cover: the syntax-model features of all the small seeds are reached by it, it
    holds at most 200 files (AFL++ warns above), and the long streams are kept apart in stress/."""
    out, doc = exported
    start = sorted((out / "corpus").glob("*.fba"))
    more = sorted((out / "more").glob("*.fba"))
    stress = sorted((out / "stress").glob("*.fba"))
    assert (len(start), len(more), len(stress)) == (doc["corpus"], doc["more"], doc["stress"])
    assert len(start) + len(more) + len(stress) == doc["seeds"] and 0 < len(start) <= MAX_SEEDS
    assert all(f.stat().st_size > STRESS_BYTES for f in stress)
    assert all(f.stat().st_size <= STRESS_BYTES for f in start + more)
    reached = set().union(*(_features(f.read_bytes()) for f in start))
    assert set().union(*(_features(f.read_bytes()) for f in more)) <= reached


def test_seed_corpus_is_valid_or_a_suite_case(exported):
    """Generated seeds and prefixes decode with the reference; suite seeds are the suite's files."""
    out, doc = exported
    files = sorted(p for d in ("corpus", "more", "stress") for p in (out / d).glob("*.fba"))
    assert len(files) == doc["seeds"] and doc["generated"] == 8
    assert len({f.read_bytes() for f in files}) == len(files)  # deduplicated
    for f in files:
        if f.name.startswith(("generated",)) or "planes" in f.name:
            decode(f.read_bytes())  # raises on an invalid stream
    errors = [f for f in files if f.name.startswith("simple-l1-error") and "planes" not in f.name]
    assert errors
    for f in errors:  # an error case: the decoder rejects it or (concealable cases) the checker does
        try:
            decode(f.read_bytes())
        except FbaconfInputError:
            continue
        assert any(d.severity == "error" for d in check_stream(f.read_bytes())), f.name


def test_cli_export(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "fbaconf", "fuzz", "export", str(tmp_path / "x"), "--valid", "2"],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "x" / "oss-fuzz" / "build.sh").read_text().startswith("#!/bin/bash")
    r = subprocess.run([sys.executable, "-m", "fbaconf", "fuzz", "export"], capture_output=True, text=True)
    assert r.returncode == 2 and "export DIR" in r.stderr


TARGET = r"""
#include <stddef.h>
#include <stdint.h>
/* counts start codes: enough to make libFuzzer load the corpus and the dictionary */
int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) {
    volatile size_t codes = 0;
    for (size_t i = 0; i + 3 < n; i++)
        if (d[i] == 0 && d[i + 1] == 0 && d[i + 2] == 1) codes++;
    return 0;
}
"""


def _libfuzzer(tmp_path: Path) -> Path:
    clang = shutil.which("clang")
    if clang is None:
        pytest.skip("clang not installed (apt-get install clang libclang-rt-14-dev)")
    src = tmp_path / "t.c"
    src.write_text(TARGET)
    exe = tmp_path / "t"
    r = subprocess.run(
        [clang, "-g", "-O1", "-fsanitize=fuzzer,address", str(src), "-o", str(exe)], capture_output=True, text=True
    )
    if r.returncode != 0:
        pytest.skip(f"clang cannot build a libFuzzer target here: {r.stderr.strip()[-200:]}")
    return exe


def test_libfuzzer_accepts_the_export(exported, tmp_path):
    out, doc = exported
    exe = _libfuzzer(tmp_path)
    r = subprocess.run(
        [str(exe), f"-dict={out / 'fba.dict'}", "-runs=300", str(out / "corpus")],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    m = re.search(r"Dictionary: (\d+) entries", r.stderr)
    assert m and int(m.group(1)) == doc["tokens"], r.stderr[-2000:]
    m = re.search(r"INFO: seed corpus: files: (\d+)", r.stderr)
    assert m and int(m.group(1)) == doc["corpus"], r.stderr[-2000:]


DOC = Path(__file__).resolve().parents[2] / "docs" / "fuzzing.md"


def _documented_lines() -> list[str]:
    """The shell block of docs/fuzzing.md that starts with the export, as a user pastes it."""
    blocks = re.findall(r"```sh\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
    block = next(b for b in blocks if b.startswith("fbaconf fuzz export fba-fuzz\ncp -r examples/fbadec"))
    return [ln for ln in block.splitlines() if ln.strip() and not ln.startswith("#")]


def test_the_documented_engine_lines_build_and_start(tmp_path, exported):
    """The lines of docs/fuzzing.md, verbatim, from a copy of the repository's layout: the planted
    bug's patch, both sanitizer builds (on the module's export: the export line is test_cli_export's);
    each engine started on the exported seeds for a few inputs (the 60 s hunt itself is measured, not
    tested: docs/fuzzing.md gives its numbers)."""
    if not (shutil.which("clang") and shutil.which("afl-clang-fast") and shutil.which("afl-fuzz")):
        pytest.skip("clang and afl++ not installed (apt-get install -y clang afl++)")
    root = Path(__file__).resolve().parents[2]
    for rel in ("examples/fbadec", "benchmarks/fuzz_bugs"):
        shutil.copytree(root / rel, tmp_path / rel, ignore=shutil.ignore_patterns("fbadec", "fbadec-asan"))
    lines = _documented_lines()
    assert len(lines) == 6, lines  # export, patch, clang build, libFuzzer run, afl-clang-fast build, afl-fuzz run
    assert lines[0] == "fbaconf fuzz export fba-fuzz"  # run by test_cli_export; its output is the module's
    shutil.copytree(exported[0], tmp_path / "fba-fuzz")
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    for line in (*lines[1:3], lines[4]):  # the patch and both builds, as they are
        r = subprocess.run(line, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)  # noqa: S602 - the documented line itself
        assert r.returncode == 0, f"{line}\n{r.stderr[-1500:]}"
    fuzz = lines[3].replace("-max_total_time=60", "-runs=200")
    r = subprocess.run(fuzz, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)  # noqa: S602
    assert "INFO: seed corpus: files:" in r.stderr, r.stderr[-1500:]
    assert "Done 200 runs" in r.stderr or "ERROR: AddressSanitizer" in r.stderr, r.stderr[-1500:]
    afl = lines[5].replace("-V 60", "-V 3")
    r = subprocess.run(afl, shell=True, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)  # noqa: S602
    stats = tmp_path / "fba-afl" / "default" / "fuzzer_stats"
    assert r.returncode == 0 and stats.is_file(), r.stdout[-1500:] + r.stderr[-1500:]
