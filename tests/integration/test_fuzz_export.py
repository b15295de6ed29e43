"""``fbaconf fuzz export``: seeds, dictionary and OSS-Fuzz snippet for the fuzzers vendors
run, checked by a real libFuzzer build where clang has one."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fbaconf.bitstreams.decoder import decode
from fbaconf.errors import FbaconfInputError
from fbaconf.fuzz.export import export
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


def test_seed_corpus_is_valid_or_a_suite_case(exported):
    """Generated seeds and prefixes decode with the reference; suite seeds are the suite's files."""
    out, doc = exported
    files = sorted((out / "corpus").glob("*.fba"))
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
    assert m and int(m.group(1)) == doc["seeds"], r.stderr[-2000:]
