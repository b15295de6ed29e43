"""fbaconf's structure-aware mutator in C (``fuzz/fba_mutator.c``, written by ``fbaconf fuzz
export`` for libFuzzer and AFL++): the fields it rewrites are the header fields fbaconf's syntax
model locates (``fuzz/model.py``, an independent walk in Python), bit for bit; its plane edits
keep the stream a face object; both engines' builds of it compile."""

from __future__ import annotations

import ctypes
import glob
import shutil
import subprocess
from pathlib import Path

import pytest

from fbaconf.conformance.suite import suites_root
from fbaconf.fuzz.export import MUTATOR_C
from fbaconf.fuzz.model import stream_model


def _cc() -> str:
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler")
    return cc


@pytest.fixture(scope="module")
def mutator(tmp_path_factory):
    so = tmp_path_factory.mktemp("mutator") / "fba_mutator.so"
    subprocess.run(
        [_cc(), "-O2", "-Wall", "-Wextra", "-Werror", "-shared", "-fPIC", str(MUTATOR_C), "-o", str(so)], check=True
    )
    lib = ctypes.CDLL(str(so))
    lib.fba_mutate.restype = ctypes.c_size_t
    lib.fba_mutate.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_size_t, ctypes.c_uint]
    return lib


def _mutate(lib, data: bytes, seed: int, room: int = 4096) -> bytes:
    buf = ctypes.create_string_buffer(data, len(data) + room)
    n = lib.fba_mutate(buf, len(data), len(data) + room, seed)
    return buf.raw[:n]


def _streams() -> list[bytes]:
    files = sorted(glob.glob(str(suites_root() / "simple-l1-core" / "*.fba")))
    if not files:
        pytest.skip("suites not built")
    return [Path(f).read_bytes() for f in files[:12]]


def test_a_field_mutation_rewrites_one_header_field_the_syntax_model_knows(mutator):
    checked = 0
    for data in _streams():
        m = stream_model(data)
        # the planes the C walker sees: those after a start code (a predicted plane without one starts
        # where an arithmetic block ends, which only a decoder knows)
        after_code = {
            p.header_offset
            for p in m.planes
            if data[p.header_offset // 8 - 4 : p.header_offset // 8] in (b"\x00\x00\x01\xbb", b"\x00\x00\x01\xba")
        }
        fields = {(f.offset, f.width) for f in m.fields if any(f.offset >= h for h in after_code)}
        for seed in range(60):
            out = _mutate(mutator, data, seed)
            if len(out) != len(data) or out == data:
                continue  # a plane edit or nothing
            diff = int.from_bytes(out, "big") ^ int.from_bytes(data, "big")
            nbits = len(data) * 8
            bits = [nbits - 1 - i for i in range(nbits) if diff >> i & 1]
            lo, hi = min(bits), max(bits)
            assert any(off <= lo and hi < off + w for off, w in fields), (seed, lo, hi)
            checked += 1
    assert checked > 100


def test_plane_edits_keep_a_face_object(mutator):
    for data in _streams():
        for seed in range(40):
            out = _mutate(mutator, data, seed)
            assert out[:4] == b"\x00\x00\x01\xba"


def test_both_engines_builds_compile(tmp_path):
    cc = _cc()
    subprocess.run(
        [cc, "-O2", "-shared", "-fPIC", "-DFBA_AFL", str(MUTATOR_C), "-o", str(tmp_path / "m.so")], check=True
    )
    clang = shutil.which("clang")
    if clang is None:
        pytest.skip("clang not installed: the libFuzzer build is not checked")
    target = tmp_path / "t.c"
    target.write_text(
        "#include <stdint.h>\n#include <stddef.h>\n"
        "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void)d; (void)n; return 0; }\n"
    )
    r = subprocess.run(
        [clang, "-fsanitize=fuzzer", "-DFBA_LIBFUZZER", str(target), str(MUTATOR_C), "-o", str(tmp_path / "fz")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-1500:]
    r = subprocess.run([str(tmp_path / "fz"), "-runs=2000"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Done 2000 runs" in r.stderr, r.stderr[-1500:]
