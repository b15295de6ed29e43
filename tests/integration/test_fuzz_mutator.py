"""fbaconf's structure-aware mutator in C (``fuzz/fba_mutator.c``: written by ``fbaconf fuzz export``
for libFuzzer and AFL++, loaded by ``fbaconf fuzz`` through ``fuzz/cmutator.py``). It parses a
stream as a decoder does and writes it again through the arithmetic coder, so the reference decoder
(an independent implementation, in Python) is the judge: the streams the reference encoder wrote
come back bit for bit, a symbol set by hand decodes to the value the quantiser step gives it
(hand arithmetic from the FAP table), its mutations of valid streams mostly stay valid, and it runs
clean under ASan and UBSan, as it does inside the engines' processes."""

from __future__ import annotations

import glob
import random
import re
import shutil
import subprocess
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from fbaconf.bitstreams.dct import DATA_FILE
from fbaconf.bitstreams.decoder import decode
from fbaconf.bitstreams.encoder import EncoderOptions, encode
from fbaconf.bitstreams.synth import synthetic_sequence
from fbaconf.bitstreams.tables import quant_steps
from fbaconf.conformance.suite import suites_root
from fbaconf.errors import BitstreamError
from fbaconf.fuzz import cmutator
from fbaconf.fuzz.export import MUTATOR_C
from fbaconf.fuzz.model import reference_parse


def _cc() -> str:
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler")
    return cc


@pytest.fixture(scope="module")
def lib():
    _cc()
    got = cmutator.library()
    assert got is not None, "a C compiler is here, yet fba_mutator.c did not build"
    return got


def _suite_streams() -> list[tuple[str, bytes]]:
    files = sorted(glob.glob(str(suites_root() / "*" / "*.fba")))
    if not files:
        pytest.skip("suites not built")
    return [(f, Path(f).read_bytes()) for f in files]


def test_every_suite_stream_comes_back_bit_for_bit(lib):
    """Parse and write again, no mutation: the reference encoder's bytes, for every stream the
    reference decoder accepts and for the error streams too (up to the plane that fails, the rest
    kept as raw bits), or None for an error stream whose first plane does not parse."""
    same = none = 0
    for name, data in _suite_streams():
        out = cmutator.rewrite(lib, data)
        if out is None:
            assert reference_parse(data)[2] is not None, f"{name}: a valid stream the mutator cannot read"
            none += 1
            continue
        assert out == data, name
        same += 1
    assert same > 100 and none < same // 5, (same, none)


def _stream(q: int = 2):
    frames = synthetic_sequence(6, 25.0, visemes=True, expressions=True, faps=[3, 19, 48], seed=3)
    data = encode(frames, EncoderOptions(fap_quant=q, intra_period=0)).data
    return data, decode(data).frames


