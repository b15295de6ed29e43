"""``fbaconf fuzz export DIR``: what the coverage-guided fuzzers vendors already run need
from fbaconf — a seed corpus, a dictionary of the syntax's tokens and an OSS-Fuzz build
snippet — so a decoder's own libFuzzer / AFL++ / OSS-Fuzz target starts from streams that
reach every part of the syntax instead of from nothing.

Layout::

    DIR/corpus/<origin>-<sha1:12>.fba   conformance suite streams, their 1–3-plane prefixes,
                                        and generated valid streams (deduplicated by content)
    DIR/fba.dict                        AFL++/libFuzzer dictionary (byte-aligned tokens)
    DIR/oss-fuzz/build.sh               OSS-Fuzz build snippet (seed corpus zip + dictionary)
    DIR/fuzz_target.c                   a libFuzzer target template (LLVMFuzzerTestOneInput)
    DIR/README.md                       how to use them
"""

from __future__ import annotations

import hashlib
import random
import re
from pathlib import Path

from .choosers import RandomChooser
from .corpus import conformance_seeds, short_prefixes
from .inputs import Entry, gen_valid
from .model import DICTIONARY

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
 *   ./fba_fuzzer -dict=fba.dict corpus/
 */
#include <stddef.h>
#include <stdint.h>

int decode_face_stream(const uint8_t *data, size_t size);  /* your decoder */

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    decode_face_stream(data, size);
    return 0;  /* libFuzzer: always 0; crashes and sanitizer reports are the findings */
}
"""

README = """# Seeds and a dictionary for coverage-guided fuzzing of a face object stream decoder

Made by `fbaconf fuzz export` ({n} seed streams: {suite} conformance streams, {prefixes}
short prefixes of them, {generated} generated valid streams; {tokens} dictionary tokens).

| file | for |
|---|---|
| `corpus/` | the seed corpus: valid streams and conformance error cases (coverage starts deep) |
| `fba.dict` | AFL++ / libFuzzer dictionary: start codes, aligned stuffing, header patterns |
| `fuzz_target.c` | a libFuzzer target template |
| `oss-fuzz/build.sh` | the lines an OSS-Fuzz `build.sh` needs to ship the seeds and the dictionary |

```sh
# libFuzzer
clang -g -O1 -fsanitize=fuzzer,address,undefined fuzz_target.c your_decoder.c -o fba_fuzzer
./fba_fuzzer -dict=fba.dict corpus/
# AFL++
afl-fuzz -i corpus -o findings -x fba.dict -- ./your_decoder @@ /dev/null
```

A crash found this way can be classified, minimised and promoted to a regression case with
`fbaconf fuzz --decoder D.toml --replay FILE` and `fbaconf fuzz --promote`.
"""


def export(out: Path, n_valid: int = 64, seed: int = 0) -> dict:
    """Write the export to ``out``; returns counts."""
    out = Path(out)
    corpus_dir = out / "corpus"
    corpus_dir.mkdir(parents=True, exist_ok=True)
    entries = seed_corpus(n_valid, seed)
    seen: set[str] = set()
    counts = {"suite": 0, "prefixes": 0, "generated": 0}
    for e in entries:
        digest = hashlib.sha1(e.data, usedforsecurity=False).hexdigest()
        if digest in seen:
            continue
        seen.add(digest)
        origin = e.origin.removeprefix("seed:")
        kind = "generated" if origin.startswith("generated") else "prefixes" if "planes]" in origin else "suite"
        counts[kind] += 1
        slug = re.sub(r"[^A-Za-z0-9]+", "-", origin).strip("-")[:60]
        (corpus_dir / f"{slug}-{digest[:12]}.fba").write_bytes(e.data)
    tokens = dictionary_tokens()
    (out / "fba.dict").write_text(dictionary_text())
    (out / "oss-fuzz").mkdir(exist_ok=True)
    (out / "oss-fuzz" / "build.sh").write_text(BUILD_SH)
    (out / "fuzz_target.c").write_text(TARGET_C)
    n = len(seen)
    (out / "README.md").write_text(
        README.format(
            n=n, suite=counts["suite"], prefixes=counts["prefixes"], generated=counts["generated"], tokens=len(tokens)
        )
    )
    return {"seeds": n, **counts, "tokens": len(tokens), "dir": str(out)}
