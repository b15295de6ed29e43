"""``fbaconf fuzz export DIR``: what the coverage-guided fuzzers vendors already run need
from fbaconf — a seed corpus, a dictionary of the syntax's tokens and an OSS-Fuzz build
snippet — so a decoder's own libFuzzer / AFL++ / OSS-Fuzz target starts from streams that
reach every part of the syntax instead of from nothing.

Layout::

    DIR/corpus/<origin>-<sha1:12>.fba   the seeds to start from: the smallest streams that together
                                        reach every feature of the syntax model, at most 200
    DIR/more/                           the other small seeds (suite streams, 1–3-plane prefixes,
                                        generated valid streams; deduplicated by content)
    DIR/stress/                         the long streams (over 8 KiB: thousands of frames), kept
                                        apart: at engine defaults a seed must decode in a few ms
    DIR/fba.dict                        AFL++/libFuzzer dictionary (byte-aligned tokens)
    DIR/oss-fuzz/build.sh               OSS-Fuzz build snippet (seed corpus zip + dictionary)
    DIR/fuzz_target.c                   a libFuzzer target template (LLVMFuzzerTestOneInput)
    DIR/fuzz_target_fbadec.c            the same around examples/fbadec (fbaconf's own C decoder)
    DIR/fba_mutator.c                   the structure-aware mutator for libFuzzer and AFL++
    DIR/README.md                       how to use them
"""

from __future__ import annotations

import hashlib
import random
import re
import shutil
from pathlib import Path

from .choosers import RandomChooser
from .corpus import conformance_seeds, short_prefixes
from .inputs import STRESS_BYTES, Entry, gen_valid
from .model import DICTIONARY, features_of

MUTATOR_C = Path(__file__).with_name("fba_mutator.c")  # the structure-aware mutator, in C
MAX_SEEDS = 200  # AFL++ warns of "far too many input files" above this; libFuzzer reads them all first

# Byte sequences worth splicing in, beyond the start codes of the syntax model's dictionary:
# each is (bytes, what). Bit patterns narrower than a byte (plane flags, mask types) cannot be
# dictionary tokens; the start codes and the aligned stuffing are what byte-level fuzzers miss.
EXTRA_TOKENS: list[tuple[bytes, str]] = [
    (b"\x7f\x00\x00\x01\xbb", "aligned stuffing + plane start code"),
    (b"\x00\x00\x01\xba\xa0", "object start code + intra plane, FAPs only"),
    (b"\x00\x00\x00", "three zero bytes (start-code emulation, D9)"),
]