@pytest.mark.parametrize(("plane", "delta"), [(0, -3), (2, 3)])
def test_a_low_level_symbol_set_by_hand_decodes_to_its_value(lib, plane, delta):
    """FAP 3 of an intra plane (its value) and of a predicted plane (its difference from the plane
    before), moved by ``delta`` steps inside the ranges the stream's lists give them."""
    data, f0 = _stream(q=2)
    fap = 2  # FAP 3, 0-based
    step = int(quant_steps()[fap]) * 2
    assert f0.is_intra[0] and not f0.is_intra[1:].any()  # one intra plane, then predicted ones
    old = f0.values[plane, fap] - (f0.values[plane - 1, fap] if plane else 0)
    assert old % step == 0
    out = cmutator.edit_symbol(lib, data, plane, 7 + fap - 2, int(old // step + delta))
    assert out is not None and out != data
    f1 = decode(out).frames
    expect = f0.values.copy()
    expect[plane:, fap] += delta * step  # predicted planes add their differences to it
    np.testing.assert_array_equal(f1.values, expect)
    np.testing.assert_array_equal(f1.high, f0.high)


def test_a_viseme_select_set_by_hand(lib):
    data, f0 = _stream()
    out = cmutator.edit_symbol(lib, data, 0, 0, 9)  # viseme_select1 of the intra plane
    shifted = f0.high[:, 0] + (9 - f0.high[0, 0])
    if ((shifted < 0) | (shifted > 14)).any():  # a later difference takes it out of 0..14
        with pytest.raises(BitstreamError) as e:
            decode(out)
        assert e.value.rule == "viseme-select-range"
    else:
        np.testing.assert_array_equal(decode(out).frames.high[:, 0], shifted)


def test_mutations_of_valid_streams_mostly_stay_valid(lib):
    """A byte-level flip in an arithmetic-coded stream is almost always an error; the mutator's
    re-encoded symbols and header values are not (measured: 65 % of 1-3 stacked mutations decode)."""
    streams = [d for _n, d in _suite_streams() if "core" in _n][:40]
    rng = random.Random(5)
    ok = total = 0
    for i in range(600):
        data = streams[i % len(streams)]
        try:
            decode(data)
        except BitstreamError:
            continue
        total += 1
        try:
            decode(cmutator.mutate(lib, data, rng.getrandbits(32)))
            ok += 1
        except BitstreamError:
            pass
    assert total > 300 and ok / total > 0.5, (ok, total)


def test_dct_groups_are_parsed_mutated_and_written_again(lib):
    """A DCT-coded stream's payload (dct_provisional.toml: segment length, high-level fields, DC
    Exp-Golomb, AC events) is parsed and re-encoded, not kept as raw bits: the stream comes back bit
    for bit, most mutants decode, and some decode to other FAP values under the same header (the
    same frames, quantiser and mask: only a payload change does that; measured 187 of 2,000, and
    0 when the payload was kept raw)."""
    frames = synthetic_sequence(40, 25.0, visemes=True, expressions=True, faps=[3, 19, 48], seed=4)
    data = encode(frames, EncoderOptions(coding="dct")).data
    want = decode(data).frames
    assert cmutator.rewrite(lib, data) == data
    rng = random.Random(1)
    ok = payload = 0
    for _ in range(1000):
        try:
            got = decode(cmutator.mutate(lib, data, rng.getrandbits(32))).frames
        except BitstreamError:
            continue
        ok += 1
        same_header = (
            got.values.shape == want.values.shape
            and np.array_equal(got.fap_quant, want.fap_quant)
            and np.array_equal(got.mask, want.mask)
        )
        payload += same_header and not np.array_equal(got.values, want.values)
    assert ok > 500 and payload > 40, (ok, payload)


FBADEC_C = Path(__file__).resolve().parents[2] / "examples" / "fbadec" / "fbadec.c"


@pytest.mark.parametrize("c_file", [MUTATOR_C, FBADEC_C], ids=["fba_mutator.c", "fbadec.c"])
def test_the_ac_codewords_are_the_data_files(c_file):
    """The C copies of the AC table — the mutator's, and the example decoder's (each stands alone:
    the export ships the mutator as one file, fbadec is an implementation of its own) — are
    bitstreams/data/dct_provisional.toml's (the reference decoder reads the file), and so is the
    escape code."""
    data = resources.files("fbaconf.bitstreams").joinpath("data", DATA_FILE).read_text("utf-8")
    doc = tomllib.loads(data)["ac"]
    text = Path(c_file).read_text()
    body = text[text.index("AC_TABLE[] = {") : text.index("};", text.index("AC_TABLE[] = {"))]
    got = [
        (int(r), int(lv), int(n), int(c, 16))
        for r, lv, n, c in re.findall(r"\{(\d+), (\d+), (\d+), (0x[0-9a-f]+)\}", body)
    ]
    want = [(r, lv, len(code), int(code, 2)) for r, lv, code in doc["table"]]
    assert got == want
    assert re.search(r"#define AC_ESCAPE_CODE (0x[0-9A-F]+)", text).group(1) == hex(
        int(doc["escape"], 2)
    ).upper().replace("X", "x")
    assert f"#define AC_ESCAPE_LEN {len(doc['escape'])}" in text


DRIVER = r"""
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <stdint.h>
size_t fba_mutate(uint8_t *, size_t, size_t, unsigned int);
size_t fba_cross(const uint8_t *, size_t, const uint8_t *, size_t, uint8_t *, size_t, unsigned int);
int main(int argc, char **argv)
{
    static uint8_t buf[64][1 << 16], w[1 << 18], o[1 << 18];
    size_t len[64];
    int n = 0;
    for (int i = 1; i < argc && n < 64; i++) {
        FILE *f = fopen(argv[i], "rb");
        if (!f) return 2;
        len[n] = fread(buf[n], 1, sizeof buf[0], f);
        n++;
        fclose(f);
    }
    unsigned s = 1;
    for (int it = 0; it < 4000; it++) {
        int k = it % n;
        s = s * 1103515245u + 12345u;
        size_t m = len[k] < 40 ? len[k] : len[k] - s % 40; /* truncated inputs too */
        memcpy(w, buf[k], m);
        for (int d = 0; d < 3; d++) {
            s = s * 1103515245u + 12345u;
            if (s % 7 == 0) { m = fba_cross(w, m, buf[s % n], len[s % n], o, sizeof o, s); memcpy(w, o, m); }
            else m = fba_mutate(w, m, sizeof w, s);
        }
    }
    puts("done");
    return 0;
}
"""


def test_the_mutator_is_clean_under_asan_and_ubsan(tmp_path):
    names = [n for n, _d in _suite_streams()]
    streams = (names[::7][:56] + [n for n in names if "dct" in Path(n).name])[:64]  # DCT groups too
    (tmp_path / "drv.c").write_text(DRIVER)
    exe = tmp_path / "drv"
    flags = ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
    r = subprocess.run([_cc(), *flags, str(tmp_path / "drv.c"), str(MUTATOR_C), "-o", str(exe)], capture_output=True)
    if r.returncode != 0:
        pytest.skip(f"no sanitizer runtime for this compiler: {r.stderr[-300:]!r}")
    r = subprocess.run([str(exe), *streams], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "done", r.stderr[-2000:]


def test_both_engines_builds_compile(tmp_path):
    cc = _cc()
    subprocess.run(
        [
            cc,
            "-O2",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-shared",
            "-fPIC",
            "-DFBA_AFL",
            str(MUTATOR_C),
            "-o",
            str(tmp_path / "m.so"),
        ],
        check=True,
    )
    clang = shutil.which("clang")
    if clang is None:
        pytest.skip("clang not installed: the libFuzzer build is not checked")
    target = tmp_path / "t.c"
    target.write_text(
        "#include <stdint.h>\n#include <stddef.h>\n"
        "int LLVMFuzzerTestOneInput(const uint8_t *d, size_t n) { (void)d; (void)n; return 0; }\n"
    )
    mo = tmp_path / "m.o"  # built on its own, uninstrumented, as the docs say
    subprocess.run([clang, "-O2", "-c", "-DFBA_LIBFUZZER", str(MUTATOR_C), "-o", str(mo)], check=True)
    r = subprocess.run(
        [clang, "-fsanitize=fuzzer", str(target), str(mo), "-o", str(tmp_path / "fz")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr[-1500:]
    r = subprocess.run([str(tmp_path / "fz"), "-runs=2000"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "Done 2000 runs" in r.stderr, r.stderr[-1500:]