def dictionary_tokens() -> list[tuple[str, bytes]]:
    """(name, bytes) of every byte-aligned token of the syntax (AFL++/libFuzzer dictionary)."""
    out: list[tuple[str, bytes]] = []
    seen: set[bytes] = set()
    for value, width, what in DICTIONARY:
        if width % 8:
            continue
        out.append((what, value.to_bytes(width // 8, "big")))
    out += [(what, b) for b, what in EXTRA_TOKENS]
    uniq = []
    for name, b in out:
        if b not in seen:
            seen.add(b)
            uniq.append((name, b))
    return uniq


def dictionary_text() -> str:
    """The dictionary in the AFL++/libFuzzer format: ``name="\\xHH..."``, one per line."""
    lines = ["# fbaconf: tokens of the MPEG-4 face object stream syntax (fbaconf fuzz export)"]
    for i, (what, b) in enumerate(dictionary_tokens()):
        name = re.sub(r"[^a-z0-9]+", "_", what.lower()).strip("_")[:40] or "token"
        lines.append(f"# {what}")
        lines.append(f'{name}_{i}="' + "".join(f"\\x{x:02X}" for x in b) + '"')
    return "\n".join(lines) + "\n"


def seed_corpus(n_valid: int = 64, seed: int = 0) -> list[Entry]:
    """Suite streams, their short prefixes and ``n_valid`` generated valid streams."""
    seeds = conformance_seeds()
    out = seeds + short_prefixes(seeds)
    ch = RandomChooser(random.Random(seed))
    for i in range(n_valid):
        e = gen_valid(ch)
        e.origin = f"generated-{seed}-{i}"
        out.append(e)
    return out


BUILD_SH = """#!/bin/bash -eu
# OSS-Fuzz build snippet (fbaconf fuzz export). Put fba.dict and corpus/ next to this
# project's sources; build your target as usual, then ship the seeds and the dictionary
# under the target's name so the fuzzing engines pick them up.
TARGET=${TARGET:-fba_decoder_fuzzer}
$CC $CFLAGS -c fuzz_target.c -o fuzz_target.o
$CXX $CXXFLAGS fuzz_target.o your_decoder.a $LIB_FUZZING_ENGINE -o "$OUT/$TARGET"
cp fba.dict "$OUT/$TARGET.dict"
(cd corpus && zip -q -j "$OUT/${TARGET}_seed_corpus.zip" ./*.fba)
"""

TARGET_C = """/* A libFuzzer target for a face object stream decoder (fbaconf fuzz export).
 * Replace decode_face_stream() with your decoder's entry point: it must accept any bytes,
 * reject invalid streams with an error return, and never crash, hang or leak.
 *
 *   clang -g -O1 -fsanitize=fuzzer,address,undefined fuzz_target.c your_decoder.c -o fba_fuzzer
 *   mkdir -p new
 *   ./fba_fuzzer -dict=fba.dict -timeout=10 -entropic_scale_per_exec_time=1 -artifact_prefix=new/ new corpus
 */
#include <stddef.h>
#include <stdint.h>

int decode_face_stream(const uint8_t *data, size_t size);  /* your decoder */

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    decode_face_stream(data, size);
    return 0;  /* libFuzzer: always 0; crashes and sanitizer reports are the findings */
}
"""

TARGET_FBADEC_C = """/* The libFuzzer target of fbaconf's own C decoder, examples/fbadec (see docs/fuzzing.md). */
#include <stddef.h>
#include <stdint.h>

#include "fbadec.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    fba_result res;
    fba_error err;
    if (fba_decode(data, size, &res, &err) == 0) fba_result_free(&res);
    return 0;
}
"""

README = """# Seeds and a dictionary for coverage-guided fuzzing of a face object stream decoder

Made by `fbaconf fuzz export` ({n} seed streams: {suite} conformance streams, {prefixes}
short prefixes of them, {generated} generated valid streams; {tokens} dictionary tokens).

| file | for |
|---|---|
| `corpus/` | {start} seeds to start from: the smallest streams reaching every syntax-model feature |
| `more/` | the {more} other small seeds (add them with a second corpus folder if you like) |
| `stress/` | {stress} long streams (thousands of frames): seconds per input under ASan, not for defaults |
| `fba.dict` | AFL++ / libFuzzer dictionary: start codes, aligned stuffing, header patterns |
| `fuzz_target.c` | a libFuzzer target template; `fuzz_target_fbadec.c` the same around examples/fbadec |
| `fba_mutator.c` | fbaconf's structure-aware mutator: parses, mutates, re-encodes (libFuzzer, AFL++: below) |
| `oss-fuzz/build.sh` | the lines an OSS-Fuzz `build.sh` needs to ship the seeds and the dictionary |

Build with a sanitizer: a read past a buffer does not crash a plain build. New inputs go to a
folder of their own (`new/`, `findings/`), never into `corpus/`.

```sh
# libFuzzer (clang): ASan + UBSan; 10 s per input at most; an input's share of the time weighed by
# its speed (libFuzzer's default ignores it: a corpus of long valid streams then runs ten times slower)
clang -g -O1 -fsanitize=fuzzer,address,undefined fuzz_target.c your_decoder.c -o fba_fuzzer
mkdir -p new && ./fba_fuzzer -dict=fba.dict -timeout=10 -entropic_scale_per_exec_time=1 -artifact_prefix=new/ new corpus
# AFL++: the same target in AFL++'s persistent mode (afl-clang-fast links its libFuzzer driver),
# ASan; -t 1000+: 1 s per input, a seed that takes longer is skipped instead of ending the dry run
AFL_USE_ASAN=1 afl-clang-fast -g -O1 -fsanitize=fuzzer fuzz_target.c your_decoder.c -o decoder-afl
afl-fuzz -i corpus -o findings -x fba.dict -t 1000+ -- ./decoder-afl
# a decoder with only a command line (DECODER IN OUT): a fork per input, about a tenth the speed
AFL_USE_ASAN=1 afl-cc -g -O1 your_decoder_main.c your_decoder.c -o decoder-afl-cli
afl-fuzz -i corpus -o findings-cli -x fba.dict -t 1000+ -- ./decoder-afl-cli @@ /dev/null
# with fbaconf's structure-aware mutator: libFuzzer links it in (built on its own: not instrumented,
# its branches are no coverage of your decoder), AFL++ loads it
clang -O2 -c -DFBA_LIBFUZZER fba_mutator.c -o fba_mutator.o
clang -g -O1 -fsanitize=fuzzer,address,undefined fuzz_target.c fba_mutator.o your_decoder.c -o fba_fuzzer
cc -O2 -shared -fPIC -DFBA_AFL fba_mutator.c -o fba_mutator.so
AFL_CUSTOM_MUTATOR_LIBRARY=./fba_mutator.so afl-fuzz -i corpus -o findings -x fba.dict -t 1000+ -- ./decoder-afl
```

A crash file of either is classified, minimised (as `fbaconf fuzz` minimises its own findings)
and promoted to a regression case with `fbaconf fuzz minimise FILE --decoder D.toml` and
`fbaconf fuzz --promote`.
"""


def _features(data: bytes) -> set[str]:
    try:
        return features_of(data)
    except Exception:  # noqa: BLE001 - a seed the syntax model cannot walk adds no feature
        return set()


def distil(entries: list[Entry], limit: int = MAX_SEEDS) -> tuple[list[Entry], list[Entry]]:
    """(the seeds to start from, the rest): smallest first, a seed is kept when it reaches a
    syntax-model feature no kept seed reaches (a greedy cover, as afl-cmin does with edges), up to
    ``limit``."""
    keep: list[Entry] = []
    rest: list[Entry] = []
    seen: set[str] = set()
    for e in sorted(entries, key=lambda e: (len(e.data), e.origin)):
        f = _features(e.data)
        if len(keep) < limit and not f <= seen:
            keep.append(e)
            seen |= f
        else:
            rest.append(e)
    return keep, rest


def export(out: Path, n_valid: int = 64, seed: int = 0) -> dict:
    """Write the export to ``out``; returns counts."""
    out = Path(out)
    entries = seed_corpus(n_valid, seed)
    unique: dict[str, Entry] = {}
    for e in entries:
        unique.setdefault(hashlib.sha1(e.data, usedforsecurity=False).hexdigest(), e)
    small = [e for e in unique.values() if len(e.data) <= STRESS_BYTES]
    stress = [e for e in unique.values() if len(e.data) > STRESS_BYTES]
    start, more = distil(small)
    counts = {"suite": 0, "prefixes": 0, "generated": 0}
    for folder, group in (("corpus", start), ("more", more), ("stress", stress)):
        (out / folder).mkdir(parents=True, exist_ok=True)
        for e in group:
            digest = hashlib.sha1(e.data, usedforsecurity=False).hexdigest()
            origin = e.origin.removeprefix("seed:")
            kind = "generated" if origin.startswith("generated") else "prefixes" if "planes]" in origin else "suite"
            counts[kind] += 1
            slug = re.sub(r"[^A-Za-z0-9]+", "-", origin).strip("-")[:60]
            (out / folder / f"{slug}-{digest[:12]}.fba").write_bytes(e.data)
    tokens = dictionary_tokens()
    (out / "fba.dict").write_text(dictionary_text())
    (out / "oss-fuzz").mkdir(exist_ok=True)
    (out / "oss-fuzz" / "build.sh").write_text(BUILD_SH)
    (out / "fuzz_target.c").write_text(TARGET_C)
    (out / "fuzz_target_fbadec.c").write_text(TARGET_FBADEC_C)
    shutil.copyfile(MUTATOR_C, out / "fba_mutator.c")
    n = len(unique)
    (out / "README.md").write_text(
        README.format(
            n=n,
            start=len(start),
            more=len(more),
            stress=len(stress),
            suite=counts["suite"],
            prefixes=counts["prefixes"],
            generated=counts["generated"],
            tokens=len(tokens),
        )
    )
    return {
        "seeds": n,
        "corpus": len(start),
        "more": len(more),
        "stress": len(stress),
        **counts,
        "tokens": len(tokens),
        "dir": str(out),
    }
